"""GAE (Schulman et al. 2016, eq. 16) against a hand-computed case and a per-drone reference loop;
termination never bootstraps, truncation bootstraps from the final observation's value."""

import numpy as np
import pytest

from quadpilot.train.ppo.gae import compute_gae


def reference_gae(rewards, values, next_values, terminated, truncated, gamma, lam):
    """The textbook recursion, one drone and one step at a time, in plain Python floats."""
    T, N = rewards.shape
    adv = np.zeros((T, N))
    for i in range(N):
        running = 0.0
        for t in reversed(range(T)):
            bootstrap = 0.0 if terminated[t, i] else gamma * next_values[t, i]
            delta = rewards[t, i] + bootstrap - values[t, i]
            if terminated[t, i] or truncated[t, i]:
                running = 0.0  # the next step belongs to another episode
            running = delta + gamma * lam * running
            adv[t, i] = running
    return adv, adv + values


def col(*x, dtype=float):
    return np.array(x, dtype=dtype).reshape(-1, 1)


def test_hand_computed_three_steps_with_a_truncation_and_a_termination():
    # step 0 ends by the time limit (final state worth 4.0), step 1 is ordinary, step 2 crashes
    gamma, lam = 0.9, 0.8
    r = col(1.0, 2.0, 3.0)
    v = col(0.5, 1.0, 1.5)
    next_v = col(4.0, 1.5, 7.0)  # 7.0 after the crash must be ignored
    term = col(False, False, True, dtype=bool)
    trunc = col(True, False, False, dtype=bool)
    adv, ret = compute_gae(r, v, next_v, term, trunc, gamma, lam)
    d0 = 1.0 + 0.9 * 4.0 - 0.5  # 4.1: bootstraps from the final observation, then the trace stops
    d1 = 2.0 + 0.9 * 1.5 - 1.0  # 2.35
    d2 = 3.0 - 1.5  # 1.5: no bootstrap after a crash
    expected = [d0, d1 + 0.9 * 0.8 * d2, d2]  # [4.1, 3.43, 1.5]
    np.testing.assert_allclose(adv[:, 0], expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ret[:, 0], np.array(expected) + v[:, 0], rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_a_per_drone_reference_loop_on_random_data(seed):
    rng = np.random.default_rng(seed)
    T, N = 37, 11
    r, v, nv = rng.normal(size=(3, T, N))
    term = rng.random((T, N)) < 0.1
    trunc = (rng.random((T, N)) < 0.1) & ~term
    adv, ret = compute_gae(r, v, nv, term, trunc, 0.99, 0.95)
    ref_adv, ref_ret = reference_gae(r, v, nv, term, trunc, 0.99, 0.95)
    np.testing.assert_allclose(adv, ref_adv, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ret, ref_ret, rtol=1e-12, atol=1e-12)


def test_last_step_advantage_is_the_td_error():
    """The course brief's check: nothing follows the rollout's last step, so Â_T = δ_T."""
    rng = np.random.default_rng(3)
    T, N, gamma = 16, 8, 0.99
    r, v, nv = rng.normal(size=(3, T, N))
    term = rng.random((T, N)) < 0.3
    trunc = (rng.random((T, N)) < 0.3) & ~term
    adv, _ = compute_gae(r, v, nv, term, trunc, gamma, 0.95)
    delta_T = r[-1] + gamma * (1.0 - term[-1]) * nv[-1] - v[-1]
    np.testing.assert_allclose(adv[-1], delta_T, rtol=0, atol=1e-12)


def test_truncation_bootstraps_from_next_values_but_termination_does_not():
    r, v = np.zeros((1, 2)), np.zeros((1, 2))
    term = np.array([[True, False]])
    trunc = np.array([[False, True]])
    low, _ = compute_gae(r, v, np.full((1, 2), 1.0), term, trunc, 0.9, 0.95)
    high, _ = compute_gae(r, v, np.full((1, 2), 5.0), term, trunc, 0.9, 0.95)
    assert low[0, 0] == high[0, 0] == 0.0  # terminated: the next value is never used
    assert low[0, 1] == pytest.approx(0.9) and high[0, 1] == pytest.approx(4.5)  # truncated: γ·V(final obs)


def test_done_cuts_the_trace_to_the_following_step():
    # step 0 ends an episode; a large advantage at step 1 (next episode) must not leak into step 0
    r = np.array([[0.0], [10.0]])
    v = np.zeros((2, 1))
    for term0, trunc0 in ((True, False), (False, True)):
        term = np.array([[term0], [False]])
        trunc = np.array([[trunc0], [False]])
        adv, _ = compute_gae(r, v, np.zeros((2, 1)), term, trunc, 0.99, 0.95)
        assert adv[0, 0] == 0.0 and adv[1, 0] == 10.0


def test_rejects_mismatched_shapes():
    a = np.zeros((4, 2))
    with pytest.raises(ValueError, match=r"\(T, N\)"):
        compute_gae(a, a, np.zeros((4, 3)), a.astype(bool), a.astype(bool))
