"""Recurrent PPO: the rollout and the minibatches of `PPO` for `arch="lstm"` (`RecurrentActorCritic`),
and the deterministic stateful actor every policy kind shares for evaluation.

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

`DeterministicActor` gives a trainer or a loaded policy the interface `evaluate` uses: a stateless
callable for an MLP, `initial_state(n)` / `step(obs, state)` for an LSTM or an observation history.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from .history import History

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


def sequence_minibatches(sequences: torch.Tensor, per_minibatch: int, generator: torch.Generator):
    """Index tensors of whole sequences for one epoch: `sequences` (the usable sequence indices)
    shuffled and cut into groups of `per_minibatch`; a remainder smaller than that is dropped (a
    different one each epoch), as the feed-forward PPO drops its remainder of transitions."""
    size = sequences.numel()
    mb = min(per_minibatch, size)
    if mb == 0:
        return []
    perm = sequences[torch.randperm(size, generator=generator)]
    return [perm[s : s + mb] for s in range(0, size - mb + 1, mb)]


def initial_rollout_state(model, n: int) -> dict:
    """Zero LSTM states for n drones, every drone at the start of an episode."""
    ah, ac = model.initial_state(n)
    ch, cc = model.initial_state(n)
    return {"actor_h": ah, "actor_c": ac, "critic_h": ch, "critic_c": cc, "start": np.ones(n, bool)}


# --- rollout --------------------------------------------------------------------------------


@torch.inference_mode()
def collect(ppo) -> dict[str, torch.Tensor]:
    """One rollout of T steps over N drones with the recurrent policy; returns sequences (see the
    module docstring): obs, act, logp, adv, ret, val, starts (L, S, …) and the four initial states
    (S, H), with S = T/L·N."""
    cfg, model = ppo.cfg, ppo.model
    n, T = cfg.num_envs, cfg.rollout_steps
    L = ppo.seq_len
    D, H = ppo.obs_dim, model.hidden
    obs_buf = np.zeros((T, n, D), np.float32)
    start_buf = np.zeros((T, n), bool)
    act_buf = torch.zeros((T, n, 4))
    logp_buf = torch.zeros((T, n))
    val_buf = np.zeros((T + 1, n))
    rew_buf = np.zeros((T, n))
    term_buf = np.zeros((T, n), bool)
    trunc_buf = np.zeros((T, n), bool)
    final_val = np.zeros((T, n))
    init = {k: torch.zeros(T // L, n, H) for k in STATE_KEYS}
    rs = ppo.rollout_state
    ah, ac, ch, cc = (rs[k] for k in STATE_KEYS)
    start = rs["start"]
    raw_seen = [ppo._obs]
    std = model.log_std.exp()
    obs_n = ppo._norm(ppo._obs)
    env_s = 0.0
    for t in range(T):
        if t % L == 0:  # the state a sequence starts from, before this step's reset mask
            for k, v in zip(STATE_KEYS, (ah, ac, ch, cc), strict=True):
                init[k][t // L] = v
        obs_buf[t], start_buf[t] = obs_n, start
        keep = torch.from_numpy(~start).to(torch.float32).unsqueeze(-1)
        ah, ac, ch, cc = ah * keep, ac * keep, ch * keep, cc * keep
        x = torch.from_numpy(obs_n).unsqueeze(0)
        mean, (ah, ac) = model.actor_sequence(x, (ah, ac))
        value, (ch, cc) = model.value_sequence(x, (ch, cc))
        mean = mean[0]
        action = mean + std * torch.randn(mean.shape, generator=ppo.torch_gen)
        logp_buf[t] = torch.distributions.Normal(mean, std).log_prob(action).sum(-1)
        act_buf[t] = action
        val_buf[t] = value[0].numpy()
        te = time.perf_counter()
        raw, reward, term, trunc, infos = ppo.env.step(action.clamp(-1.0, 1.0).numpy())
        env_s += time.perf_counter() - te
        rew_buf[t], term_buf[t], trunc_buf[t] = reward, term, trunc
        if "_final_obs" in infos:
            ppo._record_episodes(infos)
            tr = np.flatnonzero(trunc)
            if tr.size:  # V(final observation), continuing that episode's critic state
                final = torch.from_numpy(ppo._norm(infos["final_obs"][tr])).unsqueeze(0)
                idx = torch.from_numpy(tr)
                fv, _ = model.value_sequence(final, (ch[idx], cc[idx]))
                final_val[t, tr] = fv[0].numpy()
                raw_seen.append(infos["final_obs"][tr])
        raw_seen.append(raw)
        ppo._obs = raw
        obs_n = ppo._norm(raw)
        start = term | trunc
    keep = torch.from_numpy(~start).to(torch.float32).unsqueeze(-1)
    v_next, _ = model.value_sequence(torch.from_numpy(obs_n).unsqueeze(0), (ch * keep, cc * keep))
    val_buf[T] = v_next[0].numpy()
    ppo.rollout_state = {"actor_h": ah, "actor_c": ac, "critic_h": ch, "critic_c": cc, "start": start}
    adv, ret = ppo._finish_rollout(raw_seen, rew_buf, val_buf, final_val, term_buf, trunc_buf, env_s)
    f32 = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    out = {
        "obs": to_sequences(f32(obs_buf), L),
        "act": to_sequences(act_buf, L),
        "logp": to_sequences(logp_buf, L),
        "adv": to_sequences(f32(adv), L),
        "ret": to_sequences(f32(ret), L),
        "val": to_sequences(f32(val_buf[:T]), L),
        "starts": to_sequences(torch.from_numpy(start_buf), L),
    }
    out.update({k: v.reshape(-1, H) for k, v in init.items()})
    return out


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


# --- the deterministic policy ---------------------------------------------------------------


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
