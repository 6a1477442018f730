"""The commanded heading, against values worked out by hand: the version-2 observation's attitude is
relative to the commanded heading, the reward pays for holding it, and the node never gives a
policy a heading further than it was trained on."""

import math

import numpy as np
import pytest

from quadpilot.autopilot.node import HEADING_REACH_RAD, heading_within_reach
from quadpilot.core.observation import HOVER_LAYOUT, HOVER_LAYOUT_V1, TRACK_LAYOUT, build_observation
from quadpilot.core.reward import RewardConfig, hover_reward


def _state(yaw, roll=0.0, pitch=0.0):
    s = np.zeros((1, 12))
    s[0, 0:3] = (1.0, -0.5, 2.5)
    s[0, 3:6] = (0.3, 0.2, -0.1)
    s[0, 6:9] = (roll, pitch, yaw)
    s[0, 9:12] = (0.1, -0.2, 0.3)
    return s


def test_a_vehicle_facing_its_commanded_heading_sees_the_identity_yaw():
    """Level and facing exactly the commanded heading (here 100°, nose north of west): the
    heading-relative attitude is the identity, whatever the world yaw."""
    obs = build_observation(_state(math.radians(100.0)), np.zeros(3), heading=math.radians(100.0))[0]
    np.testing.assert_allclose(obs[6:15], np.eye(3).ravel(), atol=1e-6)


def test_thirty_degrees_left_of_the_commanded_heading_reads_as_a_thirty_degree_yaw():
    """Facing 40° with 10° commanded: R' = Rz(30°); its first column is (cos 30°, sin 30°, 0)."""
    obs = build_observation(_state(math.radians(40.0)), np.zeros(3), heading=math.radians(10.0))[0]
    c, s = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    np.testing.assert_allclose(obs[6:15], [c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0], atol=1e-6)


def test_body_frame_fields_do_not_depend_on_the_commanded_heading():
    s = _state(0.7, roll=0.2, pitch=-0.1)
    target_vel = np.array([0.4, -0.2, 0.0])
    a = build_observation(s, np.zeros(3), target_vel, heading=0.0)[0]
    b = build_observation(s, np.zeros(3), target_vel, heading=-2.0)[0]
    for name, sl in TRACK_LAYOUT.slices().items():
        if name != "rot":
            np.testing.assert_array_equal(a[sl], b[sl])
    assert not np.allclose(a[6:15], b[6:15])
    # roll and pitch are unchanged: the third row (the world z axis in the body) is the same
    np.testing.assert_allclose(a[12:15], b[12:15], atol=1e-7)


def test_heading_zero_gives_the_version_one_observation():
    s = _state(2.1, roll=0.3)
    np.testing.assert_array_equal(build_observation(s, np.zeros(3), heading=0.0), build_observation(s, np.zeros(3)))
    assert HOVER_LAYOUT.heading_frame and not HOVER_LAYOUT_V1.heading_frame
    assert HOVER_LAYOUT.dim == HOVER_LAYOUT_V1.dim == 18


def test_the_reward_pays_for_the_heading_and_charges_for_the_yaw_rate():
    cfg = RewardConfig()
    s = np.zeros((3, 12))
    pos_err, crash = np.zeros((3, 3)), np.zeros(3, bool)
    # on target, still: the heading Gaussian is at its weight for no error, below it for 0.5 rad,
    # e^-1 of it at one σ
    head = np.array([0.0, 0.5, 0.25])
    r = hover_reward(s, pos_err, crash, cfg, head)
    base = cfg.pos_coarse_weight + cfg.pos_fine_weight
    assert r[0] == pytest.approx(base + cfg.heading_weight)
    assert r[1] == pytest.approx(base + cfg.heading_weight * math.exp(-1.0))
    assert r[2] == pytest.approx(base + cfg.heading_weight * math.exp(-0.25))
    # a yaw rate of 2 rad/s costs rate_weight·4 + yaw_rate_weight·4 on top
    s[:, 11] = 2.0
    r2 = hover_reward(s, pos_err, crash, cfg, np.zeros(3))
    assert r2[0] == pytest.approx(base + cfg.heading_weight - 4.0 * (cfg.rate_weight + cfg.yaw_rate_weight))
    # without a heading error (version-1 policies) the reward is the old one
    assert hover_reward(s, pos_err, crash, cfg)[0] == pytest.approx(base - 4.0 * cfg.rate_weight)


