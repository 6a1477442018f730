"""The px4-raptor contract (`core.px4_raptor`) against values worked out by hand from PX4's
src/modules/mc_raptor/mc_raptor.cpp (`Raptor::observe`, `Raptor::Run`) and RLtools' L2F executor.

The vehicle: 0.8 m east, 0.1 m north and 0.2 m above its setpoint, moving at (0.3, −1.5, 0.4) m/s
ENU, rolled 30° right wing down (roll +30° about the forward axis, FLU), pitch 0, yaw 120° ENU
(30° west of north), rates (0.1, −0.2, 0.3) rad/s FLU; the setpoint faces north (ENU yaw 90°,
NED yaw 0). In the setpoint-yaw frame x points north, y west, z up:
- position error: north 0.1, west −0.8 → clipped −0.5, up 0.2;
- velocity: north −1.5 → clipped −1, west −0.3, up 0.4;
- attitude: the vehicle is yawed 30° left of the setpoint and rolled 30°: Rz(30°)·Rx(30°) =
  [[√3/2, −√3/4, 1/4], [1/2, 3/4, −√3/4], [0, 1/2, √3/2]].
PX4's own inputs for the same vehicle: NED position (2.1, 1.8, −3.2) against (2.0, 1.0, −3.0),
velocity (−1.5, 0.3, −0.4), gyro FRD (0.1, 0.2, −0.3), and the attitude quaternion (body FRD → NED,
yaw −30°, roll 30°) qz(−30°)·qx(30°) = (c², cs, −s², −cs) with c = cos 15°, s = sin 15°.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from quadpilot.core import px4_raptor as pr
from quadpilot.core.observation import build_observation
from quadpilot.link import frames

R3 = math.sqrt(3.0)
C15, S15 = math.cos(math.radians(15.0)), math.sin(math.radians(15.0))
PREV = (0.1, -0.2, 0.3, -0.4)
STATE = (1.8, 2.1, 3.2, 0.3, -1.5, 0.4, math.radians(30.0), 0.0, math.radians(120.0), 0.1, -0.2, 0.3)
TARGET = (1.0, 2.0, 3.0)
EXPECTED = [
    *(0.1, -0.5, 0.2),
    *(R3 / 2, -R3 / 4, 0.25, 0.5, 0.75, -R3 / 4, 0.0, 0.5, R3 / 2),
    *(-1.0, -0.3, 0.4),
    *(0.1, -0.2, 0.3),
    *PREV,
]


def test_the_observation_of_a_tilted_yawed_moving_vehicle_from_our_state():
    obs = pr.observation(STATE, TARGET, None, math.radians(90.0), PREV)
    assert obs.dtype == np.float32 and obs.shape == (pr.OBS_DIM,) == (pr.PX4_RAPTOR_LAYOUT.dim,)
    np.testing.assert_allclose(obs, EXPECTED, atol=1e-6)


def test_the_same_observation_from_px4s_topics_computed_as_mc_raptor_does():
    q = (C15 * C15, C15 * S15, -S15 * S15, -S15 * C15)
    pos, vel, gyro, sp = (2.1, 1.8, -3.2), (-1.5, 0.3, -0.4), (0.1, 0.2, -0.3), (2.0, 1.0, -3.0)
    obs = pr.observation_ned(pos, vel, q, gyro, sp, (0, 0, 0), 0.0, PREV)
    np.testing.assert_allclose(obs, EXPECTED, atol=1e-6)
    # the hand-worked quaternion is the one the link layer sends for this attitude
    np.testing.assert_allclose(frames.ned_frd_quaternion(*STATE[6:9]), q, atol=1e-12)


def test_the_setpoint_velocity_is_subtracted_before_the_clip():
    # setpoint moving north at 1.2 m/s: the vehicle's −1.5 north is −2.7 relative, still −1 after the clip;
    # east at 0.5: its 0.3 east is −0.2 relative, +0.2 west
    obs = pr.observation(STATE, TARGET, (0.5, 1.2, 0.1), math.radians(90.0), PREV)
    np.testing.assert_allclose(obs[12:15], (-1.0, 0.2, 0.3), atol=1e-6)


_F = st.floats(-1.0, 1.0, allow_nan=False)
_V3 = st.tuples(_F, _F, _F)


@settings(derandomize=True, database=None, deadline=None, max_examples=300)
@given(
    pos=_V3,
    vel=_V3,
    att=st.tuples(st.floats(-1.4, 1.4), st.floats(-1.4, 1.4), st.floats(-math.pi, math.pi)),
    rates=_V3,
    target=_V3,
    target_vel=_V3,
    heading=st.floats(-math.pi, math.pi),
    prev=st.tuples(_F, _F, _F, _F),
)
def test_our_state_and_px4s_topics_give_the_same_inputs(pos, vel, att, rates, target, target_vel, heading, prev):
    """Any vehicle, setpoint and heading: the ENU form and PX4's NED form agree (link.frames converts,
    as the node's simulator link does). Positions and velocities up to 2 m and 2 m/s from the
    setpoint, so that both sides of the clips are reached."""
    s = np.array([*(2 * np.array(pos)), *(2 * np.array(vel)), *att, *(3 * np.array(rates))])
    target, tv = np.array(target), np.array(target_vel)
    ours = pr.observation(s, target, tv, heading, prev)
    ned = pr.observation_ned(
        frames.enu_to_ned(s[0:3]),
        frames.enu_to_ned(s[3:6]),
        frames.ned_frd_quaternion(*s[6:9]),
        frames.flu_to_frd(s[9:12]),
        frames.enu_to_ned(target),
        frames.enu_to_ned(tv),
        math.pi / 2 - heading,
        prev,
    )
    np.testing.assert_allclose(ours, ned, atol=2e-6)


def test_the_ned_setpoint_yaw_is_our_heading():
    assert pr.heading_from_ned_yaw(0.0) == pytest.approx(math.pi / 2)  # north
    assert pr.heading_from_ned_yaw(math.pi / 2) == pytest.approx(0.0)  # east
    assert pr.heading_from_ned_yaw(-math.pi / 2) == pytest.approx(math.pi)  # west


def test_motor_commands_remap_crazyflie_order_to_quad_x_and_scale():
    # policy (FR, BR, BL, FL) = (0.5, −0.5, 1.5 → 1, −1); PX4 (FR, BL, FL, BR) = (0.5, 1, −1, −0.5)
    np.testing.assert_allclose(pr.motor_commands((0.5, -0.5, 1.5, -1.0)), (0.75, 1.0, 0.0, 0.25), atol=0)


def test_the_fallback_sees_the_hover_layout_of_the_same_vehicle():
    """Unclipped errors: the hover layout (version 2) that core.observation builds for this state
    and heading, from the px4-raptor observation alone."""
    near = (1.9, 2.0, 3.1)  # 0.1 m from the vehicle on each axis: nothing clipped
    s = np.array([(*STATE[:3], 0.3, -0.5, 0.4, *STATE[6:])])
    ours = pr.fallback_observation(pr.observation(s[0], near, None, math.radians(90.0), PREV))
    np.testing.assert_allclose(ours, build_observation(s, np.array(near), heading=math.radians(90.0))[0], atol=1e-6)


class _Recorder:
    """A step that records what it was given and answers a known action; state = calls seen."""

    def __init__(self):
        self.seen = []
        self.initial_state = np.zeros(1, np.float32)

    def __call__(self, obs, state):
        self.seen.append((obs.copy(), state.copy()))
        k = len(self.seen)
        return np.full(4, 0.1 * k, np.float32), state + 1


def test_at_250_hz_the_state_advances_every_second_call_and_the_previous_action_is_the_mean():
    """IMU_GYRO_RATEMAX 250 → force_sync 2: calls 0, 2, 4 are native. Actions 0.1, 0.2, 0.3, ...; the
    previous action a call sees: 0 after the reset, then a0, then mean(a0, a1), then a2, ..."""
    rec = _Recorder()
    ex = pr.Executor(rec, rec.initial_state, pr.force_sync_native(250.0))
    assert ex.force_sync == 2
    prevs = []
    for _ in range(5):
        prev = ex.previous_action_input()
        prevs.append(prev[0])
        ex.control(np.concatenate([np.zeros(18, np.float32), prev]))
    np.testing.assert_allclose(prevs, [0.0, 0.1, 0.15, 0.3, 0.35], atol=1e-6)
    # the state each call started from: advanced by calls 0 and 2 only
    assert [float(state[0]) for _, state in rec.seen] == [0, 1, 1, 2, 2]
    assert float(ex.state[0]) == 3  # call 4 was native
    ex.reset()
    assert float(ex.state[0]) == 0 and ex.previous_action_input().tolist() == [0, 0, 0, 0]


def test_at_100_hz_every_call_is_native():
    rec = _Recorder()
    ex = pr.Executor(rec, rec.initial_state, pr.force_sync_native(100.0))
    for _ in range(3):
        ex.control(np.concatenate([np.zeros(18, np.float32), ex.previous_action_input()]))
    assert [float(s[0]) for _, s in rec.seen] == [0, 1, 2]
    assert pr.force_sync_native(50.0) == 0 and pr.force_sync_native(1000.0) == 10


def test_the_previous_action_is_clamped_as_the_executor_clamps_it():
    ex = pr.Executor(lambda o, s: (np.array([2.0, -3.0, 0.5, 1.0], np.float32), s), np.zeros(1))
    ex.control(np.zeros(22, np.float32))
    assert ex.previous_action_input().tolist() == [1.0, -1.0, 0.5, 1.0]
