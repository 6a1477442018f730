"""The loop's timing in training (`core.timing`, `EnvConfig.timing`): what the delays do to the
environment, measured against the same environment without them.

- An observation delay of k whole steps shows the policy, at step t, the observation the undelayed
  environment showed at step t − k (the start's before that), and leaves the plant alone.
- An action delay of k whole steps makes the plant fly, from the same start, what the undelayed plant
  flies with the actions shifted by k steps (the start command first).
- A fractional action delay gives the zero-order-hold average of the two commands it falls between.
- Jitter never shows a state older than the one shown the step before.
- A configuration without timing draws exactly what it drew before the option existed (the pinned
  rollouts of test_env_bit_identity.py), and one with timing round-trips through JSON and quad-train.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from quadpilot.core.timing import PRESETS, DelayLine, TimingConfig
from quadpilot.train.envs import EnvConfig, QuadBatch, QuadVectorEnv, make_config

N, STEPS = 6, 40


def _batch(timing: TimingConfig | None, seed: int = 3) -> QuadBatch:
    b = QuadBatch(make_config("hover", timing=timing, dtype="float64"), N)
    b.reset(np.ones(N, bool), np.random.default_rng(seed))
    return b


def _actions(seed: int = 5) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-0.3, 0.3, (STEPS, N, 4))


def _fixed(action_ms: float = 0.0, obs_ms: float = 0.0, jitter_ms: float = 0.0) -> TimingConfig:
    return TimingConfig(
        action_delay_ms=(action_ms, action_ms), obs_delay_ms=(obs_ms, obs_ms), jitter_ms=(jitter_ms, jitter_ms)
    )


def test_an_observation_delay_shows_the_observation_of_k_steps_before() -> None:
    plain, late = _batch(None), _batch(_fixed(obs_ms=50.0))  # 5 steps at 100 Hz
    seen_plain, seen_late, states_plain, states_late = [plain.obs.copy()], [late.obs.copy()], [], []
    for a in _actions():
        seen_plain.append(plain.step(a)[0].copy())
        seen_late.append(late.step(a)[0].copy())
        states_plain.append(plain.state.copy())
        states_late.append(late.state.copy())
    np.testing.assert_array_equal(np.array(states_late), np.array(states_plain))  # the plant is the same
    for t in range(1, STEPS + 1):
        np.testing.assert_allclose(seen_late[t], seen_plain[max(0, t - 5)], rtol=0, atol=1e-6, err_msg=f"step {t}")
    assert not np.allclose(seen_late[STEPS], seen_plain[STEPS])


def test_an_action_delay_flies_the_actions_shifted() -> None:
    plain, late = _batch(None), _batch(_fixed(action_ms=30.0))  # 3 steps; the start command is hover
    acts = _actions()
    shifted = np.concatenate([np.zeros((3, N, 4)), acts[:-3]])
    for a_late, a_plain in zip(acts, shifted, strict=True):
        late.step(a_late)
        plain.step(a_plain)
        np.testing.assert_allclose(late.state, plain.state, rtol=0, atol=1e-9)


def test_a_fractional_action_delay_is_the_hold_average() -> None:
    line = DelayLine(_fixed(action_ms=25.0), 1, 4, 12, 0.01, np.float64)  # 2.5 steps
    line.reset(np.array([0]), np.random.default_rng(0), np.zeros((4, 1)), np.zeros((12, 1)))
    sent = [np.full((4, 1), float(i + 1)) for i in range(6)]
    got = [float(line.command(u)[0, 0]) for u in sent]
    # step t drives the rotors with u[t−3] for half the step and u[t−2] for the other half (0 before)
    assert got == [0.0, 0.0, 0.5, 1.5, 2.5, 3.5]


def test_jitter_never_shows_an_older_state_than_before() -> None:
    line = DelayLine(_fixed(obs_ms=40.0, jitter_ms=40.0), 64, 4, 12, 0.01, np.float64)
    line.reset(np.arange(64), np.random.default_rng(1), np.zeros((4, 64)), np.zeros((12, 64)))
    last = np.full(64, -np.inf)
    spread = set()
    for t in range(1, 200):
        line.command(np.zeros((4, 64)))
        seen = line.observed(np.full((12, 64), float(t)))[0]  # each state holds its step number
        assert np.all(seen >= last), t
        assert np.all(seen <= t) and np.all(seen >= t - 8)  # within the delay plus jitter (8 steps)
        spread.update((t - seen[seen > 0]).astype(int).tolist())
        last = seen
    assert len(spread) >= 5  # the jitter does spread the ages


def test_a_reset_starts_the_history_at_the_start() -> None:
    env = QuadVectorEnv(4, config=make_config("hover", timing=_fixed(action_ms=50.0, obs_ms=50.0)))
    obs, _ = env.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(700):  # past the first episode's end (500 steps), so each drone starts a second one
        obs, *_, infos = env.step(rng.uniform(-1, 1, (4, 4)))
        if "final_obs" in infos:
            done = infos["_final_obs"]
            b = env.batch
            # the new episode's first observation is of its start state, not of the last episode's
            np.testing.assert_array_equal(b.delay.count[done], 0)
            fresh = QuadBatch(b.cfg, 4)
            fresh.state = b.state.copy()
            fresh.target = b.target.copy()
            fresh.heading[:] = b.heading
            fresh.reset(np.zeros(4, bool), np.random.default_rng(0))
            fresh._observe(fresh._state.sync(), fresh._target.rows, fresh.obs, None, fresh.heading)
            np.testing.assert_allclose(obs[done], fresh.obs[done], atol=1e-6)
            return
    pytest.fail("no episode ended")


def test_timing_round_trips_and_is_checked() -> None:
    cfg = make_config("hover", timing="link")
    assert cfg.timing == PRESETS["link"]
    assert EnvConfig.from_json(cfg.to_json()).timing == cfg.timing
    assert EnvConfig.from_json({**cfg.to_json(), "timing": None}).timing is None
    for bad in ((-1.0, 2.0), (5.0, 1.0), (0.0, float("nan")), (0.0, 900.0), "x"):
        with pytest.raises(ValueError, match="timing"):
            TimingConfig(action_delay_ms=bad)
    with pytest.raises(ValueError, match="unknown timing field"):
        TimingConfig.from_json({"delay": [0, 1]})
    with pytest.raises(ValueError, match="unknown timing preset"):
        make_config("hover", timing="radio")


def test_no_timing_draws_what_it_drew_before() -> None:
    """An inactive timing ("none") makes no delay line and draws nothing: the same episodes bit for bit."""
    a, b = _batch(None), _batch(PRESETS["none"])
    assert b.delay is None
    for act in _actions():
        np.testing.assert_array_equal(a.step(act)[0], b.step(act)[0])


def test_the_link_preset_changes_the_episodes() -> None:
    a, b = _batch(None), _batch(dataclasses.replace(PRESETS["link"]))
    assert b.delay is not None
    for act in _actions():
        a.step(act)
        b.step(act)
    assert not np.allclose(a.state, b.state)


def test_a_fractional_observation_delay_is_as_old_on_average() -> None:
    """25 ms at 100 Hz: the state of 2 or of 3 steps ago, each about half the time."""
    line = DelayLine(_fixed(obs_ms=25.0), 64, 4, 12, 0.01, np.float64)
    line.reset(np.arange(64), np.random.default_rng(4), np.zeros((4, 64)), np.zeros((12, 64)))
    ages = []
    for t in range(1, 200):
        line.command(np.zeros((4, 64)))
        seen = line.observed(np.full((12, 64), float(t)))[0]
        if t > 5:
            ages.append(t - seen)
    ages = np.concatenate(ages)
    assert set(np.unique(ages)) == {2.0, 3.0}
    assert abs(ages.mean() - 2.5) < 0.05
