"""Proximal Policy Optimisation (Schulman et al. 2017, arXiv:1707.06347), from scratch: the
configuration and what every variant shares. Algorithm 1 of the paper, for iteration = 1, 2, …:

    for actor = 1 … N: run policy π_θold in the environment for T timesteps;
                       compute advantage estimates Â_1 … Â_T          (`collect`, `gae`)
    optimise the surrogate L w.r.t. θ, K epochs, minibatch size M ≤ NT  (`PPO.update`)
    θ_old ← θ

with, as a loss to minimise (eq. 6, 7 and 9),
      L_t(θ) = −L^CLIP_t(θ) + c1·L^VF_t(θ) − c2·S[π_θ](s_t)
      L^CLIP = E_t[min(r_t(θ)·Â_t, clip(r_t(θ), 1 − ε, 1 + ε)·Â_t)],   r_t(θ) = π_θ(a_t|s_t) / π_θold(a_t|s_t)

Each variant is its own class with one straight path, below the shared base class `PPO`:
- `FeedForwardPPO`: an MLP with the NumPy update (`numpy_ppo`: that loss with its
  gradient written out, the gradient clip and Adam). What runs by default (`update="auto"` picks it
  for arch mlp).
- `TorchPPO`: the same rollout with torch's forward passes, and the loss in torch
  with autograd and torch.optim.Adam (`loss`): the reference the NumPy update is checked
  against (`update="torch"`).
- `RecurrentPPO`: an LSTM actor-critic trained on sequences (`recurrent`; arch lstm), the torch loss.

`PPO(cfg, env_cfg)` builds the variant the configuration names (`variant`); `PPOConfig` and the
presets are `config`'s. The shared pieces are here (construction, the update loop over
epochs and minibatches, the bootstrap and GAE at the end of a rollout, the checkpoint entries), in
`rollout` (buffers, minibatch indices, health metrics) and in `gae`. Health metrics come back as a
dict under fixed names (docs/architecture.md style rule 5); the run loop (`runs.loop`) decides
where they go. approx_kl uses the (r − 1) − log r estimator (Schulman, "Approximating KL
Divergence", 2020), unbiased and never negative. What PPO shares with SAC (the
episode log, the checkpoint layout, the files) is `runs.trainer.Trainer`'s.
"""

from __future__ import annotations

import copy
import time

import numpy as np
import torch

from quadpilot.core.normalize import RunningMeanStd

from ..envs import EnvConfig, QuadVectorEnv
from ..envs.history import HistoryVectorEnv, network_input_dim
from ..networks import ActorCritic, RecurrentActorCritic, build_actor_critic
from ..networks.actor import DeterministicActor
from ..runs import plotting, runlog, trainer
from ..runs.checks import rms_state, tensor
from .config import PRESETS, UPDATE_PATHS, PPOConfig
from .gae import bootstrapped_gae
from .loss import gradient_step
from .numpy_ppo import LOG_SQRT_2PI, NumpyPPO
from .recurrent import STATE_KEYS, finite_sequences, forward, initial_rollout_state, to_sequences
from .rollout import RolloutBuffer, UpdateStats, minibatches

__all__ = [
    "PPO",
    "PRESETS",
    "UPDATE_PATHS",
    "FeedForwardPPO",
    "NonFiniteError",
    "PPOConfig",
    "RecurrentPPO",
    "TorchPPO",
]

NonFiniteError = trainer.NonFiniteError  # every algorithm's; named here, where PPO's docs look for it


