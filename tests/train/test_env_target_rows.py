"""`QuadBatch.target` reads and writes as an (N, 3) array while the batch keeps the targets as rows
(3, N) (`batch._Rows`, as for `state` and `rotor`): a target written through the array, in place or
by assignment, is the one the next step's reward and observation measure the position error to, and
a reset that draws new targets (waypoint) puts them where the step reads them."""

from __future__ import annotations

import numpy as np
import pytest

from quadpilot.core import dynamics
from quadpilot.core.mission import yaw_errors
from quadpilot.core.observation import build_observation
from quadpilot.core.reward import crashed, hover_reward
from quadpilot.train.envs import QuadBatch, make_config

N = 16


def expected(batch: QuadBatch, state: np.ndarray, rotor: np.ndarray, target: np.ndarray, action: np.ndarray):
    """The step of `batch` from (state, rotor) towards `target` as the allocating functions compute
    it: (observation, reward)."""
    cfg = batch.cfg
    command = dynamics.action_to_command(action, batch.u_hover)
    new_state, _ = dynamics.step(state, rotor, command, batch.params, cfg.dt, cfg.substeps)
    obs = build_observation(new_state, target, heading=batch.heading)
    pos_err = new_state[:, 0:3] - target
    crash = crashed(new_state, pos_err, cfg.reward)
    heading_error = yaw_errors(new_state, batch.heading)[1]
    return obs, hover_reward(new_state, pos_err, crash, cfg.reward, heading_error)


@pytest.mark.parametrize("how", ["in place", "by assignment"])
def test_a_target_written_through_the_array_is_what_the_next_step_measures_to(how):
    cfg = make_config("hover")
    batch = QuadBatch(cfg, N)
    batch.reset(np.ones(N, bool), np.random.default_rng(1))
    batch.step(np.zeros((N, 4), np.float32))
    new_target = (batch.target + np.random.default_rng(2).uniform(-0.5, 0.5, (N, 3))).astype(np.float32)
    if how == "in place":
        batch.target[:] = new_target
    else:
        batch.target = new_target.copy()
    action = np.random.default_rng(3).uniform(-1, 1, (N, 4)).astype(np.float32)
    want_obs, want_reward = expected(batch, batch.state, batch.rotor, new_target, action)
    obs, reward, *_ = batch.step(action)
    assert obs.tobytes() == want_obs.tobytes()
    assert reward.tobytes() == want_reward.astype(np.float32).tobytes()
    assert np.array_equal(batch.target, new_target)


def test_a_reset_puts_its_new_targets_where_the_step_reads_them():
    cfg = make_config("waypoint")
    batch = QuadBatch(cfg, N)
    batch.reset(np.ones(N, bool), np.random.default_rng(4))
    before = batch.target.copy()
    batch.reset(np.arange(N) < 5, np.random.default_rng(5))  # new targets for five drones
    target = batch.target.copy()
    assert not np.array_equal(target[:5], before[:5]) and np.array_equal(target[5:], before[5:])
    action = np.random.default_rng(6).uniform(-1, 1, (N, 4)).astype(np.float32)
    want_obs, _ = expected(batch, batch.state, batch.rotor, target, action)
    assert batch.step(action)[0].tobytes() == want_obs.tobytes()
