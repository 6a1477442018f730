"""Recurrent PPO: the sequences `ppo.RecurrentPPO` (the PPO variant for `arch="lstm"`,
`networks.RecurrentActorCritic`) collects and trains on.

What changes against the feed-forward PPO (the objective, GAE and the health metrics do not):

- **Rollout.** Each drone carries the (h, c) state of the actor LSTM and of the critic LSTM from
  step to step and from one rollout to the next; the state is zeroed before the first step of every
  episode (`start` flags: an episode starts at the step after one ended, the vector env resets
  in the same step). The value of a truncated episode's final observation continues the critic's
  state of that episode. GAE is unchanged, per drone along the rollout.
- **Sequences and truncated backprop through time.** Each drone's T-step rollout is cut into
  T/L sequences of L = `bptt_steps` consecutive steps (L = T by default: one sequence per drone
  and rollout). With every sequence the rollout stores the LSTM states it started from (as they
  were at collection, before that step's reset mask) and the start flags of its steps, so the
  update replays the sequence exactly as it was collected: before the first gradient step the
  recomputed log-probabilities equal the stored ones (a test checks it). Gradients flow through
  at most L steps; the stored initial state is a constant (it was computed with older weights,
  the usual approximation of recurrent PPO, e.g. Kapturowski et al. 2019 "stored state").
- **Minibatches over whole drones.** A minibatch is a set of whole sequences
  (`minibatch_size // L` of them), shuffled each epoch; the losses average over their L·B steps.

The update is the torch loss of the feed-forward reference (`loss.gradient_step`) on the
replayed sequences, inside the loop every variant shares (`ppo.PPO.update`).
"""

from __future__ import annotations

import numpy as np
import torch

STATE_KEYS = ("actor_h", "actor_c", "critic_h", "critic_c")


# --- sequences ------------------------------------------------------------------------------


def to_sequences(a, length: int):
    """(T, N, ...) → (L, T/L·N, ...): sequence j = chunk j // N of drone j % N, its L steps in order.
    Works on NumPy arrays and tensors."""
    t, n = a.shape[0], a.shape[1]
    if t % length:
        raise ValueError(f"a rollout of {t} steps does not split into sequences of {length}")
    chunks = t // length
    rest = tuple(a.shape[2:])
    a = a.reshape(chunks, length, n, *rest)
    a = a.transpose(0, 1) if isinstance(a, torch.Tensor) else a.swapaxes(0, 1)
    return a.reshape(length, chunks * n, *rest)


def from_sequences(a, steps: int):
    """The inverse of `to_sequences`: (L, T/L·N, ...) → (T, N, ...)."""
    length, s = a.shape[0], a.shape[1]
    chunks = steps // length
    n = s // chunks
    rest = tuple(a.shape[2:])
    a = a.reshape(length, chunks, n, *rest)
    a = a.transpose(0, 1) if isinstance(a, torch.Tensor) else a.swapaxes(0, 1)
    return a.reshape(steps, n, *rest)


def initial_rollout_state(model, n: int) -> dict:
    """Zero LSTM states for n drones, every drone at the start of an episode."""
    ah, ac = model.initial_state(n)
    ch, cc = model.initial_state(n)
    return {"actor_h": ah, "actor_c": ac, "critic_h": ch, "critic_c": cc, "start": np.ones(n, bool)}


# --- update ---------------------------------------------------------------------------------


def finite_sequences(batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """(S,) bool: sequences whose every float entry (and initial state) is finite."""
    ok = None
    for k, v in batch.items():
        if k == "starts":
            continue
        f = torch.isfinite(v)
        f = f.reshape(f.shape[0], -1).all(1) if k in STATE_KEYS else f.transpose(0, 1).reshape(f.shape[1], -1).all(1)
        ok = f if ok is None else ok & f
    return ok


def forward(model, batch: dict[str, torch.Tensor], idx: torch.Tensor):
    """Replay sequences `idx` through the actor and critic from their stored states, resetting at
    their episode starts: (Gaussian over the L·B steps, values (L·B,), the minibatch's stored
    tensors flattened to (L·B, …))."""
    obs, starts = batch["obs"][:, idx], batch["starts"][:, idx]
    actor0 = (batch["actor_h"][idx], batch["actor_c"][idx])
    critic0 = (batch["critic_h"][idx], batch["critic_c"][idx])
    mean, _ = model.actor_sequence(obs, actor0, starts)
    value, _ = model.value_sequence(obs, critic0, starts)
    mean = mean.reshape(-1, mean.shape[-1])
    dist = torch.distributions.Normal(mean, model.log_std.exp().expand_as(mean))
    mb = {k: batch[k][:, idx].reshape(-1, *batch[k].shape[2:]) for k in ("act", "logp", "adv", "ret", "val")}
    return dist, value.reshape(-1), mb
