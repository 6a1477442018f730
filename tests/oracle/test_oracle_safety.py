"""Oracle tests of the safety monitor's arithmetic of commands and counts (`runtime.safety`), around
the shipped hover policy (numpy backend) and a scripted fallback: what reaches the motors is float32
in [0, 1] whatever the fallback answers, a non-finite fallback command becomes the hover command,
and every event is counted once per step.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from quadpilot.core.observation import build_observation
from quadpilot.runtime.backends import Policy, load_policy
from quadpilot.runtime.fallback import FallbackController
from quadpilot.runtime.safety import SafetyMonitor

HOVER = Path(__file__).resolve().parents[2] / "models" / "hover" / "policy.onnx"
TARGET = np.array([0.0, 0.0, 2.0])


@pytest.fixture(scope="module")
def policy():
    return load_policy(HOVER, "numpy")


class ScriptedFallback:
    """A fallback controller that answers a fixed command, as float64 (what a controller written in
    plain NumPy returns)."""

    def __init__(self, command) -> None:
        self.command = np.asarray(command, np.float64)
        self.resets = 0

    def act(self, obs):
        return self.command.copy()

    def reset(self):
        self.resets += 1


def hover_obs(offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    s = np.zeros((1, 12))
    s[0, 0:3] = TARGET + np.asarray(offset)
    return build_observation(s, TARGET)[0]


def far_obs() -> np.ndarray:
    """10 m above the target, beyond the hover envelope's 5 m: the fallback flies."""
    return hover_obs((0.0, 0.0, 10.0))


def test_fallback_commands_are_clamped_to_zero_one_as_float32(policy):
    monitor = SafetyMonitor(policy, fallback=ScriptedFallback([-0.5, 1.5, 0.25, 0.125]))
    u = monitor.act(far_obs())
    assert u.dtype == np.float32
    np.testing.assert_array_equal(u, np.float32([0.0, 1.0, 0.25, 0.125]))
    assert monitor.source == "fallback" and monitor.events["fallback_steps"] == 1


def test_a_non_finite_fallback_command_is_replaced_by_hover_and_counted_each_time(policy):
    hover = np.float32(policy.info.vehicle.hover_command)
    monitor = SafetyMonitor(policy, fallback=ScriptedFallback([0.5, np.nan, 0.5, 0.5]))
    for n in (1, 2, 3):
        u = monitor.act(far_obs())
        np.testing.assert_array_equal(u, np.full(4, hover, np.float32))
        assert monitor.events["fallback_nonfinite"] == n
        assert monitor.events["fallback_steps"] == n


def test_blind_steps_are_counted_each_step_and_reset_re_arms(policy):
    monitor = SafetyMonitor(policy, fallback=ScriptedFallback([0.5, 0.5, 0.5, 0.5]))
    bad = hover_obs()
    bad[0] = np.nan
    hover = np.float32(policy.info.vehicle.hover_command)
    for n in (1, 2, 3):
        np.testing.assert_array_equal(monitor.act(bad), np.full(4, hover, np.float32))
        assert monitor.events["blind_steps"] == n and monitor.events["obs_nonfinite"] == n
    assert monitor.events["fallback_engaged"] == 1 and monitor.in_fallback is True and not monitor.latched
    monitor.reset()
    assert monitor.in_fallback is False and monitor.source == "policy"
    monitor.act(hover_obs())
    assert monitor.source == "policy"


def monitor_for(policy) -> SafetyMonitor:
    return SafetyMonitor(policy, fallback=ScriptedFallback([0.5, 0.5, 0.5, 0.5]))


@pytest.mark.parametrize(
    "offset, inside",
    [
        ((3.0, 4.0, 0.0), True),  # exactly 5 m (float32 3 and 4: d² = 25 exactly) is still inside
        ((0.0, 3.0, 4.0), True),
        ((5.5, 0.0, 0.0), False),  # beyond 5 m along each axis alone
        ((0.0, 5.5, 0.0), False),
        ((0.0, 0.0, 5.5), False),
        ((0.0, -5.5, 0.0), False),
        ((3.0, 4.0, 0.5), False),  # d = √25.25
    ],
)
def test_the_distance_envelope_is_five_metres_in_every_direction(policy, offset, inside):
    monitor = monitor_for(policy)
    monitor.act(hover_obs(offset))
    assert monitor.source == ("policy" if inside else "fallback")
    assert monitor.events["out_of_envelope"] == (0 if inside else 1)


def tilted_obs(roll_deg=0.0, pitch_deg=0.0) -> np.ndarray:
    s = np.zeros((1, 12))
    s[0, 0:3] = TARGET
    s[0, 6], s[0, 7] = np.radians(roll_deg), np.radians(pitch_deg)
    return build_observation(s, TARGET)[0]


@pytest.mark.parametrize(
    "roll, pitch, inside",
    [
        (55.0, 0.0, True),
        (-59.0, 0.0, True),
        (65.0, 0.0, False),
        (-65.0, 0.0, False),
        (120.0, 0.0, False),
        (0.0, 59.0, True),
        (0.0, 61.0, False),
        (0.0, -61.0, False),
        (59.0, 59.0, True),  # each angle on its own, not their combination
        (50.0, 65.0, False),
    ],
)
def test_the_tilt_envelope_is_sixty_degrees_of_roll_or_pitch(policy, roll, pitch, inside):
    """ZYX Euler angles as training terminated on them: |roll| ≤ 60° and |pitch| ≤ 60°, upside down
    (|roll| > 90°) outside."""
    monitor = monitor_for(policy)
    monitor.act(tilted_obs(roll, pitch))
    assert monitor.source == ("policy" if inside else "fallback")


