"""Oracle tests of the reward (`core.reward`): its sign and shape against hand-computed values.

    r = w_c·exp(−d²/σ_c²) + w_f·exp(−d²/σ_f²) − w_ω·|ω|² − w_tilt·max(0, max(|φ|, |θ|) − tilt_soft)²
        − crash_penalty·[crashed]
with the defaults of `RewardConfig`: w_c 0.5, σ_c 1 m, w_f 1.0, σ_f 0.1 m, w_ω 0.01, crash_penalty 10.0
("paid once on the step that ends in a crash"), crash beyond 60° tilt, below the ground or 5 m away.
Circle adds w_R·exp(−e_R²/σ_R²) + w_v·exp(−e_v²/σ_v²) with w 0.5, σ_R 0.1 m, σ_v 0.2 m/s.
"""

import math

import numpy as np
import pytest

from quadpilot.core.reward import RewardConfig, circle_errors, circle_reward, crashed, hover_reward

CFG = RewardConfig()


def hover(pos_error, rates=(0.0, 0.0, 0.0), roll=0.0, pitch=0.0, crash=False, cfg=CFG) -> float:
    s = np.zeros((1, 12))
    s[0, 2] = 1.0
    s[0, 6], s[0, 7] = roll, pitch
    s[0, 9:12] = rates
    return float(hover_reward(s, np.array([pos_error], float), np.array([crash]), cfg)[0])


def test_the_documented_defaults():
    assert (CFG.pos_coarse_weight, CFG.pos_coarse_sigma, CFG.pos_fine_weight, CFG.pos_fine_sigma) == (
        0.5,
        1.0,
        1.0,
        0.1,
    )
    assert (CFG.rate_weight, CFG.crash_penalty, CFG.max_tilt_deg, CFG.max_distance) == (0.01, 10.0, 60.0, 5.0)
    assert (CFG.radius_weight, CFG.radius_sigma, CFG.speed_weight, CFG.speed_sigma) == (0.5, 0.1, 0.5, 0.2)


def test_hand_values():
    # d = 0.2 m, |ω|² = 0.01 + 0.04 + 0.09 = 0.14:
    # 0.5·e^(−0.04) + 1.0·e^(−4) − 0.01·0.14 = 0.4803947196 + 0.0183156389 − 0.0014 = 0.4973103585
    assert hover((0.2, 0.0, 0.0), rates=(0.1, -0.2, 0.3)) == pytest.approx(0.4973103585, abs=1e-9)
    # d = 0.05 m (3-4-5 in cm): 0.5·e^(−0.0025) + e^(−0.25) = 1.2775523443
    assert hover((0.03, -0.04, 0.0)) == pytest.approx(1.2775523443, abs=1e-9)
    # d = σ_c = 1 m: the coarse term is w_c/e and the fine one e^(−100) ≈ 0
    assert hover((0.0, 0.0, 1.0)) == pytest.approx(0.5 / math.e, abs=1e-12)
    # d = σ_f = 0.1 m: the fine term is w_f/e
    assert hover((0.0, 0.1, 0.0)) == pytest.approx(0.5 * math.exp(-0.01) + 1.0 / math.e, abs=1e-12)


def test_the_maximum_is_at_the_target_and_equals_the_sum_of_the_weights():
    assert hover((0.0, 0.0, 0.0)) == pytest.approx(1.5, abs=1e-15)


def test_closer_is_better_along_every_direction():
    rng = np.random.default_rng(0)
    for _ in range(20):
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        d = np.linspace(0.0, 4.0, 81)
        r = [hover(tuple(di * u)) for di in d]
        assert np.all(np.diff(r) < 0), "the reward must fall strictly as the distance grows"
    # and it depends on the distance only
    assert hover((0.3, 0.0, 0.0)) == pytest.approx(hover((0.0, -0.3, 0.0)), abs=1e-15)


def test_body_rates_cost_their_squared_norm():
    base = hover((0.1, 0.0, 0.0))
    assert hover((0.1, 0.0, 0.0), rates=(2.0, 0.0, 0.0)) == pytest.approx(base - 0.04, abs=1e-12)
    assert hover((0.1, 0.0, 0.0), rates=(0.0, -1.0, 3.0)) == pytest.approx(base - 0.1, abs=1e-12)


def test_tilt_penalty_beyond_the_soft_limit():
    cfg = RewardConfig(tilt_weight=50.0)
    base = hover((0.0, 0.0, 0.0), cfg=cfg)
    assert hover((0.0, 0.0, 0.0), roll=math.radians(39.0), cfg=cfg) == pytest.approx(base, abs=1e-15)
    # 50° roll: 10° beyond 40°, 50·(0.17453 rad)² = 1.5230870989
    assert hover((0.0, 0.0, 0.0), roll=math.radians(50.0), cfg=cfg) == pytest.approx(base - 1.5230870989, abs=1e-9)
    assert hover((0.0, 0.0, 0.0), pitch=math.radians(-50.0), cfg=cfg) == pytest.approx(base - 1.5230870989, abs=1e-9)


def test_a_crash_costs_the_crash_penalty_of_ten():
    for err in ((0.0, 0.0, 0.0), (0.2, 0.0, 0.0), (3.0, 0.0, 0.0)):
        assert hover(err, crash=True) == pytest.approx(hover(err) - 10.0, abs=1e-12)
    assert hover((0.0, 0.0, 0.0), crash=True) == pytest.approx(1.5 - 10.0, abs=1e-12)


