"""A short observation/action history as the input of a feed-forward policy (`PPOConfig.obs_history`).

With a history of k, the network sees, per drone,

    [o_t, a_{t−1}, o_{t−1}, a_{t−2}, …, o_{t−k+1}, a_{t−k}]        (k·(obs_dim + 4) numbers)

where a is the action the environment applied (clipped to [−1, 1]). At the start of an episode the
history is filled with the first observation and zero actions (hover trim). Frame stacking is the
cheap alternative to a recurrent network (Mnih et al. 2015 stacked 4 Atari frames); with motor lag
the past actions tell the policy where the rotors are, which the observation does not.

`History` is the batched buffer (NumPy); `HistoryVectorEnv` wraps the vector environment so that
PPO trains an MLP on the stacked input unchanged. The runtime and ONNX export know only the plain
observation layouts, so history models are evaluated in-process (`evaluate`), not exported.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from quadpilot.core.params import NUM_MOTORS as ACT_DIM  # the action is one command a rotor


def history_dim(obs_dim: int, k: int) -> int:
    """Width of the stacked input for a history of k (k = 1: the observation alone)."""
    return obs_dim if k <= 1 else k * (obs_dim + ACT_DIM)


def network_input_dim(obs_dim: int, ppo_cfg) -> int:
    """What the actor and critic take for a PPOConfig (its obs_history)."""
    return history_dim(obs_dim, getattr(ppo_cfg, "obs_history", 1))


class History:
    """Per-drone ring of the last k (observation, previous action) frames, newest first."""

    def __init__(self, n: int, obs_dim: int, k: int) -> None:
        if k < 2:
            raise ValueError(f"a history needs k ≥ 2 frames, got {k}")
        self.n, self.obs_dim, self.k = n, obs_dim, k
        self.buf = np.zeros((n, k, obs_dim + ACT_DIM), np.float32)

    def reset(self, mask, obs: np.ndarray) -> None:
        """Drones `mask` start an episode with observation `obs` (n, obs_dim) (only their rows are read)."""
        idx = np.flatnonzero(mask)
        self.buf[idx] = 0.0
        self.buf[idx, :, : self.obs_dim] = obs[idx, None, :]

    def push(self, obs: np.ndarray, action: np.ndarray) -> None:
        """Every drone moves on: newest frame (obs (n, obs_dim), the action (n, 4) that led to it)."""
        self.buf[:, 1:] = self.buf[:, :-1]
        self.buf[:, 0, : self.obs_dim] = obs
        self.buf[:, 0, self.obs_dim :] = action

    def peek(self, obs: np.ndarray, action: np.ndarray, idx) -> np.ndarray:
        """The stacked input drones `idx` would have after `push(obs, action)` (their rows of obs
        and action given), without changing the buffer: the final observation of an ended episode."""
        rows = self.buf[idx]
        out = np.empty_like(rows)
        out[:, 1:] = rows[:, :-1]
        out[:, 0, : self.obs_dim] = obs
        out[:, 0, self.obs_dim :] = action
        return out.reshape(len(out), -1)

    def stacked(self) -> np.ndarray:
        """(n, k·(obs_dim + 4)) float32, a copy."""
        return self.buf.reshape(self.n, -1).copy()


class HistoryVectorEnv:
    """`QuadVectorEnv` with observations replaced by the stacked history (same-step autoreset kept:
    `infos["final_obs"]` holds the stacked final observation of the drones whose episode ended).

    Forwards what PPO and checkpoints use of the inner environment (`batch`, `rng`, `started`,
    `cfg`, `num_envs`, `set_target_radius`)."""

    def __init__(self, env, k: int) -> None:
        self.env, self.k = env, k
        self.num_envs = env.num_envs
        self.cfg = env.cfg
        self.history = History(env.num_envs, env.cfg.layout.dim, k)

    # forwarded state (a resumed trainer writes rng and started)
    batch = property(lambda self: self.env.batch)
    rng = property(lambda self: self.env.rng, lambda self, v: setattr(self.env, "rng", v))
    started = property(lambda self: self.env.started, lambda self, v: setattr(self.env, "started", v))

    def set_target_radius(self, radius: float) -> None:
        self.env.set_target_radius(radius)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.history.reset(np.ones(self.num_envs, bool), obs)
        return self.history.stacked(), info

    def step(self, actions):
        applied = np.clip(np.asarray(actions, np.float32), -1.0, 1.0)
        obs, reward, term, trunc, infos = self.env.step(actions)
        out: dict[str, Any] = dict(infos)
        if "_final_obs" in infos:
            done = infos["_final_obs"]
            final = np.zeros((self.num_envs, self.history.buf[0].size), np.float32)
            idx = np.flatnonzero(done)
            final[idx] = self.history.peek(infos["final_obs"][idx], applied[idx], idx)
            out["final_obs"] = final
        self.history.push(obs, applied)
        if "_final_obs" in infos:
            self.history.reset(infos["_final_obs"], obs)
        return self.history.stacked(), reward, term, trunc, out

    def state_dict(self) -> dict:
        return {"buf": self.history.buf.copy()}

    def load_state_dict(self, d: dict) -> None:
        buf = np.asarray(d["buf"], np.float32)
        if buf.shape != self.history.buf.shape:
            raise ValueError(f"history of shape {buf.shape}, expected {self.history.buf.shape}")
        self.history.buf = buf.copy()
