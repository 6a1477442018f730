"""Oracle tests of Generalised Advantage Estimation (Schulman et al. 2016, eqs. 10 and 16) against
numbers worked out by hand, and of how the PPO trainer feeds it (truncation bootstraps from the final
observation's value, termination does not, rewards are scaled first).

    δ_t = r_t + γ·(1 − terminated_t)·V(s_{t+1}) − V(s_t)
    Â_t = δ_t + γλ·(1 − done_t)·Â_{t+1}
    R_t = Â_t + V(s_t)
"""

import numpy as np
import pytest

from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPO, PPOConfig
from quadpilot.train.ppo.gae import compute_gae

GAMMA, LAM = 0.9, 0.8  # γλ = 0.72

# Two drones, four steps. Columns are drones.
# Drone 0 crashes (terminated) at t = 1; drone 1 hits the time limit (truncated) at t = 2.
REWARDS = np.array([[1.0, 0.5], [0.0, 0.5], [2.0, 0.5], [1.0, 0.5]])
VALUES = np.array([[0.5, 1.0], [1.0, 2.0], [1.5, 0.0], [0.2, 1.0]])  # V(s_t)
V_LAST = np.array([0.7, -1.0])  # V(s_T), the observation after the rollout
FINAL_OBS_VALUE = 3.0  # V of drone 1's final observation at its truncation (t = 2)
TERMINATED = np.array([[False, False], [True, False], [False, False], [False, False]])
TRUNCATED = np.array([[False, False], [False, False], [False, True], [False, False]])
# V of the state reached after step t. After drone 0's crash the vector env resets it, so the
# "next" value there (1.5) is the new episode's and must be ignored; after drone 1's truncation the
# state reached is the final observation (value 3.0), not the reset one (VALUES[3, 1] = 1.0).
NEXT_VALUES = np.array([[1.0, 2.0], [1.5, 0.0], [0.2, FINAL_OBS_VALUE], [0.7, -1.0]])

# Hand computation, drone 0:
#   δ0 = 1 + 0.9·1.0 − 0.5 = 1.4      δ1 = 0 + 0 − 1.0 = −1.0 (terminated: no bootstrap)
#   δ2 = 2 + 0.9·0.2 − 1.5 = 0.68     δ3 = 1 + 0.9·0.7 − 0.2 = 1.43
#   Â3 = 1.43;  Â2 = 0.68 + 0.72·1.43 = 1.7096;  Â1 = −1.0 (done: trace cut);  Â0 = 1.4 + 0.72·(−1.0) = 0.68
# drone 1:
#   δ0 = 0.5 + 0.9·2.0 − 1.0 = 1.3    δ1 = 0.5 + 0.9·0.0 − 2.0 = −1.5
#   δ2 = 0.5 + 0.9·3.0 − 0.0 = 3.2 (truncated: bootstrap from the final observation)
#   δ3 = 0.5 + 0.9·(−1.0) − 1.0 = −1.4
#   Â3 = −1.4;  Â2 = 3.2 (done: trace cut);  Â1 = −1.5 + 0.72·3.2 = 0.804;  Â0 = 1.3 + 0.72·0.804 = 1.87888
DELTAS = np.array([[1.4, 1.3], [-1.0, -1.5], [0.68, 3.2], [1.43, -1.4]])
ADVANTAGES = np.array([[0.68, 1.87888], [-1.0, 0.804], [1.7096, 3.2], [1.43, -1.4]])
RETURNS = ADVANTAGES + VALUES  # [[1.18, 2.87888], [0.0, 2.804], [3.2096, 3.2], [1.63, -0.4]]


def test_hand_computed_rollout_with_a_termination_and_a_truncation():
    adv, ret = compute_gae(REWARDS, VALUES, NEXT_VALUES, TERMINATED, TRUNCATED, GAMMA, LAM)
    np.testing.assert_allclose(adv, ADVANTAGES, rtol=0, atol=1e-6)
    np.testing.assert_allclose(ret, RETURNS, rtol=0, atol=1e-6)
    np.testing.assert_allclose(ret[:, 0], [1.18, 0.0, 3.2096, 1.63], rtol=0, atol=1e-6)
    np.testing.assert_allclose(ret[:, 1], [2.87888, 2.804, 3.2, -0.4], rtol=0, atol=1e-6)


