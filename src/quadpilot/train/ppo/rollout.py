"""What every PPO variant (`ppo.FeedForwardPPO`, `ppo.TorchPPO`, `ppo.RecurrentPPO`) shares around its own maths: the
rollout's buffers, the minibatch indices of an epoch and the health metrics of an update.

The advantage estimate with its bootstrap on truncation is `gae.bootstrapped_gae`; the loop that
uses all of them is `ppo.PPO.update`.
"""

from __future__ import annotations

import numpy as np
import torch

STAT_KEYS = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction", "grad_norm")
"""The health metrics of one gradient step, in the order a variant's `_gradient_step` returns them
(docs/architecture.md style rule 5)."""


class RolloutBuffer:
    """One rollout of T steps over n drones, as PPO's Algorithm 1 collects it (arXiv:1707.06347):
    network inputs `obs` (T, n, obs_dim) float32, actions `act` (T, n, 4) float32, log π_θold(a|s)
    `logp` (T, n) float32, V(s_0 … s_T) `val` (T + 1, n), rewards `rew`, terminated `term` and
    truncated `trunc` (T, n), and `final_val` (T, n): V of the final observation of an episode cut by
    the time limit at that step (the bootstrap; zero elsewhere). `raw_seen` collects the raw
    observations the normaliser learns from; `env_s` the time spent inside `env.step`."""

    def __init__(self, steps: int, n: int, obs_dim: int, first_raw: np.ndarray) -> None:
        self.obs = np.zeros((steps, n, obs_dim), np.float32)
        self.act = np.zeros((steps, n, 4), np.float32)
        self.logp = np.zeros((steps, n), np.float32)
        self.val = np.zeros((steps + 1, n))
        self.rew = np.zeros((steps, n))
        self.term = np.zeros((steps, n), bool)
        self.trunc = np.zeros((steps, n), bool)
        self.final_val = np.zeros((steps, n))
        self.raw_seen = [first_raw]
        self.env_s = 0.0

    def record_step(self, t: int, reward, term, trunc) -> None:
        self.rew[t], self.term[t], self.trunc[t] = reward, term, trunc


def minibatches(usable: torch.Tensor, per_minibatch: int, generator: torch.Generator) -> list[torch.Tensor]:
    """Index tensors for one epoch: the `usable` indices (transitions, or whole sequences of a
    recurrent policy) shuffled and cut into groups of `per_minibatch`; a remainder smaller than that
    is dropped (a different one each epoch). One `torch.randperm` per epoch, always drawn."""
    size = usable.numel()
    perm = usable[torch.randperm(size, generator=generator)]
    mb = min(per_minibatch, size)
    if mb == 0:
        return []
    return [perm[s : s + mb] for s in range(0, size - mb + 1, mb)]


class UpdateStats:
    """The health metrics of one update: each gradient step's (`STAT_KEYS` order), averaged at the
    end, and the steps skipped for a non-finite loss or gradient norm."""

    def __init__(self) -> None:
        self.steps: dict[str, list[float]] = {k: [] for k in STAT_KEYS}
        self.skipped = 0

    def add(self, step: tuple[float, ...] | None) -> None:
        if step is None:
            self.skipped += 1
            return
        for k, x in zip(STAT_KEYS, step, strict=True):
            self.steps[k].append(x)

    def kl_above(self, target_kl: float | None) -> bool:
        """The early stop between epochs: the last step's approx_kl above target_kl."""
        kl = self.steps["approx_kl"]
        return target_kl is not None and bool(kl) and kl[-1] > target_kl

    def summary(self, returns: torch.Tensor, values: torch.Tensor) -> dict[str, float]:
        """Means of the step metrics (NaN without steps) and the explained variance of the values
        against the returns, 1 − Var[R − V]/Var[R] (NaN when Var[R] is not positive)."""
        var_y = returns.var().item() if returns.numel() > 1 else float("nan")
        out = {k: float(np.mean(s)) if s else float("nan") for k, s in self.steps.items()}
        out["explained_variance"] = float("nan") if not var_y > 0 else 1.0 - (returns - values).var().item() / var_y
        return out
