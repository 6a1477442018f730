"""The deterministic policy of a trained network, stateful or not: what evaluation, export and a
loaded checkpoint use (`ppo.PPO.act_deterministic`, `runs.checkpoint.TrainedPolicy`).

A stateless callable for an MLP, `initial_state(n)` / `step(obs, state)` for an LSTM or an
observation history (`envs.history`).
"""

from __future__ import annotations

import numpy as np
import torch

from ..envs.history import History


class _HistoryState:
    """What a history policy carries between steps: the frames and the last action."""

    def __init__(self, n: int, obs_dim: int, k: int) -> None:
        self.history = History(n, obs_dim, k)
        self.last_action = np.zeros((n, 4), np.float32)
        self.started = False

    def advance(self, raw_obs: np.ndarray) -> np.ndarray:
        if not self.started:
            self.history.reset(np.ones(self.history.n, bool), raw_obs)
            self.started = True
        else:
            self.history.push(raw_obs, self.last_action)
        return self.history.stacked()


class DeterministicActor:
    """The deterministic (clipped mean) action of a network, from raw observations (N, obs_dim):

    - MLP: `actor(obs)` → actions (N, 4), stateless (`stateful` False);
    - LSTM or observation history: `initial_state(n)` then `step(obs, state)` → (actions, state),
      one call per control step, state zeroed/refilled at the start (`stateful` True).

    `normalize` maps the network's raw input (the stacked history, if any) to what it was trained on."""

    def __init__(self, model, normalize, obs_dim: int, obs_history: int = 1) -> None:
        self.model, self.normalize = model, normalize
        self.obs_dim, self.k = obs_dim, obs_history
        self.lstm = bool(getattr(model, "recurrent", False))
        self.stateful = self.lstm or obs_history > 1

    def network_input(self, raw: np.ndarray) -> torch.Tensor:
        """The network's input for raw observations: normalised as in training, float32."""
        return torch.from_numpy(np.ascontiguousarray(self.normalize(raw), np.float32))

    @torch.inference_mode()
    def __call__(self, raw_obs: np.ndarray) -> np.ndarray:
        if self.stateful:
            raise TypeError("a recurrent or history policy keeps state: use initial_state() and step()")
        return self.model.mean_action(self.network_input(raw_obs)).numpy()

    def initial_state(self, n: int):
        if self.lstm:
            return self.model.initial_state(n)
        if self.k > 1:
            return _HistoryState(n, self.obs_dim, self.k)
        return None

    @torch.inference_mode()
    def step(self, raw_obs: np.ndarray, state):
        if self.lstm:
            action, state = self.model.mean_action_step(self.network_input(raw_obs), state)
            return action.numpy(), state
        if self.k > 1:
            action = self.model.mean_action(self.network_input(state.advance(raw_obs))).numpy()
            state.last_action = action
            return action, state
        return self(raw_obs), state