@pytest.mark.parametrize(
    ("yaw_deg", "commanded_deg", "given_deg"),
    [
        (0.0, 10.0, 10.0),  # within reach: the commanded heading itself
        (0.0, -25.0, -25.0),
        (0.0, 90.0, 25.0),  # beyond: 25° ahead, towards it
        (0.0, -170.0, -25.0),
        (170.0, -170.0, -170.0),  # 20° across ±180°: the short way
        (170.0, -100.0, -165.0),  # 90° the short way round, across ±180°: 25° ahead is 195° = −165°
    ],
)
def test_the_node_gives_a_heading_at_most_25_degrees_ahead(yaw_deg, commanded_deg, given_deg):
    got = heading_within_reach(math.radians(yaw_deg), math.radians(commanded_deg))
    assert math.degrees(got) == pytest.approx(given_deg, abs=1e-9)
    assert HEADING_REACH_RAD == pytest.approx(math.radians(25.0))


@pytest.mark.parametrize(("heading_frame", "ends_at"), [(True, 0.0), (False, 0.5)])
def test_the_fallback_holds_the_commanded_heading_in_a_version_two_observation(heading_frame, ends_at):
    """A hovering seed quad at yaw 0.5 rad, commanded heading 0, flown 4 s by the fallback on the
    version-2 observation: with heading_frame it turns to the commanded heading; without (a
    version-1 controller), it holds the heading it found, 0.5 rad."""
    from quadpilot.core import dynamics
    from quadpilot.core.params import ParamBatch
    from quadpilot.core.vehicle_file import get_preset
    from quadpilot.runtime.fallback import FallbackController

    vehicle = get_preset("seed")
    ctrl = FallbackController(vehicle, 0.01, heading_frame=heading_frame)
    params = ParamBatch.from_preset(vehicle, 1)
    state = np.zeros((1, 12))
    state[0, 2], state[0, 8] = 2.0, 0.5
    rotor = np.full((1, 4), vehicle.hover_command)
    target = np.array([0.0, 0.0, 2.0])
    for _ in range(400):
        obs = build_observation(state, target, heading=0.0)[0]
        state, rotor = dynamics.step(state, rotor, ctrl.act(obs)[None].astype(np.float64), params, 0.01)
    assert state[0, 8] == pytest.approx(ends_at, abs=math.radians(2.0))
    assert abs(state[0, 11]) < 0.05 and np.linalg.norm(state[0, 0:3] - target) < 0.05


def test_the_circle_reward_pays_the_same_heading_term():
    """Circle's reward is hover's towards the moving point plus its own terms: the heading term
    (and the yaw-rate charge) come with it."""
    from quadpilot.core.reward import circle_reward

    cfg = RewardConfig()
    s = np.zeros((2, 12))
    s[:, 0], s[:, 2], s[:, 4], s[:, 11] = 1.0, 2.0, 1.0, 1.5  # on the circle, at its speed, turning
    pos_err, crash, centre = np.zeros((2, 3)), np.zeros(2, bool), np.array([0.0, 0.0, 2.0])
    head = np.array([0.0, 0.5])
    with_heading = circle_reward(s, pos_err, crash, centre, 1.0, 1.0, cfg, head)
    without = circle_reward(s, pos_err, crash, centre, 1.0, 1.0, cfg)
    extra = cfg.heading_weight * np.exp(-(head**2) / cfg.heading_sigma**2) - cfg.yaw_rate_weight * 1.5**2
    np.testing.assert_allclose(with_heading - without, extra, rtol=1e-12)