class PPO(trainer.Trainer):
    """The PPO trainer: environment, actor-critic, optimiser, normaliser and RNGs (`runs.trainer.Trainer`
    has what it shares with SAC: the episode log, the checkpoint layout, the files).

    `PPO(cfg, env_cfg)` is an instance of the variant `cfg` names (see the module docstring); a
    variant provides `collect` (one rollout → a batch), `_usable` (which units of the batch are
    finite), `_prepare` and `_gradient_step` (one minibatch). `iterate()` runs one rollout and one
    update and returns the metrics dict.
    """

    algo = "ppo"
    unit = "update"
    default_preset = "fast"
    Config = PPOConfig
    columns = runlog.COLUMNS
    run_keys = (
        *("schema", "task", "preset", "ppo", "env", "curriculum", "checkpoint_every", "snapshot_every"),
        *("eval_episodes", "command", "started", "resumes", "machine"),
    )
    eval_keys = ("policy", "global_step", "updates", "train_time_s", "first_success", "time_breakdown_s")
    recurrent = False
    """Whether the policy carries an LSTM state (`RecurrentPPO`)."""

    def __new__(cls, cfg: PPOConfig, env_cfg: EnvConfig):
        return super().__new__(variant(cfg) if cls is PPO else cls)

    def __init__(self, cfg: PPOConfig, env_cfg: EnvConfig) -> None:
        if type(self) is not variant(cfg):
            raise ValueError(f"{type(self).__name__} cannot train arch {cfg.arch!r} with update {cfg.update!r}")
        self.cfg, self.env_cfg = cfg, env_cfg
        torch.set_num_threads(cfg.threads)
        if cfg.obs_history < 1 or (cfg.obs_history > 1 and cfg.arch != "mlp"):
            raise ValueError(
                f"obs_history must be ≥ 1, and > 1 only with arch='mlp'; got {cfg.obs_history} ({cfg.arch})"
            )
        self._check_config()
        env = QuadVectorEnv(cfg.num_envs, config=env_cfg)
        if cfg.obs_history > 1:
            env = HistoryVectorEnv(env, cfg.obs_history)
        self.obs_dim = obs_dim = network_input_dim(env_cfg.layout.dim, cfg)
        self.torch_gen = torch.Generator().manual_seed(cfg.seed)
        torch.manual_seed(cfg.seed)  # parameter initialisation draws from the default generator
        self.model: ActorCritic | RecurrentActorCritic = build_actor_critic(obs_dim, 4, cfg)
        self.opt = torch.optim.Adam(self.model.parameters(), lr=cfg.lr, eps=1e-5)
        self._build_update()
        self.obs_rms = RunningMeanStd((obs_dim,))
        self._start(env)
        self.reseed(cfg.seed)

    # --- what a variant adds to construction ----------------------------------------------
    def _check_config(self) -> None:
        """Refuse a configuration the variant cannot train (ValueError)."""

    def _build_update(self) -> None:
        """What the variant's update needs beyond the model and the optimiser."""

    # --- environment and state between iterations -----------------------------------------
    def extra_state(self) -> dict:
        """Trainer state beyond the networks', as arrays and plain data for a checkpoint: the
        observation history, the sensor-noise processes (`RecurrentPPO` adds its LSTM states)."""
        out: dict = {}
        if isinstance(self.env, HistoryVectorEnv):
            out["history"] = self.env.state_dict()
        return {**out, **super().extra_state()}

    def load_extra_state(self, d: dict | None) -> None:
        """Put back what `extra_state` saved (a checkpoint without it leaves things as they are)."""
        d = d or {}
        if "history" in d and isinstance(self.env, HistoryVectorEnv):
            self.env.load_state_dict({k: np.asarray(v) for k, v in d["history"].items()})
        super().load_extra_state(d)

    # --- checkpoint entries (`trainer.Trainer.state_dict`) -----------------------------------
    def own_state(self) -> dict:
        rms = self.obs_rms
        opt = self.opt.state_dict()
        # every Adam tensor copied onto its own storage (the NumPy path's are views of flat tensors)
        opt = {
            "state": {i: {k: v.detach().clone() for k, v in st.items()} for i, st in opt["state"].items()},
            "param_groups": copy.deepcopy(opt["param_groups"]),
        }
        return {
            "model": {k: v.detach().clone() for k, v in self.model.state_dict().items()},
            "optimizer": opt,
            "obs_rms": {"mean": tensor(rms.mean), "var": tensor(rms.var), "count": rms.count, "clip": rms.clip},
        }

    def own_optimizers(self, ckpt: dict, source: str) -> dict:
        return {"optimizer": (ckpt["optimizer"], self.opt)}

    def load_own_state(self, ckpt: dict) -> None:
        self.model.load_state_dict(ckpt["model"])
        self.opt.load_state_dict(ckpt["optimizer"])

    def load_own_numbers(self, ckpt: dict) -> None:
        self.obs_rms.load_state_dict(rms_state(ckpt["obs_rms"]))

    def plot_curves(self, metrics_path, out_path, title: str, radii: tuple[float, ...]):
        return plotting.plot_curves(metrics_path, out_path, title, radii)

    def _norm(self, raw: np.ndarray) -> np.ndarray:
        return self.obs_rms.normalize(raw) if self.cfg.normalize_obs else raw.astype(np.float32)

    # --- rollout: the variant's `collect`, then this ----------------------------------------
    def collect(self) -> dict[str, torch.Tensor]:
        """One rollout of T steps over N drones with the current (old) policy, as tensors."""
        raise NotImplementedError(f"{type(self).__name__} has no rollout")

    def _finish_rollout(self, raw_seen, rew, val, final_val, term, trunc, env_s: float):
        """The end of every rollout, feed-forward or recurrent: the normaliser update, the
        bootstrap value of time-limit truncations (V of the final observation, never on
        termination) and GAE (`gae.bootstrapped_gae`). rew, term, trunc, final_val (T, n); val
        (T + 1, n). Returns (adv, ret)."""
        cfg = self.cfg
        if cfg.normalize_obs:  # statistics move between rollouts, never within one
            self.obs_rms.update(np.concatenate(raw_seen))
        adv, ret = bootstrapped_gae(rew * cfg.reward_scale, val, final_val, term, trunc, cfg.gamma, cfg.lam)
        self.global_step += rew.size
        self.last_env_s = env_s
        return adv, ret

    # --- update ------------------------------------------------------------------------------
    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        """K epochs of minibatch steps on the surrogate loss (the variant's `_gradient_step`), then
        θ_old ← θ: the next rollout samples from the updated policy. Units of the batch holding NaN
        or Inf are left out and counted; a gradient step whose loss or gradient norm is not finite
        is skipped (the weights untouched) and counted."""
        cfg = self.cfg
        if cfg.lr_schedule == "linear":
            frac = max(0.0, 1.0 - self.updates / cfg.num_updates)
            for g in self.opt.param_groups:
                g["lr"] = cfg.lr * frac
        finite, skipped, per_minibatch = self._usable(batch)
        usable = torch.nonzero(finite).squeeze(1)
        data = self._prepare(batch)
        stats = UpdateStats()
        for _epoch in range(cfg.epochs):
            for idx in minibatches(usable, per_minibatch, self.torch_gen):
                stats.add(self._gradient_step(data, idx))
            if stats.kl_above(cfg.target_kl):
                break
        self.updates += 1
        self._count_nonfinite(
            bool(skipped or stats.skipped),
            f"updates met NaN/Inf (this one: {skipped} non-finite transitions, {stats.skipped} skipped gradient "
            "steps); the weights were not touched by them. Lower the learning rate or check the environment and "
            "reward for NaN.",
        )
        out = stats.summary(*self._returns_and_values(batch, finite))
        out["lr"] = self.opt.param_groups[0]["lr"]
        out["nonfinite_skipped"] = skipped + stats.skipped
        return out

    def _usable(self, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, int, int]:
        """(finite mask over the batch's units, transitions left out, units per minibatch). The
        units of a feed-forward batch are transitions (`RecurrentPPO`: whole sequences)."""
        finite = torch.stack([torch.isfinite(v).reshape(v.shape[0], -1).all(1) for v in batch.values()]).all(0)
        return finite, int((~finite).sum()), self.cfg.minibatch_size

    def _returns_and_values(self, batch: dict[str, torch.Tensor], finite: torch.Tensor):
        """The finite units' returns and stored values, flat: the explained variance's inputs."""
        return batch["ret"][finite], batch["val"][finite]

    def _prepare(self, batch: dict[str, torch.Tensor]):
        """The batch as the variant's gradient steps read it."""
        return batch

    def _gradient_step(self, data, idx: torch.Tensor) -> tuple[float, ...] | None:
        """One minibatch step on units `idx`: the `rollout.STAT_KEYS` metrics, or None when skipped."""
        raise NotImplementedError(f"{type(self).__name__} has no update")

    def iterate(self) -> dict[str, float]:
        """One rollout and one update; returns every health metric under its fixed name."""
        t0 = time.perf_counter()
        n_before = len(self.ep_returns)
        batch = self.collect()
        t1 = time.perf_counter()
        metrics = self.update(batch)
        t2 = time.perf_counter()
        metrics.update(
            global_step=self.global_step,
            update=self.updates,
            steps_per_s=self.cfg.batch_size / (t2 - t0),
            rollout_s=t1 - t0,
            env_s=self.last_env_s,
            inference_s=t1 - t0 - self.last_env_s,
            update_s=t2 - t1,
            **self._episode_metrics(n_before),
        )
        return metrics

    @property
    def act_deterministic(self) -> DeterministicActor:
        """The deterministic policy on raw observations (N, obs_dim): what evaluation and export
        use. For an MLP a callable, `ppo.act_deterministic(obs)` → mean actions (N, 4); for an LSTM
        or an observation history, `initial_state(n)` and `step(obs, state)` (`envs.evaluate` takes both)."""
        return DeterministicActor(self.model, self._norm, self.env_cfg.layout.dim, self.cfg.obs_history)

    @classmethod
    def preset_values(cls, preset: str | None) -> dict:
        return PRESETS[preset or "fast"]

    @classmethod
    def init_from(cls, path: str, explicit: dict, algorithms: dict) -> tuple[dict, dict]:
        from . import init_from

        source = init_from.load_source(path, algorithms)
        return source, init_from.network_options(source, explicit, path)

    def start_from(self, ckpt: dict, source: str) -> dict:
        from .init_from import start_from

        return start_from(self, ckpt, source)

    @classmethod
    def policy_settings(cls, ckpt: dict) -> tuple[PPOConfig, bool, int]:
        cfg = PPOConfig.from_json(ckpt["ppo_config"])
        return cfg, bool(cfg.normalize_obs), int(cfg.obs_history)

    @classmethod
    def policy_network(cls, ckpt: dict, obs_dim: int, cfg: PPOConfig) -> tuple[torch.nn.Module, PPOConfig]:
        return build_actor_critic(network_input_dim(obs_dim, cfg), 4, cfg).eval(), cfg