def test_lambda_zero_is_the_one_step_td_error():
    adv, ret = compute_gae(REWARDS, VALUES, NEXT_VALUES, TERMINATED, TRUNCATED, GAMMA, 0.0)
    np.testing.assert_allclose(adv, DELTAS, rtol=0, atol=1e-6)
    # the one-step TD target r + γ·V(s') (no bootstrap after the crash)
    np.testing.assert_allclose(ret, DELTAS + VALUES, rtol=0, atol=1e-6)
    np.testing.assert_allclose(ret[1, 0], 0.0, atol=1e-12)


def test_lambda_one_gamma_one_is_monte_carlo_return_minus_value():
    # one drone, two episodes in the rollout: a crash at t = 1, then one that crashes at t = 4
    r = np.array([[1.0], [2.0], [3.0], [4.0], [5.0]])
    v = np.array([[0.5], [-1.0], [2.0], [0.0], [1.0]])
    nv = np.array([[-1.0], [9.0], [0.0], [1.0], [9.0]])  # the 9s follow crashes and must be ignored
    term = np.array([[False], [True], [False], [False], [True]])
    trunc = np.zeros_like(term)
    adv, ret = compute_gae(r, v, nv, term, trunc, gamma=1.0, lam=1.0)
    mc = np.array([[1.0 + 2.0], [2.0], [3.0 + 4.0 + 5.0], [4.0 + 5.0], [5.0]])  # undiscounted sums to the crash
    np.testing.assert_allclose(ret, mc, rtol=0, atol=1e-9)
    np.testing.assert_allclose(adv, mc - v, rtol=0, atol=1e-9)