@pytest.mark.parametrize(
    "z, roll, pitch, err, expected",
    [
        (1.0, 0.0, 0.0, (0.0, 0.0, 0.0), False),
        (-0.01, 0.0, 0.0, (0.0, 0.0, 0.0), True),  # below the ground
        (1.0, math.radians(59.0), 0.0, (0.0, 0.0, 0.0), False),
        (1.0, math.radians(61.0), 0.0, (0.0, 0.0, 0.0), True),  # tilt beyond 60°
        (1.0, 0.0, math.radians(-61.0), (0.0, 0.0, 0.0), True),
        (1.0, 0.0, 0.0, (4.99, 0.0, 0.0), False),
        (1.0, 0.0, 0.0, (3.0, 4.0, 0.1), True),  # more than 5 m from the target
        (1.0, 0.0, 0.0, (np.nan, 0.0, 0.0), True),
    ],
)
def test_crash_conditions(z, roll, pitch, err, expected):
    s = np.zeros((1, 12))
    s[0, 2], s[0, 6], s[0, 7] = z, roll, pitch
    assert bool(crashed(s, np.array([err], float), CFG)[0]) is expected


def circle_state(x, y, vx, vy) -> np.ndarray:
    s = np.zeros((1, 12))
    s[0, [0, 1, 2, 3, 4]] = x, y, 1.0, vx, vy
    return s


def test_circle_errors_by_hand():
    # on the +x side of a 1 m circle, 5 cm outside, moving north at 0.4 m/s: counter-clockwise seen
    # from above, tangential speed +0.4
    e_r, e_v = circle_errors(circle_state(1.05, 0.0, 0.0, 0.4), np.zeros(2), 1.0, 0.5)
    np.testing.assert_allclose([e_r[0], e_v[0]], [0.05, -0.1], atol=1e-12)
    # moving south there is clockwise: tangential speed −0.4
    _, e_v = circle_errors(circle_state(1.05, 0.0, 0.0, -0.4), np.zeros(2), 1.0, 0.5)
    np.testing.assert_allclose(e_v, [-0.9], atol=1e-12)
    # at (0, 2) around the centre (0, 1), moving west: counter-clockwise, radial speed ignored
    e_r, e_v = circle_errors(circle_state(0.0, 2.0, -0.5, 0.3), np.array([0.0, 1.0]), 1.0, 0.5)
    np.testing.assert_allclose([e_r[0], e_v[0]], [0.0, 0.0], atol=1e-12)


def test_circle_reward_by_hand():
    """The hover reward towards the moving point plus 0.5·e^(−0.05²/0.1²) + 0.5·e^(−0.1²/0.2²),
    both 0.5·e^(−0.25) = 0.3894003915."""
    s = circle_state(1.05, 0.0, 0.0, 0.4)
    pos_error = np.array([[0.03, -0.04, 0.0]])  # hover part: 1.2775523443 (see test_hand_values)
    r = circle_reward(s, pos_error, np.array([False]), np.zeros(2), 1.0, 0.5, CFG)
    assert float(r[0]) == pytest.approx(1.2775523443 + 2 * 0.3894003915, abs=1e-9)
    r_crash = circle_reward(s, pos_error, np.array([True]), np.zeros(2), 1.0, 0.5, CFG)
    assert float(r_crash[0]) == pytest.approx(float(r[0]) - 10.0, abs=1e-12)
    # on the circle at the right speed, at the moving point: the maximum 1.5 + 0.5 + 0.5
    best = circle_reward(
        circle_state(1.0, 0.0, 0.0, 0.5), np.zeros((1, 3)), np.array([False]), np.zeros(2), 1.0, 0.5, CFG
    )
    assert float(best[0]) == pytest.approx(2.5, abs=1e-12)


@pytest.mark.parametrize(
    "z, roll, pitch, err, expected",
    [
        (0.0, 0.0, 0.0, (0.0, 0.0, 0.0), False),  # on the ground is not below it
        (0.5, 0.0, 0.0, (0.0, 0.0, 0.0), False),
        (-1e-9, 0.0, 0.0, (0.0, 0.0, 0.0), True),
        (1.0, math.radians(60.0), 0.0, (0.0, 0.0, 0.0), False),  # exactly 60° is not beyond it
        (1.0, 0.0, -math.radians(60.0), (0.0, 0.0, 0.0), False),
        (1.0, 0.0, 0.0, (3.0, 4.0, 0.0), False),  # exactly 5 m (d² = 25) is still inside
    ],
)
def test_crash_limits_are_strict(z, roll, pitch, err, expected):
    """A crash is altitude < 0, tilt > 60°, distance > 5 m: each boundary itself is not one."""
    s = np.zeros((1, 12))
    s[0, 2], s[0, 6], s[0, 7] = z, roll, pitch
    assert bool(crashed(s, np.array([err], float), CFG)[0]) is expected


def test_circle_errors_about_a_centre_off_both_axes():
    """Centre (2, −1), radius 1: the point (2.6, −0.2) is ρ = √(0.6² + 0.8²) = 1 from it (e_R = 0);
    moving with v = (−0.8, 0.6) it goes counter-clockwise at (0.6·0.6 − 0.8·(−0.8))/1 = 1.0 m/s."""
    e_r, e_v = circle_errors(circle_state(2.6, -0.2, -0.8, 0.6), np.array([2.0, -1.0]), 1.0, 0.25)
    np.testing.assert_allclose([e_r[0], e_v[0]], [0.0, 0.75], atol=1e-12)