# === the variants: FeedForwardPPO (NumPy update, the default), TorchPPO (the reference), RecurrentPPO


class FeedForwardPPO(PPO):
    """PPO for an MLP (`networks.ActorCritic`) with the NumPy update, what `update="auto"` picks for
    arch mlp: the rollout's forward passes and the minibatch step in NumPy (`numpy_ppo.NumpyPPO`: the
    loss of eq. 9 with its gradient written out, the global gradient-norm clip and Adam, on the very
    parameters and optimiser state torch holds). It exists for speed (docs/benchmarks.md)."""

    def _build_update(self) -> None:
        # the NumPy path moves the parameters onto flat memory it shares with torch (values unchanged)
        self._np = NumpyPPO(self.model, self.opt)

    # --- rollout: run π_θold for T steps on N drones ------------------------------------------
    @torch.inference_mode()
    def collect(self) -> dict[str, torch.Tensor]:
        """One rollout of T steps over N drones with the current (old) policy: flat transitions
        obs, act, logp, adv, ret, val (T·N, …), the advantages by GAE."""
        n, T = self.cfg.num_envs, self.cfg.rollout_steps
        buf = RolloutBuffer(T, n, self.obs_dim, self._obs)
        std = self._policy_std()
        obs_n = self._norm(self._obs)
        for t in range(T):
            buf.obs[t] = obs_n
            buf.act[t], buf.logp[t], buf.val[t] = self._act(obs_n, std)
            te = time.perf_counter()
            raw, reward, term, trunc, infos = self.env.step(np.clip(buf.act[t], -1.0, 1.0))
            buf.env_s += time.perf_counter() - te
            buf.record_step(t, reward, term, trunc)
            if "_final_obs" in infos:
                self._record_episodes(infos)
                tr = np.flatnonzero(trunc)
                if tr.size:  # bootstrap from the final observation of time-limit truncations
                    buf.final_val[t, tr] = self._value(self._norm(infos["final_obs"][tr]))
                    buf.raw_seen.append(infos["final_obs"][tr])
            buf.raw_seen.append(raw)
            self._obs = raw
            obs_n = self._norm(raw)
        buf.val[T] = self._value(obs_n)
        adv, ret = self._finish_rollout(buf.raw_seen, buf.rew, buf.val, buf.final_val, buf.term, buf.trunc, buf.env_s)
        flat = lambda a: torch.as_tensor(a, dtype=torch.float32).reshape(T * n, *a.shape[2:])  # noqa: E731
        return {
            "obs": flat(buf.obs),
            "act": torch.from_numpy(buf.act.reshape(T * n, 4)),
            "logp": torch.from_numpy(buf.logp.reshape(T * n)),
            "adv": flat(adv),
            "ret": flat(ret),
            "val": flat(buf.val[:T]),
        }

    def _policy_std(self):
        """σ = exp(log_std) of the Gaussian policy, for a rollout."""
        return np.exp(self._np.log_std)

    def _act(self, obs_n: np.ndarray, std) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The Gaussian policy sampled at normalised observations (n, obs_dim): action (n, 4),
        log π(action) (n,) and V (n,). The noise is drawn from torch_gen, as `TorchPPO` draws it."""
        mean = self._np.actor_mean(obs_n)
        action = mean + std * torch.randn(mean.shape, generator=self.torch_gen).numpy()
        diff = action - mean  # log π as torch.distributions.Normal.log_prob computes it
        logp = (-(diff * diff) / (2 * (std * std)) - np.log(std) - LOG_SQRT_2PI).sum(-1)
        return action, logp, self._np.value(obs_n)

    def _value(self, obs_n: np.ndarray) -> np.ndarray:
        return self._np.value(obs_n)

    # --- update: one minibatch step --------------------------------------------------------------
    def _prepare(self, batch: dict[str, torch.Tensor]) -> np.ndarray:
        """Adam's state taken over if it was loaded since the last update; the batch packed as rows."""
        self._np.attach()
        return self._np.pack(batch)

    def _gradient_step(self, packed: np.ndarray, idx: torch.Tensor) -> tuple[float, ...] | None:
        return self._np.minibatch_step(packed, idx.numpy(), self.cfg)