def test_lambda_one_is_the_discounted_monte_carlo_return():
    r = np.array([[1.0], [2.0], [3.0], [4.0]])
    v = np.array([[10.0], [20.0], [30.0], [40.0]])
    nv = np.array([[20.0], [30.0], [40.0], [0.0]])
    term = np.array([[False], [False], [False], [True]])
    adv, ret = compute_gae(r, v, nv, term, np.zeros_like(term), gamma=0.5, lam=1.0)
    # G0 = 1 + 0.5·2 + 0.25·3 + 0.125·4 = 3.25;  G1 = 2 + 1.5 + 1 = 4.5;  G2 = 3 + 2 = 5;  G3 = 4
    np.testing.assert_allclose(ret[:, 0], [3.25, 4.5, 5.0, 4.0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(adv[:, 0], [3.25 - 10, 4.5 - 20, 5.0 - 30, 4.0 - 40], rtol=0, atol=1e-9)


def test_lambda_is_used():
    """Two λ give the numbers each predicts; a GAE that ignores λ (or uses γ in its place) gives
    the same advantages for both."""
    r = np.array([[0.0], [0.0], [1.0]])
    v = np.zeros((3, 1))
    nv = np.zeros((3, 1))
    no = np.zeros((3, 1), bool)
    for lam, expected_a0 in ((0.5, 1.0 * (1.0 * 0.5) ** 2), (0.25, 1.0 * (1.0 * 0.25) ** 2)):
        adv, _ = compute_gae(r, v, nv, no, no, gamma=1.0, lam=lam)
        # only δ2 = 1 is non-zero, so Â0 = (γλ)²·δ2, Â1 = γλ·δ2
        np.testing.assert_allclose(adv[:, 0], [expected_a0, lam, 1.0], rtol=0, atol=1e-12)


def test_gamma_is_used():
    """With λ = 1 and zero values the advantage is the discounted reward-to-go: Â0 = γ²·r2."""
    r = np.array([[0.0], [0.0], [1.0]])
    z = np.zeros((3, 1))
    no = np.zeros((3, 1), bool)
    for gamma in (0.5, 0.9):
        adv, _ = compute_gae(r, z, z, no, no, gamma=gamma, lam=1.0)
        np.testing.assert_allclose(adv[:, 0], [gamma**2, gamma, 1.0], rtol=0, atol=1e-12)
    # γ also discounts the bootstrap inside δ: r = 0, V(s') = 1 → δ = γ
    adv, _ = compute_gae(z[:1], z[:1], np.ones((1, 1)), no[:1], no[:1], gamma=0.7, lam=0.95)
    np.testing.assert_allclose(adv, [[0.7]], rtol=0, atol=1e-12)


@pytest.mark.parametrize("kind", ["terminated", "truncated"])
def test_a_done_step_cuts_the_trace(kind):
    """A reward after the end of an episode must not leak into the advantage of the steps before it."""
    r = np.array([[0.0], [0.0], [100.0]])
    z = np.zeros((3, 1))
    done = np.array([[False], [True], [False]])
    no = np.zeros_like(done)
    term, trunc = (done, no) if kind == "terminated" else (no, done)
    adv, _ = compute_gae(r, z, z, term, trunc, gamma=0.9, lam=0.9)
    np.testing.assert_allclose(adv[:, 0], [0.0, 0.0, 100.0], rtol=0, atol=1e-12)


def test_termination_does_not_bootstrap_but_truncation_does():
    r = np.zeros((1, 2))
    v = np.zeros((1, 2))
    nv = np.full((1, 2), 5.0)
    term = np.array([[True, False]])
    trunc = np.array([[False, True]])
    adv, ret = compute_gae(r, v, nv, term, trunc, gamma=0.9, lam=0.95)
    np.testing.assert_allclose(adv, [[0.0, 4.5]], rtol=0, atol=1e-12)
    np.testing.assert_allclose(ret, [[0.0, 4.5]], rtol=0, atol=1e-12)  # V = 0: the return is 0.9·5 or nothing
    # terminated and truncated in the same step: termination wins, no bootstrap
    adv, _ = compute_gae(r, v, nv, np.array([[True, True]]), np.array([[True, True]]), gamma=0.9, lam=0.95)
    np.testing.assert_allclose(adv, [[0.0, 0.0]], rtol=0, atol=1e-12)


def test_the_trainer_bootstraps_truncations_from_the_final_observation_and_scales_rewards():
    """PPO._finish_rollout builds next values from the rollout's V(s_0..s_T) and the values of the
    final observations of truncated episodes, scales rewards by reward_scale and calls GAE with the
    configured γ and λ: the hand-computed rollout above, fed as the trainer holds it."""
    cfg = PPOConfig(num_envs=2, rollout_steps=4, gamma=GAMMA, lam=LAM, reward_scale=0.5, threads=1, seed=0)
    ppo = PPO(cfg, make_config("hover", episode_steps=8))
    val = np.vstack([VALUES, V_LAST])  # (T + 1, N): V(s_t) as collected, reset observations included
    final_val = np.zeros((4, 2))
    final_val[2, 1] = FINAL_OBS_VALUE
    final_val[1, 0] = 99.0  # never read: drone 0's step 1 ended in a crash, not a truncation
    adv, ret = ppo._finish_rollout([], REWARDS / 0.5, val, final_val, TERMINATED, TRUNCATED, 0.0)
    np.testing.assert_allclose(adv, ADVANTAGES, rtol=0, atol=1e-6)
    np.testing.assert_allclose(ret, RETURNS, rtol=0, atol=1e-6)
    assert ppo.global_step == 8


def test_the_defaults_are_gamma_0_99_and_lambda_0_95():
    """Called without γ and λ, GAE uses the paper's γ = 0.99, λ = 0.95 (γλ = 0.9405): with only
    δ2 = 1 non-zero, Â = ((γλ)², γλ, 1); one bootstrapped step of V(s') = 1 gives δ = γ = 0.99."""
    r = np.array([[0.0], [0.0], [1.0]])
    z = np.zeros((3, 1))
    no = np.zeros((3, 1), bool)
    adv, ret = compute_gae(r, z, z, no, no)
    np.testing.assert_allclose(adv[:, 0], [0.88454025, 0.9405, 1.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(ret, adv, rtol=0, atol=0)
    adv, _ = compute_gae(z[:1], z[:1], np.ones((1, 1)), no[:1], no[:1])
    np.testing.assert_allclose(adv, [[0.99]], rtol=0, atol=1e-12)