def with_rot(rows) -> np.ndarray:
    obs = hover_obs()
    obs[6:15] = np.asarray(rows, np.float32).reshape(-1)
    return obs


S10, C10 = np.sin(np.radians(10.0)), np.cos(np.radians(10.0))


@pytest.mark.parametrize(
    "rows, why",
    [
        ([[1, 0, 0], [0, 1, 0], [0, 0, -1]], "level, mirrored: third column −(first × second), along z"),
        ([[1, 0, 0], [0, 0, 1], [0, 1, 0]], "rolled 90°, mirrored: the third column along y flipped"),
        ([[0, 0, -1], [0, 1, 0], [-1, 0, 0]], "pitched 90°, mirrored: the third column along x flipped"),
        ([[1, C10, 0], [0, S10, 0], [0, 0, S10]], "second column of unit length, 10° from the first"),
        ([[1, 0, 0], [0, 0.8, -0.8], [0, 0.8, 0.8]], "second column (0, 0.8, 0.8): √1.28 long"),
        ([[0.8, 0, 0.8], [0.8, 0, -0.8], [0, 1, 0]], "first column (0.8, 0.8, 0): √1.28 long"),
    ],
)
def test_an_attitude_block_that_is_no_rotation_is_flown_blind(policy, rows, why):
    """Each of these fails exactly one part of the rotation check (columns of unit length, the first
    two orthogonal, third column = first × second) and passes the others; every entry lies in [−1, 1],
    so the range check does not catch them."""
    monitor = monitor_for(policy)
    hover = np.float32(policy.info.vehicle.hover_command)
    u = monitor.act(with_rot(rows))
    assert monitor.events["obs_not_rotation"] == 1, why
    np.testing.assert_array_equal(u, np.full(4, hover, np.float32))
    # a proper rotation (yawed 90°) with the same layout is flown by the policy
    monitor = monitor_for(policy)
    monitor.act(with_rot([[0, -1, 0], [1, 0, 0], [0, 0, 1]]))
    assert monitor.source == "policy"


def test_a_new_monitor_lets_the_policy_fly(policy):
    monitor = monitor_for(policy)
    assert monitor.source == "policy" and monitor.in_fallback is False
    monitor.act(hover_obs())
    assert monitor.source == "policy" and not monitor.events


def test_the_attitude_block_is_read_where_the_layout_puts_it():
    """The circle layout (21 values: the target velocity after the rates) holds R at 6..14 as the
    hover one does; a level circle observation is a rotation and is flown by the policy."""
    circle = load_policy(HOVER.parents[1] / "circle" / "policy.onnx", "numpy")
    s = np.zeros((1, 12))
    s[0, 0:3] = TARGET
    obs = build_observation(s, TARGET, np.array([0.5, 0.0, 0.0]))[0]
    assert obs.shape == (21,)
    monitor = SafetyMonitor(circle)
    u = monitor.act(obs)
    assert monitor.source == "policy" and not monitor.events
    assert u.shape == (4,) and np.all((u >= 0.0) & (u <= 1.0))


@pytest.mark.parametrize("v, ok", [(100.0, True), (-100.0, True), (100.5, False), (-100.5, False)])
def test_an_observation_value_at_its_bound_is_accepted(policy, v, ok):
    """Velocity is bounded by 100 m/s (`ObservationLimits.vel`), the bound itself included."""
    obs = hover_obs()
    obs[3] = v
    monitor = monitor_for(policy)
    monitor.act(obs)
    assert monitor.events["obs_out_of_range"] == (0 if ok else 1)
    assert monitor.source == ("policy" if ok else "fallback")


class FixedCommand(Policy):
    """A policy with the hover file's metadata that answers a fixed command (a foreign graph)."""

    backend = "test-double"

    def __init__(self, info, command) -> None:
        super().__init__(info)
        self.command = np.asarray(command, np.float32)

    def act_unchecked(self, x):
        return self.command.copy()


@pytest.mark.parametrize(
    "command, clamped, expected",
    [
        ([0.0, 1.0, 0.5, 1.0], False, [0.0, 1.0, 0.5, 1.0]),  # the ends of [0, 1] are commands, not faults
        ([0.0, 1.25, -0.5, 1.0], True, [0.0, 1.0, 0.0, 1.0]),
    ],
)
def test_policy_commands_outside_zero_one_are_clamped_and_counted(policy, command, clamped, expected):
    monitor = SafetyMonitor(FixedCommand(policy.info, command), fallback=ScriptedFallback([0.5] * 4))
    u = monitor.act(hover_obs())
    np.testing.assert_array_equal(u, np.float32(expected))
    assert u.dtype == np.float32
    assert monitor.events["command_clamped"] == (1 if clamped else 0) and monitor.source == "policy"


def test_the_default_fallback_is_built_for_the_files_vehicle_and_control_period(policy):
    """Without a fallback given, the monitor builds FallbackController(vehicle, control period) from
    the file's metadata: for a 20 ms policy its first command out of the envelope is that of a 20 ms
    controller (the gains depend on the period), not of a 10 ms one."""
    info = replace(policy.info, control_period_s=0.02)
    monitor = SafetyMonitor(FixedCommand(info, [0.5] * 4))
    obs = hover_obs((1.0, -2.0, 5.5))
    u = monitor.act(obs)
    assert monitor.source == "fallback"
    expected = np.clip(
        np.asarray(
            FallbackController(info.vehicle, 0.02, heading_frame=info.layout.heading_frame).act(obs), np.float32
        ),
        0.0,
        1.0,
    )
    np.testing.assert_array_equal(u, expected)
    assert not np.array_equal(
        expected,
        FallbackController(info.vehicle, 0.01, heading_frame=info.layout.heading_frame).act(obs).astype(np.float32),
    )