class TorchPPO(FeedForwardPPO):
    """PPO for an MLP with torch's forward passes and the loss in torch with autograd and
    torch.optim.Adam (`loss.gradient_step`), `update="torch"`: the reference, equal to the NumPy
    step to float32 rounding (tests/train/test_numpy_ppo.py). The rollout is `FeedForwardPPO`'s."""

    def _build_update(self) -> None:
        pass  # torch.optim.Adam over the model, built by PPO

    def _policy_std(self):
        return self.model.log_std.exp()

    def _act(self, obs_n: np.ndarray, std) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = torch.from_numpy(obs_n)
        mean = self.model.actor(x)
        action = mean + std * torch.randn(mean.shape, generator=self.torch_gen)
        logp = torch.distributions.Normal(mean, std).log_prob(action).sum(-1)
        return action.numpy(), logp.numpy(), self.model.value(x).numpy()

    def _value(self, obs_n: np.ndarray) -> np.ndarray:
        return self.model.value(torch.from_numpy(obs_n)).numpy()

    def _prepare(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return batch

    def _gradient_step(self, batch: dict[str, torch.Tensor], idx: torch.Tensor) -> tuple[float, ...] | None:
        data = {k: batch[k][idx] for k in ("act", "logp", "adv", "ret", "val")}
        obs = batch["obs"][idx]
        dist, v = self.model.distribution(obs), self.model.value(obs)
        return gradient_step(self.model, self.opt, dist, v, data, self.cfg)


class RecurrentPPO(PPO):
    """PPO for an LSTM actor-critic (arch lstm, update torch): the rollout carries each drone's LSTM
    states and is cut into sequences; the update replays whole sequences from their stored states
    (`recurrent`'s docstring has the details), with the torch loss (`loss`)."""

    recurrent = True

    def _check_config(self) -> None:
        cfg = self.cfg
        if cfg.bptt_steps < 0 or cfg.rollout_steps % cfg.seq_len:
            raise ValueError(
                f"bptt_steps {cfg.bptt_steps} must divide rollout_steps {cfg.rollout_steps} (0: all of it)"
            )
        self.seq_len = cfg.seq_len

    # --- LSTM states carried from step to step and rollout to rollout ------------------------------
    def reseed(self, seed: int) -> None:
        super().reseed(seed)
        self.rollout_state = initial_rollout_state(self.model, self.cfg.num_envs)

    def extra_state(self) -> dict:
        """The LSTM states in flight, then what every PPO keeps (`PPO.extra_state`)."""
        out = {"rollout_state": {k: v.clone() for k, v in self.rollout_state.items() if k != "start"}}
        out["rollout_state"]["start"] = self.rollout_state["start"].copy()
        return {**out, **super().extra_state()}

    def load_extra_state(self, d: dict | None) -> None:
        d = d or {}
        if "rollout_state" in d:
            rs = d["rollout_state"]
            self.rollout_state = {
                k: torch.as_tensor(np.asarray(rs[k]), dtype=torch.float32).clone() for k in STATE_KEYS
            }
            self.rollout_state["start"] = np.asarray(rs["start"], bool).copy()
        super().load_extra_state(d)

    # --- rollout ---------------------------------------------------------------------------------
    @torch.inference_mode()
    def collect(self) -> dict[str, torch.Tensor]:
        """One rollout of T steps over N drones with the recurrent policy; returns sequences (see the
        module docstring): obs, act, logp, adv, ret, val, starts (L, S, …) and the four initial states
        (S, H), with S = T/L·N."""
        cfg, model = self.cfg, self.model
        n, T = cfg.num_envs, cfg.rollout_steps
        L, H = self.seq_len, model.hidden
        buf = RolloutBuffer(T, n, self.obs_dim, self._obs)
        start_buf = np.zeros((T, n), bool)
        init = {k: torch.zeros(T // L, n, H) for k in STATE_KEYS}
        rs = self.rollout_state
        ah, ac, ch, cc = (rs[k] for k in STATE_KEYS)
        start = rs["start"]
        std = model.log_std.exp()
        obs_n = self._norm(self._obs)
        for t in range(T):
            if t % L == 0:  # the state a sequence starts from, before this step's reset mask
                for k, v in zip(STATE_KEYS, (ah, ac, ch, cc), strict=True):
                    init[k][t // L] = v
            buf.obs[t], start_buf[t] = obs_n, start
            keep = torch.from_numpy(~start).to(torch.float32).unsqueeze(-1)
            ah, ac, ch, cc = ah * keep, ac * keep, ch * keep, cc * keep
            x = torch.from_numpy(obs_n).unsqueeze(0)
            mean, (ah, ac) = model.actor_sequence(x, (ah, ac))
            value, (ch, cc) = model.value_sequence(x, (ch, cc))
            mean = mean[0]
            action = mean + std * torch.randn(mean.shape, generator=self.torch_gen)
            buf.logp[t] = torch.distributions.Normal(mean, std).log_prob(action).sum(-1).numpy()
            buf.act[t] = action.numpy()
            buf.val[t] = value[0].numpy()
            te = time.perf_counter()
            raw, reward, term, trunc, infos = self.env.step(action.clamp(-1.0, 1.0).numpy())
            buf.env_s += time.perf_counter() - te
            buf.record_step(t, reward, term, trunc)
            if "_final_obs" in infos:
                self._record_episodes(infos)
                tr = np.flatnonzero(trunc)
                if tr.size:  # V(final observation), continuing that episode's critic state
                    final = torch.from_numpy(self._norm(infos["final_obs"][tr])).unsqueeze(0)
                    idx = torch.from_numpy(tr)
                    fv, _ = model.value_sequence(final, (ch[idx], cc[idx]))
                    buf.final_val[t, tr] = fv[0].numpy()
                    buf.raw_seen.append(infos["final_obs"][tr])
            buf.raw_seen.append(raw)
            self._obs = raw
            obs_n = self._norm(raw)
            start = term | trunc
        keep = torch.from_numpy(~start).to(torch.float32).unsqueeze(-1)
        v_next, _ = model.value_sequence(torch.from_numpy(obs_n).unsqueeze(0), (ch * keep, cc * keep))
        buf.val[T] = v_next[0].numpy()
        self.rollout_state = {"actor_h": ah, "actor_c": ac, "critic_h": ch, "critic_c": cc, "start": start}
        adv, ret = self._finish_rollout(buf.raw_seen, buf.rew, buf.val, buf.final_val, buf.term, buf.trunc, buf.env_s)
        f32 = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
        out = {
            "obs": to_sequences(f32(buf.obs), L),
            "act": to_sequences(f32(buf.act), L),
            "logp": to_sequences(f32(buf.logp), L),
            "adv": to_sequences(f32(adv), L),
            "ret": to_sequences(f32(ret), L),
            "val": to_sequences(f32(buf.val[:T]), L),
            "starts": to_sequences(torch.from_numpy(start_buf), L),
        }
        out.update({k: v.reshape(-1, H) for k, v in init.items()})
        return out

    # --- update: the units are whole sequences -------------------------------------------------------
    def _usable(self, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, int, int]:
        finite = finite_sequences(batch)
        return finite, int((~finite).sum()) * self.seq_len, max(1, self.cfg.minibatch_size // self.seq_len)

    def _returns_and_values(self, batch: dict[str, torch.Tensor], finite: torch.Tensor):
        return batch["ret"][:, finite].reshape(-1), batch["val"][:, finite].reshape(-1)

    def _gradient_step(self, batch: dict[str, torch.Tensor], idx: torch.Tensor) -> tuple[float, ...] | None:
        """Replay whole sequences `idx` from their stored LSTM states, then the torch loss."""
        dist, v, data = forward(self.model, batch, idx)
        return gradient_step(self.model, self.opt, dist, v, data, self.cfg)


def variant(cfg: PPOConfig) -> type[PPO]:
    """The class of the PPO variant `cfg` names: arch lstm → `RecurrentPPO`; arch mlp with update
    numpy → `FeedForwardPPO`, with update torch → `TorchPPO`."""
    if cfg.arch == "lstm":
        return RecurrentPPO
    return FeedForwardPPO if cfg.update == "numpy" else TorchPPO
