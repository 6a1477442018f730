"""Proximal Policy Optimisation (Schulman et al. 2017, arXiv:1707.06347), from scratch.

Read against the paper:
- `PPO.collect`: "run policy π_θold in environment for T timesteps" with N actors (Algorithm 1).
- `compute_gae` (gae.py): Â_t by GAE, eq. 11 of the PPO paper / eq. 16 of Schulman et al. 2016.
- `PPO.update`: K epochs of minibatch SGD on
      L_t(θ) = −L^CLIP_t(θ) + c1·L^VF_t(θ) − c2·S[π_θ](s_t)                (PPO eq. 9, as a loss)
      L^CLIP = E_t[min(r_t(θ)·Â_t, clip(r_t(θ), 1 − ε, 1 + ε)·Â_t)]          (eq. 7)
      r_t(θ) = π_θ(a_t|s_t) / π_θold(a_t|s_t)                                 (eq. 6)
  and θ_old ← θ.
- With `PPOConfig.update = "numpy"` (an MLP's default) the same minibatches go through `numpy_ppo`:
  that loss with its gradient written out, the same gradient clip and Adam, on the same parameters
  and optimiser state; the rollout's forward passes too. torch's path stays the reference.

Health metrics come back as a dict under fixed names (docs/architecture.md style rule 5); the run loop (`run`)
decides where they go. approx_kl uses the (r − 1) − log r estimator (Schulman, "Approximating KL
Divergence", 2020), unbiased and never negative. What PPO shares with SAC (the episode log, the
checkpoint layout, the files) is `trainer.Trainer`'s.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np
import torch

from quadpilot.core.normalize import RunningMeanStd

from . import recurrent_ppo, runlog, trainer
from .checks import rms_state, tensor
from .envs import EnvConfig, QuadVectorEnv
from .gae import compute_gae
from .history import HistoryVectorEnv, network_input_dim
from .networks import ActorCritic, RecurrentActorCritic, build_actor_critic
from .numpy_ppo import LOG_SQRT_2PI, NumpyPPO

UPDATE_PATHS = ("auto", "numpy", "torch")
STAT_KEYS = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction", "grad_norm")


@dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters. Derived sizes are properties, never written back."""

    num_envs: int = 128
    """Parallel drones in the batched vector environment (N actors)."""
    rollout_steps: int = 64
    """Steps per drone per rollout (T); a rollout holds num_envs × rollout_steps transitions."""
    total_steps: int = 1_000_000
    """Environment steps (transitions) to train for."""
    epochs: int = 8
    """K, passes over each rollout. 8 since the NumPy update: the fastest to the hover bar of 6, 8 and
    10 (docs/benchmarks.md, "Time to the hover bar"); models trained before it ran 10, as their
    config.json records."""
    minibatch_size: int = 1024
    """Transitions per gradient step."""
    lr: float = 1e-3
    """Adam learning rate (at the start, if annealed)."""
    lr_schedule: str = "linear"
    """constant, or linear (anneal to 0 over total_steps)."""
    gamma: float = 0.99
    """Discount γ."""
    lam: float = 0.95
    """GAE λ."""
    clip_eps: float = 0.2
    """ε of the clipped surrogate."""
    clip_value: bool = False
    """Clip the value update to ±clip_eps around the old value (as OpenAI baselines)."""
    vf_coef: float = 0.5
    """c1, weight of the value loss."""
    ent_coef: float = 0.0
    """c2, weight of the entropy bonus."""
    max_grad_norm: float = 0.5
    """Global gradient-norm clip."""
    target_kl: float | None = None
    """Stop the epochs of an update early once approx_kl exceeds this (None: never)."""
    arch: str = "mlp"
    """Network: mlp (feed-forward actor and critic), or lstm (`RecurrentActorCritic`, one LSTM layer
    of lstm_hidden units and a linear head each, trained on sequences: `recurrent_ppo`)."""
    lstm_hidden: int = 64
    """LSTM width when arch is lstm."""
    bptt_steps: int = 0
    """arch lstm: truncated backprop through time, the length L of the sequences each drone's
    rollout is cut into (each replayed from the LSTM state stored at collection); minibatches hold
    minibatch_size // L whole sequences. 0: the whole rollout (L = rollout_steps)."""
    obs_history: int = 1
    """arch mlp: the network sees the last k observations and the k actions before them, stacked
    (`history`); 1: the current observation only. Evaluated in-process; not exportable."""
    actor_hidden: tuple[int, ...] = (64, 64)
    """Actor hidden layer widths."""
    critic_hidden: tuple[int, ...] = (64, 64)
    """Critic hidden layer widths."""
    activation: str = "tanh"
    """Hidden activation: tanh, relu or elu."""
    init_log_std: float = -1.0
    """Initial log standard deviation of the Gaussian policy (σ ≈ 0.37)."""
    reward_scale: float = 0.05
    """Rewards are multiplied by this before GAE; keeps the value loss from eating the shared
    gradient-norm budget (measured: unscaled, the policy starved)."""
    normalize_obs: bool = False
    """Keep a running mean/std of observations and feed the networks normalised inputs. Off by
    default: every observation field is already O(1) in SI units, and measured on hover (2 seeds,
    1 M steps) the running normaliser kept the final error at 5–8 cm (success 45–100 %) while raw
    inputs reached 100 % success at ~0.5 M steps with 1 cm error: near hover, nearly constant
    features (R33, rates) get divided by a shrinking std, so the inputs keep changing scale under
    the policy. The normaliser is saved with the weights either way (identity when off)."""
    normalize_adv: bool = True
    """Normalise advantages per minibatch."""
    max_nonfinite_updates: int = 5
    """Abort after this many consecutive updates that had to skip non-finite data or gradients."""
    seed: int = 0
    """Seed for the environment, the networks and the sampling."""
    threads: int = 2
    """torch intra-op threads (the NumPy update runs its matrix products on one BLAS thread: faster at
    these sizes)."""
    update: str = "auto"
    """How the update and the rollout's forward passes are computed: torch (autograd and
    torch.optim.Adam: the reference), numpy (`numpy_ppo`: the same loss, hand-written gradient, clip
    and Adam in NumPy, on the same parameters and optimiser state; equal to float32 rounding, and
    ~2.5× faster per gradient step at minibatch 1,024: benchmarks/test_ppo_gradient_step.py; arch
    mlp only), or auto: numpy for arch mlp, torch for lstm. auto is resolved when the configuration is
    made, so a run's config.json names the path it trained with; a configuration saved before this
    field existed reads as torch, the path that trained it."""

    def __post_init__(self) -> None:
        if self.update == "auto":
            object.__setattr__(self, "update", "numpy" if self.arch == "mlp" else "torch")
        if self.update not in UPDATE_PATHS:
            raise ValueError(f"update must be one of {', '.join(UPDATE_PATHS)}; got {self.update!r}")
        if self.update == "numpy" and self.arch != "mlp":
            raise ValueError(f"update 'numpy' is for arch 'mlp' only; arch {self.arch!r} needs update 'torch'")

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.rollout_steps

    @property
    def num_minibatches(self) -> int:
        return max(1, self.batch_size // self.minibatch_size)

    @property
    def seq_len(self) -> int:
        """Steps per training sequence of a recurrent policy (see bptt_steps)."""
        return self.bptt_steps or self.rollout_steps

    @property
    def num_updates(self) -> int:
        return max(1, math.ceil(self.total_steps / self.batch_size))

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> PPOConfig:
        d = dict(d)
        for k in ("actor_hidden", "critic_hidden"):
            d[k] = tuple(d[k])
        d.setdefault("update", "torch")  # saved before the NumPy path existed: trained with torch
        return cls(**d)


PRESETS: dict[str, dict] = {
    # Batched PPO tuned on this project's hover task (see docs/benchmarks.md).
    "fast": {},
    # The ENPM 667 project's recipe as published: actor 32×32, critic 128×128, γ 0.99, lr 1e-4, 350-step
    # rollouts, minibatch 64, 10 epochs; one actor as in its code.
    "seed001": {
        "num_envs": 1,
        "rollout_steps": 350,
        "minibatch_size": 64,
        "epochs": 10,
        "lr": 1e-4,
        "gamma": 0.99,
        "actor_hidden": (32, 32),
        "critic_hidden": (128, 128),
    },
    # Stable-Baselines3 PPO's constructor defaults (SB3 2.x) in our terms, on 8 drones as the
    # design notes measured SB3: 2048-step rollouts, minibatch 64, lr 3e-4 constant, log-std 0,
    # unscaled rewards, SB3's vf_coef 0.5 on the MSE = ours 1.0 on ½·MSE. For the SB3 comparison.
    "sb3_defaults": {
        "num_envs": 8,
        "rollout_steps": 2048,
        "minibatch_size": 64,
        "epochs": 10,
        "lr": 3e-4,
        "lr_schedule": "constant",
        "vf_coef": 1.0,
        "init_log_std": 0.0,
        "reward_scale": 1.0,
    },
}


NonFiniteError = trainer.NonFiniteError  # every algorithm's; named here, where PPO's docs look for it


class PPO(trainer.Trainer):
    """The trainer: environment, actor-critic, optimiser, normaliser and RNGs (`trainer.Trainer`
    has what it shares with SAC: the episode log, the checkpoint layout, the files).

    `iterate()` runs one rollout and one update and returns the metrics dict.
    """

    algo = "ppo"
    unit = "update"
    Config = PPOConfig
    columns = runlog.COLUMNS
    run_keys = (
        *("schema", "task", "preset", "ppo", "env", "curriculum", "checkpoint_every", "snapshot_every"),
        *("eval_episodes", "command", "started", "resumes", "machine"),
    )
    eval_keys = ("policy", "global_step", "updates", "train_time_s", "first_success", "time_breakdown_s")

    def __init__(self, cfg: PPOConfig, env_cfg: EnvConfig) -> None:
        self.cfg, self.env_cfg = cfg, env_cfg
        torch.set_num_threads(cfg.threads)
        self.recurrent = cfg.arch == "lstm"
        if cfg.obs_history < 1 or (cfg.obs_history > 1 and cfg.arch != "mlp"):
            raise ValueError(
                f"obs_history must be ≥ 1, and > 1 only with arch='mlp'; got {cfg.obs_history} ({cfg.arch})"
            )
        if self.recurrent and (cfg.bptt_steps < 0 or cfg.rollout_steps % cfg.seq_len):
            raise ValueError(
                f"bptt_steps {cfg.bptt_steps} must divide rollout_steps {cfg.rollout_steps} (0: all of it)"
            )
        self.seq_len = cfg.seq_len
        env = QuadVectorEnv(cfg.num_envs, config=env_cfg)
        if cfg.obs_history > 1:
            env = HistoryVectorEnv(env, cfg.obs_history)
        self.obs_dim = obs_dim = network_input_dim(env_cfg.layout.dim, cfg)
        self.torch_gen = torch.Generator().manual_seed(cfg.seed)
        torch.manual_seed(cfg.seed)  # parameter initialisation draws from the default generator
        self.model: ActorCritic | RecurrentActorCritic = build_actor_critic(obs_dim, 4, cfg)
        self.opt = torch.optim.Adam(self.model.parameters(), lr=cfg.lr, eps=1e-5)
        # the NumPy path moves the parameters onto flat memory it shares with torch (values unchanged)
        self._np = NumpyPPO(self.model, self.opt) if cfg.update == "numpy" else None
        self.obs_rms = RunningMeanStd((obs_dim,))
        if self.recurrent:  # LSTM states carried from step to step and rollout to rollout
            self.rollout_state = recurrent_ppo.initial_rollout_state(self.model, cfg.num_envs)
        self._start(env)
        self.reseed(cfg.seed)

    # --- environment and state between iterations -----------------------------------------
    def reseed(self, seed: int) -> None:
        super().reseed(seed)
        if self.recurrent:
            self.rollout_state = recurrent_ppo.initial_rollout_state(self.model, self.cfg.num_envs)

    def extra_state(self) -> dict:
        """Trainer state beyond the MLP's, as arrays and plain data for a checkpoint: the LSTM
        states in flight, the observation history, the sensor-noise processes."""
        out: dict = {}
        if self.recurrent:
            out["rollout_state"] = {k: v.clone() for k, v in self.rollout_state.items() if k != "start"}
            out["rollout_state"]["start"] = self.rollout_state["start"].copy()
        if isinstance(self.env, HistoryVectorEnv):
            out["history"] = self.env.state_dict()
        return {**out, **super().extra_state()}

    def load_extra_state(self, d: dict | None) -> None:
        """Put back what `extra_state` saved (a checkpoint without it leaves things as they are)."""
        d = d or {}
        if self.recurrent and "rollout_state" in d:
            rs = d["rollout_state"]
            self.rollout_state = {
                k: torch.as_tensor(np.asarray(rs[k]), dtype=torch.float32).clone() for k in recurrent_ppo.STATE_KEYS
            }
            self.rollout_state["start"] = np.asarray(rs["start"], bool).copy()
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
        return runlog.plot_curves(metrics_path, out_path, title, radii)

    def _norm(self, raw: np.ndarray) -> np.ndarray:
        return self.obs_rms.normalize(raw) if self.cfg.normalize_obs else raw.astype(np.float32)

    # --- rollout -------------------------------------------------------------------------
    @torch.inference_mode()
    def collect(self) -> dict[str, torch.Tensor]:
        """One rollout of T steps over N drones with the current (old) policy. A recurrent policy
        returns sequences instead of flat transitions (`recurrent_ppo.collect`)."""
        if self.recurrent:
            return recurrent_ppo.collect(self)
        n, T = self.cfg.num_envs, self.cfg.rollout_steps
        obs_dim = self.obs_dim
        obs_buf = np.zeros((T, n, obs_dim), np.float32)
        act_buf = np.zeros((T, n, 4), np.float32)
        logp_buf = np.zeros((T, n), np.float32)
        val_buf = np.zeros((T + 1, n))
        rew_buf = np.zeros((T, n))
        term_buf = np.zeros((T, n), bool)
        trunc_buf = np.zeros((T, n), bool)
        final_val = np.zeros((T, n))
        raw_seen = [self._obs]
        std = self.model.log_std.exp() if self._np is None else np.exp(self._np.log_std)
        obs_n = self._norm(self._obs)
        env_s = 0.0  # time inside env.step; the rest of the rollout is inference and bookkeeping
        for t in range(T):
            obs_buf[t] = obs_n
            action, logp_buf[t], val_buf[t] = self._act(obs_n, std)
            act_buf[t] = action
            te = time.perf_counter()
            raw, reward, term, trunc, infos = self.env.step(np.clip(action, -1.0, 1.0))
            env_s += time.perf_counter() - te
            rew_buf[t], term_buf[t], trunc_buf[t] = reward, term, trunc
            if "_final_obs" in infos:
                self._record_episodes(infos)
                tr = np.flatnonzero(trunc)
                if tr.size:  # bootstrap from the final observation of time-limit truncations
                    final = self._norm(infos["final_obs"][tr])
                    final_val[t, tr] = self._value(final)
                    raw_seen.append(infos["final_obs"][tr])
            raw_seen.append(raw)
            self._obs = raw
            obs_n = self._norm(raw)
        val_buf[T] = self._value(obs_n)
        adv, ret = self._finish_rollout(raw_seen, rew_buf, val_buf, final_val, term_buf, trunc_buf, env_s)
        flat = lambda a: torch.as_tensor(a, dtype=torch.float32).reshape(T * n, *a.shape[2:])  # noqa: E731
        return {
            "obs": flat(obs_buf),
            "act": torch.from_numpy(act_buf.reshape(T * n, 4)),
            "logp": torch.from_numpy(logp_buf.reshape(T * n)),
            "adv": flat(adv),
            "ret": flat(ret),
            "val": flat(val_buf[:T]),
        }

    def _act(self, obs_n: np.ndarray, std) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The Gaussian policy sampled at normalised observations (n, obs_dim): action (n, 4),
        log π(action) (n,) and V (n,). The noise is drawn from torch_gen on either path."""
        if self._np is not None:
            mean = self._np.actor_mean(obs_n)
            action = mean + std * torch.randn(mean.shape, generator=self.torch_gen).numpy()
            diff = action - mean  # log π as torch.distributions.Normal.log_prob computes it
            logp = (-(diff * diff) / (2 * (std * std)) - np.log(std) - LOG_SQRT_2PI).sum(-1)
            return action, logp, self._np.value(obs_n)
        x = torch.from_numpy(obs_n)
        mean = self.model.actor(x)
        action = mean + std * torch.randn(mean.shape, generator=self.torch_gen)
        logp = torch.distributions.Normal(mean, std).log_prob(action).sum(-1)
        return action.numpy(), logp.numpy(), self.model.value(x).numpy()

    def _value(self, obs_n: np.ndarray) -> np.ndarray:
        if self._np is not None:
            return self._np.value(obs_n)
        return self.model.value(torch.from_numpy(obs_n)).numpy()

    def _finish_rollout(self, raw_seen, rew, val, final_val, term, trunc, env_s: float):
        """The end of every rollout, feed-forward or recurrent: the normaliser update, the
        bootstrap value of time-limit truncations (V of the final observation, never on
        termination) and GAE. rew, term, trunc, final_val (T, n); val (T + 1, n). Returns (adv, ret)."""
        cfg = self.cfg
        if cfg.normalize_obs:  # statistics move between rollouts, never within one
            self.obs_rms.update(np.concatenate(raw_seen))
        next_val = val[1:].copy()
        next_val[trunc] = final_val[trunc]
        adv, ret = compute_gae(rew * cfg.reward_scale, val[:-1], next_val, term, trunc, cfg.gamma, cfg.lam)
        self.global_step += rew.size
        self.last_env_s = env_s
        return adv, ret

    # --- update --------------------------------------------------------------------------
    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        cfg = self.cfg
        if cfg.lr_schedule == "linear":
            frac = max(0.0, 1.0 - self.updates / cfg.num_updates)
            for g in self.opt.param_groups:
                g["lr"] = cfg.lr * frac
        if self.recurrent:  # the units are whole sequences (recurrent_ppo)
            finite = recurrent_ppo.finite_sequences(batch)
            skipped = int((~finite).sum()) * self.seq_len
            per_minibatch = max(1, cfg.minibatch_size // self.seq_len)
        else:  # the units are transitions
            finite = torch.stack([torch.isfinite(v).reshape(v.shape[0], -1).all(1) for v in batch.values()]).all(0)
            skipped = int((~finite).sum())
            per_minibatch = cfg.minibatch_size
        idx_all = torch.nonzero(finite).squeeze(1)
        size = idx_all.numel()
        mb = min(per_minibatch, size) if size else 0
        stats: dict[str, list[float]] = {k: [] for k in ("policy_loss", "value_loss", "entropy", "approx_kl")}
        stats.update(clip_fraction=[], grad_norm=[])
        skipped_steps = 0
        params = list(self.model.parameters())
        if self._np is not None:  # the same minibatches, loss, clip and Adam in NumPy (numpy_ppo)
            self._np.attach()
            packed = self._np.pack(batch)
        for _epoch in range(cfg.epochs):
            perm = idx_all[torch.randperm(size, generator=self.torch_gen)]
            for start in range(0, size - mb + 1, mb) if mb else []:
                i = perm[start : start + mb]
                if self._np is not None:
                    step = self._np.minibatch_step(packed, i.numpy(), cfg)
                    if step is None:  # a non-finite loss or gradient norm: skipped, as below
                        skipped_steps += 1
                    else:
                        for k, x in zip(STAT_KEYS, step, strict=True):
                            stats[k].append(x)
                    continue
                if self.recurrent:  # replay whole sequences from their stored LSTM states
                    dist, v, data = recurrent_ppo.forward(self.model, batch, i)
                else:
                    data = {k: batch[k][i] for k in ("act", "logp", "adv", "ret", "val")}
                    obs = batch["obs"][i]
                    dist, v = self.model.distribution(obs), self.model.value(obs)
                act, old_logp = data["act"], data["logp"]
                adv, ret, old_v = data["adv"], data["ret"], data["val"]
                if cfg.normalize_adv:
                    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
                logp = dist.log_prob(act).sum(-1)
                log_ratio = logp - old_logp
                ratio = log_ratio.exp()
                # L^CLIP as a loss: max of the negated unclipped and clipped objectives
                pg_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1 - cfg.clip_eps, 1 + cfg.clip_eps)).mean()
                if cfg.clip_value:
                    v_clip = old_v + (v - old_v).clamp(-cfg.clip_eps, cfg.clip_eps)
                    v_loss = 0.5 * torch.max((v - ret) ** 2, (v_clip - ret) ** 2).mean()
                else:
                    v_loss = 0.5 * ((v - ret) ** 2).mean()
                entropy = dist.entropy().sum(-1).mean()
                loss = pg_loss + cfg.vf_coef * v_loss - cfg.ent_coef * entropy
                self.opt.zero_grad(set_to_none=True)
                if not torch.isfinite(loss):
                    skipped_steps += 1
                    continue
                loss.backward()
                gnorm = torch.nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
                if not torch.isfinite(gnorm):
                    self.opt.zero_grad(set_to_none=True)
                    skipped_steps += 1
                    continue
                self.opt.step()
                with torch.no_grad():
                    stats["policy_loss"].append(pg_loss.item())
                    stats["value_loss"].append(v_loss.item())
                    stats["entropy"].append(entropy.item())
                    stats["approx_kl"].append(((ratio - 1) - log_ratio).mean().item())
                    stats["clip_fraction"].append(((ratio - 1).abs() > cfg.clip_eps).float().mean().item())
                    stats["grad_norm"].append(gnorm.item())
            if cfg.target_kl is not None and stats["approx_kl"] and stats["approx_kl"][-1] > cfg.target_kl:
                break
        self.updates += 1
        self._count_nonfinite(
            bool(skipped or skipped_steps),
            f"updates met NaN/Inf (this one: {skipped} non-finite transitions, {skipped_steps} skipped gradient "
            "steps); the weights were not touched by them. Lower the learning rate or check the environment and "
            "reward for NaN.",
        )
        if self.recurrent:
            y, v = batch["ret"][:, finite].reshape(-1), batch["val"][:, finite].reshape(-1)
        else:
            y, v = batch["ret"][finite], batch["val"][finite]
        var_y = y.var().item() if y.numel() > 1 else float("nan")
        out = {k: float(np.mean(s)) if s else float("nan") for k, s in stats.items()}
        out["explained_variance"] = float("nan") if not var_y > 0 else 1.0 - (y - v).var().item() / var_y
        out["lr"] = self.opt.param_groups[0]["lr"]
        out["nonfinite_skipped"] = skipped + skipped_steps
        return out

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
    def act_deterministic(self) -> recurrent_ppo.DeterministicActor:
        """The deterministic policy on raw observations (N, obs_dim): what evaluation and export
        use. For an MLP a callable, `ppo.act_deterministic(obs)` → mean actions (N, 4); for an LSTM
        or an observation history, `initial_state(n)` and `step(obs, state)` (`evaluate` takes both)."""
        return recurrent_ppo.DeterministicActor(self.model, self._norm, self.env_cfg.layout.dim, self.cfg.obs_history)
