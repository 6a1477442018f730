"""Soft Actor-Critic (Haarnoja et al. 2018, arXiv:1801.01290), with the automatic temperature of
Haarnoja et al. 2018b (arXiv:1812.05905), from scratch, on the batched quadrotor environment.

Read against the papers (equations of arXiv:1812.05905 unless said otherwise):
- policy: a squashed Gaussian, a = tanh(u), u ~ N(μ_φ(s), σ_φ(s)²), so actions stay in (−1, 1);
      log π(a|s) = log N(u; μ, σ²) − Σ_i log(1 − tanh²(u_i))                (1801.01290, appendix C, eq. 21)
  `squashed_log_prob` writes log(1 − tanh² u) as 2·(log 2 − u − softplus(−2u)), the same number
  without the cancellation of 1 − tanh² u → 0 for large |u|.
- critic: twin soft Q functions with target networks, each trained on
      J_Q(θ_j) = E[½ (Q_θj(s, a) − y)²],                                                       (eq. 5)
      y = r + γ (1 − terminated) (min_k Q_θ̄k(s', a') − α log π(a'|s')),  a' ~ π(·|s')       (eqs. 3, 5)
  with the minimum over the two target networks (the clipped double Q of Fujimoto et al. 2018,
  arXiv:1802.09477, which 1812.05905 §5 uses). Bootstrapping stops on termination only: a time-limit
  truncation stores the true final observation as s' and bootstraps from it (DESIGN style 4).
- actor: J_π(φ) = E[α log π(ã|s) − min_k Q_θk(s, ã)],  ã = tanh(μ_φ(s) + σ_φ(s)·ε), ε ~ N(0, I)
  (eq. 7 with the reparameterisation a = f_φ(ε; s) of §4.2).
- temperature: J(α) = E[−α log π(a|s) − α H̄] with target entropy H̄ = −|A| = −4       (eq. 18, §5)
  minimised over log α (a positive α by construction; the gradient has the same sign).
- targets: θ̄ ← τ θ + (1 − τ) θ̄ after every gradient step (Polyak averaging, Algorithm 1).

Collection is batched: every vector step moves `num_envs` drones one step with the current policy and
stores their transitions, then `updates_per_step` gradient steps follow, so the update-to-data ratio
is updates_per_step / num_envs gradient steps per transition. The first `learning_starts`
transitions use uniform random actions and no gradient steps.

Defaults and the reasons for them (docs/comparison.md, section "SAC"): the paper's table 1
(1812.05905 appendix D: Adam lr 3·10⁻⁴ for all three, minibatch 256, γ 0.99, τ 0.005, one target
update per gradient step, target entropy −|A|) with these changes, measured on hover: 64-wide
networks instead of 256 (a gradient step of two 256×256 ReLU critics and actor costs about 4×
more on this CPU), an update-to-data ratio of 1/4 (16 drones × 1 step, then 4 gradient steps;
1/16 had learned nothing useful by 150k steps), and α starting at 0.05 with log σ at −1 and a
faster temperature (α = 1 kept the actions near uniform for the first 150k steps). "Learning to
Fly in Seconds" (Eschmann et al. 2023, arXiv:2311.13081) trained TD3 with 64-wide layers,
minibatch 256, γ 0.99 and a critic step every 10 environment steps (0.1 per transition) for its
300k steps.

One row of metrics.csv is one *iteration*: `rollout_steps` vector steps with their gradient steps;
--eval-every and --checkpoint-every count iterations. The replay buffer is resumable: each
checkpoint first writes the transitions added since the previous one as an immutable chunk under
`replay/` (tensors only, atomic), so a save costs what was added, not the whole buffer.
"""

from __future__ import annotations

import copy
import dataclasses
import io
import math
import os
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from . import runlog
from .checkpoint import (
    _ENV_ARRAYS,
    LATEST,
    POLICY,
    PREVIOUS,
    SCHEMA,
    CheckpointError,
    _check_env_shapes,
    _load_env_state,
    _load_episode_state,
    _load_rng_state,
    _one_line,
    atomic_write,
    check_fits,
    load_checkpoint,
    plain,
)
from .envs import EnvConfig, QuadVectorEnv
from .networks import ACTIVATIONS, mlp

ACT_DIM = 4
LOG2 = math.log(2.0)
HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)
REPLAY_DIR = "replay"
REPLAY_SCHEMA = "quadpilot.replay/1"


@dataclass(frozen=True)
class SACConfig:
    """SAC hyper-parameters. Derived values are properties, never written back."""

    num_envs: int = 16
    """Drones stepped together per vector step (the batched environment)."""
    rollout_steps: int = 128
    """Vector steps per iteration (one metrics.csv row; the unit of --eval-every and
    --checkpoint-every); an iteration holds num_envs × rollout_steps transitions."""
    total_steps: int = 500_000
    """Environment steps (transitions) to train for."""
    learning_starts: int = 5_000
    """Transitions collected with uniform random actions before the first gradient step."""
    updates_per_step: int = 4
    """Gradient steps after each vector step; the update-to-data ratio is updates_per_step /
    num_envs gradient steps per transition."""
    minibatch_size: int = 256
    """Transitions per gradient step, drawn uniformly from the replay buffer (1812.05905 table 1)."""
    buffer_size: int = 1_000_000
    """Replay buffer capacity in transitions (1812.05905 table 1: 10⁶)."""
    gamma: float = 0.99
    """Discount γ."""
    tau: float = 0.005
    """Polyak factor of the target critics, θ̄ ← τθ + (1 − τ)θ̄ every gradient step."""
    actor_lr: float = 3e-4
    """Adam learning rate of the actor."""
    critic_lr: float = 3e-4
    """Adam learning rate of the twin critics."""
    alpha_lr: float = 1e-3
    """Adam learning rate of log α (the temperature)."""
    init_alpha: float = 0.05
    """Initial temperature α (log α = 0, α = 1, is the usual start; measured here, with rewards of order 1 per step,
    α = 1 kept the actions near uniform for the first 150k steps)."""
    autotune_alpha: bool = True
    """Learn α so that the policy's entropy tracks target_entropy (1812.05905 eq. 18); off: α fixed."""
    target_entropy: float | None = None
    """Target entropy H̄ in nats; None: −|A| = −4 (1812.05905 §5)."""
    actor_hidden: tuple[int, ...] = (64, 64)
    """Actor hidden layer widths."""
    critic_hidden: tuple[int, ...] = (64, 64)
    """Hidden layer widths of each of the two critics."""
    activation: str = "relu"
    """Hidden activation: relu, tanh or elu."""
    init_log_std: float = -1.0
    """Initial bias of the log-std head (the initial σ of u before the tanh is about e^this)."""
    log_std_min: float = -5.0
    """Lower clamp of the actor's log σ."""
    log_std_max: float = 2.0
    """Upper clamp of the actor's log σ."""
    reward_scale: float = 1.0
    """Rewards are multiplied by this in the critic target (stored unscaled in the buffer)."""
    max_nonfinite_updates: int = 5
    """Abort after this many consecutive iterations that had to skip non-finite gradient steps."""
    seed: int = 0
    """Seed for the environment, the networks, the sampling and the replay draws."""
    threads: int = 1
    """torch intra-op threads."""

    def __post_init__(self) -> None:
        for name in ("num_envs", "rollout_steps", "total_steps", "updates_per_step", "minibatch_size", "buffer_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be ≥ 1, got {getattr(self, name)}")
        if self.learning_starts < 0:
            raise ValueError(f"learning_starts must be ≥ 0, got {self.learning_starts}")
        if not 0.0 < self.tau <= 1.0:
            raise ValueError(f"tau must be in (0, 1], got {self.tau}")
        if not 0.0 <= self.gamma <= 1.0:
            raise ValueError(f"gamma must be in [0, 1], got {self.gamma}")
        if not self.init_alpha > 0:
            raise ValueError(f"init_alpha must be > 0, got {self.init_alpha}")
        if not self.log_std_min < self.log_std_max:
            raise ValueError(f"log_std_min {self.log_std_min} must be below log_std_max {self.log_std_max}")
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"unknown activation {self.activation!r}; expected one of {sorted(ACTIVATIONS)}")
        if not self.actor_hidden or not self.critic_hidden:
            raise ValueError("actor_hidden and critic_hidden need at least one layer")

    @property
    def batch_size(self) -> int:
        """Transitions per iteration."""
        return self.num_envs * self.rollout_steps

    @property
    def num_updates(self) -> int:
        """Iterations to reach total_steps (the name PPOConfig uses for its unit of progress)."""
        return max(1, math.ceil(self.total_steps / self.batch_size))

    @property
    def update_to_data(self) -> float:
        """Gradient steps per transition."""
        return self.updates_per_step / self.num_envs

    @property
    def entropy_target(self) -> float:
        return float(-ACT_DIM if self.target_entropy is None else self.target_entropy)

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> SACConfig:
        d = dict(d)
        for k in ("actor_hidden", "critic_hidden"):
            d[k] = tuple(d[k])
        return cls(**d)


# --- networks -------------------------------------------------------------------------------


def squashed_log_prob(u: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """log π(tanh(u)|s) for u ~ N(mean, exp(log_std)²) per dimension, summed over the last axis.

    1801.01290 appendix C (eq. 21): the density of a = tanh(u) is N(u)·|da/du|⁻¹, da/du = 1 − tanh²(u),
    and log(1 − tanh²(u)) = 2·(log 2 − u − softplus(−2u)) exactly (stable for large |u|)."""
    z = (u - mean) * torch.exp(-log_std)
    log_normal = -0.5 * z * z - log_std - HALF_LOG_2PI
    log_det = 2.0 * (LOG2 - u - F.softplus(-2.0 * u))
    return (log_normal - log_det).sum(-1)


class SquashedGaussianActor(nn.Module):
    """π_φ(a|s): an MLP trunk with a mean head and a log-σ head; a = tanh(mean + σ·ε).

    `actor` is the deterministic policy as one `nn.Sequential`, trunk → mean head → Tanh, so the
    exported graph (and the runtime's architecture spec: the last layer's activation is tanh) is
    tanh(mean), the action SAC evaluates. The log-σ head reads the trunk's features beside it.
    Initialisation as `networks.mlp` (orthogonal, gain √2 hidden), mean head gain 0.01 so the initial
    deterministic action is ≈ 0, hover trim."""

    squash = "tanh"

    def __init__(
        self,
        obs_dim: int,
        act_dim: int = ACT_DIM,
        hidden: tuple[int, ...] = (64, 64),
        activation: str = "relu",
        init_log_std: float = 0.0,
        log_std_bounds: tuple[float, float] = (-5.0, 2.0),
    ) -> None:
        super().__init__()
        self.obs_dim, self.act_dim = obs_dim, act_dim
        self.log_std_bounds = (float(log_std_bounds[0]), float(log_std_bounds[1]))
        body = mlp(obs_dim, tuple(hidden), act_dim, activation, out_gain=0.01)
        self.actor = nn.Sequential(*body, nn.Tanh())
        self.log_std_head = nn.Linear(hidden[-1], act_dim)
        nn.init.orthogonal_(self.log_std_head.weight, 0.01)
        nn.init.constant_(self.log_std_head.bias, float(init_log_std))
        # plain references (not registered twice): the trunk and the mean head inside `actor`
        self._trunk = tuple(body)[:-1]
        self._mean_head = body[-1]

    def features(self, obs: torch.Tensor) -> torch.Tensor:
        x = obs
        for m in self._trunk:
            x = m(x)
        return x

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean, log σ) of u, each (B, act_dim); log σ clamped to log_std_bounds."""
        h = self.features(obs)
        lo, hi = self.log_std_bounds
        return self._mean_head(h), self.log_std_head(h).clamp(lo, hi)

    def sample(self, obs: torch.Tensor, generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised action a = tanh(mean + σ·ε) (B, act_dim) and log π(a|s) (B,)."""
        mean, log_std = self(obs)
        eps = torch.randn(mean.shape, generator=generator, dtype=mean.dtype)
        u = mean + log_std.exp() * eps
        return torch.tanh(u), squashed_log_prob(u, mean, log_std)

    def mean_action(self, obs: torch.Tensor) -> torch.Tensor:
        """The deterministic action tanh(mean) in (−1, 1): what is evaluated, exported and flown."""
        return self.actor(obs)


class TwinQ(nn.Module):
    """Q_θ1(s, a) and Q_θ2(s, a): two MLPs of the same shape, their weights stacked on a leading axis
    of 2 and applied with one batched matmul per layer (the maths of two separate MLPs, half the
    calls). Initialisation as `networks.mlp`: orthogonal per critic, gain √2 hidden and 1 output."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...], activation: str) -> None:
        super().__init__()
        dims = [obs_dim + act_dim, *hidden, 1]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for k in range(len(dims) - 1):
            w = torch.empty(2, dims[k], dims[k + 1])
            gain = 1.0 if k == len(dims) - 2 else math.sqrt(2.0)
            for j in range(2):
                nn.init.orthogonal_(w[j], gain)
            self.weights.append(nn.Parameter(w))
            self.biases.append(nn.Parameter(torch.zeros(2, 1, dims[k + 1])))
        self.act = ACTIVATIONS[activation]()

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        """(2, B): both critics' Q for obs (B, obs_dim) and act (B, act_dim)."""
        x = torch.cat([obs, act], -1)
        x = x.unsqueeze(0).expand(2, *x.shape)
        last = len(self.weights) - 1
        for k, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            x = torch.baddbmm(b, x, w)
            if k < last:
                x = self.act(x)
        return x.squeeze(-1)


def build_actor(obs_dim: int, cfg: SACConfig) -> SquashedGaussianActor:
    """The actor a SACConfig describes (also what `checkpoint.TrainedPolicy` builds for export)."""
    return SquashedGaussianActor(
        obs_dim, ACT_DIM, cfg.actor_hidden, cfg.activation, cfg.init_log_std, (cfg.log_std_min, cfg.log_std_max)
    )


@torch.no_grad()
def polyak_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """θ̄ ← τ θ + (1 − τ) θ̄ for every parameter (1812.05905 Algorithm 1)."""
    for pt, p in zip(target.parameters(), source.parameters(), strict=True):
        pt.lerp_(p, tau)


def temperature_loss(log_alpha: torch.Tensor, log_prob: torch.Tensor, target_entropy: float) -> torch.Tensor:
    """J(α) of 1812.05905 eq. 18 over log α: −log α · E[log π(a|s) + H̄]. With the policy's entropy
    −E[log π] below the target H̄ its gradient is negative, so a descent step raises α."""
    return -(log_alpha * (log_prob.detach() + target_entropy)).mean()


# --- replay buffer --------------------------------------------------------------------------


class ReplayBuffer:
    """A ring buffer of transitions (s, a, r, s', terminated), one float32 row each:
    [obs (D) | action (4) | reward (1) | next obs (D) | terminated (1)].

    `stored` counts every transition ever added; transition i lives in row i mod capacity. The
    reward is stored unscaled. s' of a drone whose episode ended is its final observation (the
    vector env's `final_obs`), never the next episode's first."""

    def __init__(self, capacity: int, obs_dim: int, act_dim: int = ACT_DIM) -> None:
        self.capacity, self.obs_dim, self.act_dim = int(capacity), obs_dim, act_dim
        d, a = obs_dim, act_dim
        self.width = 2 * d + a + 2
        self.slices = {
            "obs": slice(0, d),
            "act": slice(d, d + a),
            "rew": slice(d + a, d + a + 1),
            "next_obs": slice(d + a + 1, 2 * d + a + 1),
            "term": slice(2 * d + a + 1, 2 * d + a + 2),
        }
        self.data = torch.empty(self.capacity, self.width)  # pages are touched only as rows arrive
        self.stored = 0

    def __len__(self) -> int:
        return min(self.stored, self.capacity)

    def add(self, obs, act, rew, next_obs, term) -> None:
        """Append n transitions: obs, next_obs (n, D); act (n, 4); rew, term (n,)."""
        n = obs.shape[0]
        assert obs.shape == next_obs.shape == (n, self.obs_dim) and act.shape == (n, self.act_dim)
        rows = np.empty((n, self.width), np.float32)
        s = self.slices
        rows[:, s["obs"]] = obs
        rows[:, s["act"]] = act
        rows[:, s["rew"]] = np.asarray(rew).reshape(n, 1)
        rows[:, s["next_obs"]] = next_obs
        rows[:, s["term"]] = np.asarray(term).reshape(n, 1)
        self.put_rows(self.stored, torch.from_numpy(rows))

    def put_rows(self, start: int, rows: torch.Tensor) -> None:
        """Write rows for transitions start, start + 1, … (at most `capacity` of them)."""
        n = rows.shape[0]
        if n > self.capacity:
            rows, start, n = rows[-self.capacity :], start + n - self.capacity, self.capacity
        i = start % self.capacity
        first = min(n, self.capacity - i)
        self.data[i : i + first] = rows[:first]
        if first < n:
            self.data[: n - first] = rows[first:]
        self.stored = max(self.stored, start + n)

    def rows(self, start: int, end: int) -> torch.Tensor:
        """A copy of transitions start … end − 1 (they must still be in the buffer)."""
        if not (self.stored - len(self) <= start <= end <= self.stored):
            raise ValueError(
                f"transitions {start}…{end} are not in the buffer ({self.stored - len(self)}…{self.stored})"
            )
        idx = torch.arange(start, end) % self.capacity
        return self.data[idx].clone()

    def sample(self, n: int, generator: torch.Generator) -> dict[str, torch.Tensor]:
        """n transitions drawn uniformly with replacement: views of one gathered (n, width) tensor."""
        rows = self.data[torch.randint(len(self), (n,), generator=generator)]
        s = self.slices
        return {
            "obs": rows[:, s["obs"]],
            "act": rows[:, s["act"]],
            "rew": rows[:, s["rew"]].squeeze(1),
            "next_obs": rows[:, s["next_obs"]],
            "term": rows[:, s["term"]].squeeze(1),
        }


# --- the trainer ----------------------------------------------------------------------------


class SAC:
    """The trainer: vector environment, actor, twin critics and their targets, temperature,
    optimisers, replay buffer and RNGs. `iterate()` runs one iteration and returns its metrics."""

    def __init__(self, cfg: SACConfig, env_cfg: EnvConfig) -> None:
        self.cfg, self.env_cfg = cfg, env_cfg
        torch.set_num_threads(cfg.threads)
        self.env = QuadVectorEnv(cfg.num_envs, config=env_cfg)
        obs_dim = env_cfg.layout.dim
        self.torch_gen = torch.Generator().manual_seed(cfg.seed)
        torch.manual_seed(cfg.seed)  # parameter initialisation draws from the default generator
        self.actor = build_actor(obs_dim, cfg)
        self.critic = TwinQ(obs_dim, ACT_DIM, cfg.critic_hidden, cfg.activation)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.log_alpha = torch.tensor(math.log(cfg.init_alpha), requires_grad=True)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=cfg.actor_lr)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=cfg.critic_lr)
        self.alpha_opt = torch.optim.Adam([self.log_alpha], lr=cfg.alpha_lr)
        self.buffer = ReplayBuffer(cfg.buffer_size, obs_dim)
        self.global_step = 0
        self.updates = 0  # iterations
        self.grad_steps = 0
        self._nonfinite_streak = 0
        self.ep_returns: list[float] = []
        self.ep_lengths: list[int] = []
        self.ep_success: list[bool] = []
        self.reseed(cfg.seed)

    @property
    def model(self) -> SquashedGaussianActor:
        """The policy network (the name the export path and PPO use)."""
        return self.actor

    @property
    def alpha(self) -> float:
        return float(self.log_alpha.detach().exp())

    def reseed(self, seed: int) -> None:
        raw, _ = self.env.reset(seed=seed)
        self._obs = raw

    # --- learning ------------------------------------------------------------------------
    def gradient_step(self) -> dict[str, float] | None:
        """One critic, actor and temperature step on a minibatch, then the target update. Returns
        the losses, or None if a loss was not finite: that step and the ones after it in this call are
        skipped (a non-finite critic loss changes nothing; a non-finite actor loss leaves the critic
        step done and skips the actor, temperature and target steps)."""
        cfg = self.cfg
        b = self.buffer.sample(cfg.minibatch_size, self.torch_gen)
        alpha = self.log_alpha.detach().exp()
        with torch.no_grad():
            next_a, next_logp = self.actor.sample(b["next_obs"], self.torch_gen)
            next_q = self.critic_target(b["next_obs"], next_a).min(0).values
            y = cfg.reward_scale * b["rew"] + cfg.gamma * (1.0 - b["term"]) * (next_q - alpha * next_logp)
        q = self.critic(b["obs"], b["act"])  # (2, B)
        q_loss = 0.5 * ((q - y) ** 2).mean(1).sum()  # J_Q of both critics (eq. 5)
        if not torch.isfinite(q_loss):
            return None
        self.critic_opt.zero_grad(set_to_none=True)
        q_loss.backward()
        self.critic_opt.step()

        self.critic.requires_grad_(False)  # the actor's loss moves the actor only
        try:
            a, logp = self.actor.sample(b["obs"], self.torch_gen)
            pi_loss = (alpha * logp - self.critic(b["obs"], a).min(0).values).mean()  # eq. 7
            if not torch.isfinite(pi_loss):
                return None
            self.actor_opt.zero_grad(set_to_none=True)
            pi_loss.backward()
            self.actor_opt.step()
        finally:
            self.critic.requires_grad_(True)

        alpha_loss = temperature_loss(self.log_alpha, logp, cfg.entropy_target)
        if cfg.autotune_alpha:
            self.alpha_opt.zero_grad(set_to_none=True)
            alpha_loss.backward()
            self.alpha_opt.step()
        polyak_update(self.critic_target, self.critic, cfg.tau)
        self.grad_steps += 1
        return {
            "q_loss": q_loss.item(),
            "policy_loss": pi_loss.item(),
            "alpha_loss": alpha_loss.item(),
            "entropy": -logp.detach().mean().item(),
            "q_mean": q.detach().mean().item(),
        }

    # --- one iteration -------------------------------------------------------------------
    def iterate(self) -> dict[str, float]:
        """`rollout_steps` vector steps, each followed by `updates_per_step` gradient steps once
        `learning_starts` transitions are stored. Returns every metric under its fixed name."""
        cfg, n = self.cfg, self.cfg.num_envs
        t0 = time.perf_counter()
        env_s = update_s = 0.0
        n_before = len(self.ep_returns)
        stats: dict[str, list[float]] = {k: [] for k in ("q_loss", "policy_loss", "alpha_loss", "entropy", "q_mean")}
        skipped = 0
        for _ in range(cfg.rollout_steps):
            with torch.inference_mode():
                if self.global_step < cfg.learning_starts:
                    action = torch.rand((n, ACT_DIM), generator=self.torch_gen) * 2.0 - 1.0
                else:
                    action, _ = self.actor.sample(torch.from_numpy(self._obs), self.torch_gen)
            act = action.numpy()
            te = time.perf_counter()
            raw, reward, term, _trunc, infos = self.env.step(act)  # truncation: bootstrap
            env_s += time.perf_counter() - te
            final = infos["final_obs"] if "_final_obs" in infos else raw  # s' of ended drones: their last obs
            self.buffer.add(self._obs, act, reward, final, term)
            if "_episode" in infos:
                ended, ep = infos["_episode"], infos["episode"]
                self.ep_returns.extend(ep["r"][ended].tolist())
                self.ep_lengths.extend(ep["l"][ended].tolist())
                self.ep_success.extend(ep["success"][ended].tolist())
            self._obs = raw
            self.global_step += n
            if self.global_step >= cfg.learning_starts:
                tu = time.perf_counter()
                for _ in range(cfg.updates_per_step):
                    s = self.gradient_step()
                    if s is None:
                        skipped += 1
                        continue
                    for k, v in s.items():
                        stats[k].append(v)
                update_s += time.perf_counter() - tu
        self.updates += 1
        if skipped:
            self._nonfinite_streak += 1
            if self._nonfinite_streak >= cfg.max_nonfinite_updates:
                from .ppo import NonFiniteError

                raise NonFiniteError(
                    f"{self._nonfinite_streak} consecutive SAC iterations met NaN/Inf losses (this one: {skipped} "
                    "skipped gradient steps; the weights were not touched by them). Lower the learning rates or "
                    "the reward scale, or check the environment and reward for NaN."
                )
        else:
            self._nonfinite_streak = 0
        t1 = time.perf_counter()
        recent = slice(max(n_before, len(self.ep_returns) - 4 * n), None)
        ended_r, ended_l, ended_s = self.ep_returns[recent], self.ep_lengths[recent], self.ep_success[recent]
        out = {k: float(np.mean(v)) if v else float("nan") for k, v in stats.items()}
        out.update(
            global_step=self.global_step,
            update=self.updates,
            alpha=self.alpha,
            grad_steps=self.grad_steps,
            steps_per_s=cfg.batch_size / (t1 - t0),
            rollout_s=t1 - t0 - update_s,
            env_s=env_s,
            inference_s=t1 - t0 - update_s - env_s,
            update_s=update_s,
            ep_return=float(np.mean(ended_r)) if ended_r else float("nan"),
            ep_length=float(np.mean(ended_l)) if ended_l else float("nan"),
            success_rate=float(np.mean(ended_s)) if ended_s else float("nan"),
            episodes=len(ended_r),
            buffer_size=len(self.buffer),
            nonfinite_skipped=skipped,
        )
        keep = 8 * n
        del self.ep_returns[:-keep], self.ep_lengths[:-keep], self.ep_success[:-keep]
        return out

    @torch.inference_mode()
    def act_deterministic(self, raw_obs: np.ndarray) -> np.ndarray:
        """tanh(mean) for raw observations (N, obs_dim): what evaluation and export use."""
        return self.actor.mean_action(torch.from_numpy(np.asarray(raw_obs, np.float32))).numpy()


# --- checkpoints ----------------------------------------------------------------------------


def _tensor(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.array(a, copy=True))


def _clone_state(module_or_opt) -> dict:
    return copy.deepcopy(module_or_opt.state_dict())


def checkpoint_dict(sac: SAC, extra: dict | None = None) -> dict:
    """A checkpoint (checkpoint.pt / policy.pt) of `sac`: tensors and JSON-able data only. The
    replay buffer's rows are not in it: they live in replay/ chunks (`save_replay_chunk`); the
    checkpoint records how many transitions it covers. `model` is the actor, as in a PPO checkpoint,
    and `obs_rms` the identity (SAC trains on raw observations), so export reads both alike."""
    batch = sac.env.batch
    obs_dim = sac.env_cfg.layout.dim
    return plain(
        {
            "schema": SCHEMA,
            "algo": "sac",
            "created_unix": time.time(),
            "sac_config": sac.cfg.to_json(),
            "env_config": sac.env_cfg.to_json(),
            "obs_layout": sac.env_cfg.layout.to_json(),
            "model": _clone_state(sac.actor),
            "critic": _clone_state(sac.critic),
            "critic_target": _clone_state(sac.critic_target),
            "log_alpha": sac.log_alpha.detach().clone(),
            "optimizer": {
                "actor": _clone_state(sac.actor_opt),
                "critic": _clone_state(sac.critic_opt),
                "alpha": _clone_state(sac.alpha_opt),
            },
            "obs_rms": {"mean": np.zeros(obs_dim), "var": np.ones(obs_dim), "count": 1e-4, "clip": 10.0},
            "global_step": int(sac.global_step),
            "updates": int(sac.updates),
            "grad_steps": int(sac.grad_steps),
            "trainer": {
                "nonfinite_streak": int(sac._nonfinite_streak),
                "ep_returns": [float(x) for x in sac.ep_returns],
                "ep_lengths": [int(x) for x in sac.ep_lengths],
                "ep_success": [bool(x) for x in sac.ep_success],
                "obs": _tensor(sac._obs),
            },
            "env": {
                **{name: _tensor(getattr(batch, name)) for name in _ENV_ARRAYS},
                "target_radius": float(batch.target_radius),
                "started": bool(sac.env._started),
            },
            "rng": {
                "env": copy.deepcopy(sac.env._rng.bit_generator.state),
                "torch_gen": sac.torch_gen.get_state(),
                "torch_default": torch.get_rng_state(),
            },
            "replay": {"stored": int(sac.buffer.stored), "capacity": sac.buffer.capacity, "dir": REPLAY_DIR},
            "extra": dict(extra or {}),
        }
    )


def load_sac_state(sac: SAC, ckpt: dict, source: str = "checkpoint") -> None:
    """Put a loaded checkpoint's state into `sac` (built with the same configuration), all but the
    replay rows (`load_replay`). Raises CheckpointError if anything does not fit."""
    opt = ckpt["optimizer"]
    mine = {"actor": sac.actor_opt, "critic": sac.critic_opt, "alpha": sac.alpha_opt}
    if not isinstance(opt, dict) or set(opt) != set(mine):
        raise CheckpointError(f"{source}: optimizer: expected the actor, critic and alpha optimizers' states")
    check_fits(sac, checkpoint_dict(sac), ckpt, source, {f"optimizer.{k}": (opt[k], o) for k, o in mine.items()})
    _check_env_shapes(sac.env.batch, ckpt["env"], source)
    try:
        sac.actor.load_state_dict(ckpt["model"])
        sac.critic.load_state_dict(ckpt["critic"])
        sac.critic_target.load_state_dict(ckpt["critic_target"])
        sac.actor_opt.load_state_dict(opt["actor"])
        sac.critic_opt.load_state_dict(opt["critic"])
        sac.alpha_opt.load_state_dict(opt["alpha"])
    except (RuntimeError, ValueError, KeyError) as e:
        raise CheckpointError(f"{source}: weights do not fit these networks ({_one_line(e)})") from None
    try:  # checked above and in load_checkpoint; what is left is what the loaders refuse
        with torch.no_grad():
            sac.log_alpha.copy_(ckpt["log_alpha"])
        sac.global_step = int(ckpt["global_step"])
        sac.updates = int(ckpt["updates"])
        sac.grad_steps = int(ckpt["grad_steps"])
        _load_episode_state(sac, ckpt["trainer"])
        _load_env_state(sac, ckpt["env"])
        _load_rng_state(sac, ckpt["rng"], source)
    except (KeyError, TypeError, ValueError, RuntimeError, IndexError, AttributeError) as e:
        raise CheckpointError(f"{source}: training state does not fit this trainer ({_one_line(e)})") from None


_CHUNK = re.compile(r"^(\d{12})-(\d{12})\.pt$")


def _chunks(directory: Path) -> list[tuple[int, int, Path]]:
    """(start, end, path) of the replay chunks in directory/replay, by start."""
    d = directory / REPLAY_DIR
    if not d.is_dir():
        return []
    out = []
    for p in d.iterdir():
        m = _CHUNK.match(p.name)
        if m:
            out.append((int(m.group(1)), int(m.group(2)), p))
    return sorted(out)


def save_replay_chunk(directory: str | os.PathLike, buffer: ReplayBuffer, start: int) -> Path | None:
    """Write transitions start … buffer.stored − 1 (those still in the buffer) as one immutable
    chunk file replay/<start>-<end>.pt, atomically; None if there is nothing new."""
    directory = Path(directory)
    end = buffer.stored
    start = max(start, end - len(buffer))
    if end <= start:
        return None
    (directory / REPLAY_DIR).mkdir(exist_ok=True)
    data = {"schema": REPLAY_SCHEMA, "start": start, "end": end, "rows": buffer.rows(start, end)}
    return atomic_write(directory / REPLAY_DIR / f"{start:012d}-{end:012d}.pt", lambda f: torch.save(data, f))


def prune_replay(directory: str | os.PathLike, keep_from: int) -> None:
    """Delete chunks that end at or before transition `keep_from` (no checkpoint needs them)."""
    for _start, end, p in _chunks(Path(directory)):
        if end <= keep_from:
            p.unlink(missing_ok=True)


def load_replay(directory: str | os.PathLike, buffer: ReplayBuffer, stored: int) -> None:
    """Refill `buffer` with the transitions max(0, stored − capacity) … stored − 1 from the chunks
    in directory/replay. Chunks from beyond `stored` (written before a kill, after the checkpoint)
    are deleted. Raises CheckpointError naming what is missing or unreadable."""
    directory = Path(directory)
    need_from = max(0, stored - buffer.capacity)
    pos = need_from
    for start, end, p in _chunks(directory):
        if start >= stored:
            p.unlink(missing_ok=True)  # written after the checkpoint we resume from
            continue
        if end <= need_from:
            continue
        if start > pos or end > stored:
            break
        try:
            chunk = torch.load(p, map_location="cpu", weights_only=True)
            rows = chunk["rows"]
            ok = chunk.get("schema") == REPLAY_SCHEMA and tuple(rows.shape) == (end - start, buffer.width)
        except Exception as e:  # a torn or foreign file
            raise CheckpointError(f"{p}: unreadable replay chunk ({type(e).__name__}: {e})") from e
        if not ok:
            raise CheckpointError(f"{p}: not a replay chunk of this run (schema {REPLAY_SCHEMA}, width {buffer.width})")
        lo = max(start, pos)
        buffer.put_rows(lo, rows[lo - start :])
        pos = end
    if pos != stored:
        raise CheckpointError(
            f"{directory / REPLAY_DIR}: the checkpoint's replay buffer holds transitions {need_from:,}…{stored:,}, "
            f"but the chunks there reach only {pos:,}; the replay buffer cannot be rebuilt, so this run "
            "cannot be resumed (start a new run with another --out)"
        )
    buffer.stored = stored


def save_for_resume(directory: str | os.PathLike, sac: SAC, saved_stored: int, extra: dict | None = None) -> int:
    """The new replay rows as a chunk, then checkpoint.pt (the previous one kept as
    checkpoint.prev.pt), then the chunks neither generation needs are deleted. `saved_stored` is the
    buffer count at the previous save; returns the count of this one."""
    directory = Path(directory)
    save_replay_chunk(directory, sac.buffer, saved_stored)
    data = checkpoint_dict(sac, extra)
    atomic_write(directory / LATEST, lambda f: torch.save(data, f), keep_previous=PREVIOUS)
    prune_replay(directory, saved_stored - sac.buffer.capacity)  # what checkpoint.prev.pt needs stays
    return sac.buffer.stored


def save_policy(path: str | os.PathLike, sac: SAC, extra: dict | None = None) -> Path:
    """policy.pt: the same content as checkpoint.pt (no replay rows), what quad-export reads."""
    data = checkpoint_dict(sac, extra)
    return atomic_write(path, lambda f: torch.save(data, f))


def sac_from_checkpoint(
    directory: str | os.PathLike, ckpt: dict, cfg: SACConfig | None = None, source: str = ""
) -> SAC:
    """A SAC trainer rebuilt from a loaded checkpoint and the replay chunks beside it."""
    try:
        cfg = cfg or SACConfig.from_json(ckpt["sac_config"])
        sac = SAC(cfg, EnvConfig.from_json(ckpt["env_config"]))
    except (KeyError, TypeError, ValueError) as e:
        where = source or directory
        raise CheckpointError(f"{where}: its configuration cannot build a trainer ({_one_line(e)})") from None
    load_sac_state(sac, ckpt, source or str(directory))
    load_replay(directory, sac.buffer, int(ckpt["replay"]["stored"]))
    return sac


def load_trainer(path: str | os.PathLike) -> SAC:
    """The SAC trainer of a run directory's checkpoint.pt (for tests and notebooks)."""
    path = Path(path)
    return sac_from_checkpoint(path.parent, load_checkpoint(path), source=str(path))


# --- metrics.csv ----------------------------------------------------------------------------

# The PPO file's column names where they mean the same (runlog.COLUMNS), SAC's own in between.
COLUMNS = (
    "global_step",
    "update",
    "time_s",
    "q_loss",
    "policy_loss",
    "alpha",
    "alpha_loss",
    "entropy",
    "q_mean",
    "grad_steps",
    "steps_per_s",
    "rollout_s",
    "env_s",
    "inference_s",
    "update_s",
    "ep_return",
    "ep_length",
    "success_rate",
    "episodes",
    "buffer_size",
    "nonfinite_skipped",
    "curriculum_stage",
    "target_radius",
    "eval_success_rate",
    "eval_error_m",
)
HEADER = ",".join(COLUMNS)


class MetricsLog(runlog.MetricsLog):
    """metrics.csv of a SAC run: runlog.MetricsLog with SAC's COLUMNS, one row per iteration."""

    def __init__(self, path: str | os.PathLike) -> None:
        super().__init__(path, COLUMNS)


def read_rows(path: str | os.PathLike) -> list[dict[str, str]]:
    """Complete rows of a SAC metrics.csv (a torn last line is dropped)."""
    return runlog._rows(Path(path), COLUMNS)


def read_metrics(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """A SAC metrics.csv as float columns (blank cells are NaN)."""
    return runlog.read_metrics(path, COLUMNS)


def truncate_metrics(path: str | os.PathLike, updates: int) -> int:
    """Keep rows of iterations 1 … `updates`, rewrite atomically; returns rows dropped."""
    return runlog.truncate_metrics(path, updates, COLUMNS)


def plot_curves(metrics_path: str | os.PathLike, out_path: str | os.PathLike, title: str = "") -> Path:
    """curves.png of a SAC run: return, success (training and evaluation), critic loss, α and entropy."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    m = read_metrics(metrics_path)
    x = m["global_step"]
    fig = Figure(figsize=(8, 8), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(4, 1, sharex=True)
    axes[0].plot(x, m["ep_return"], lw=1.2)
    axes[0].set_ylabel("episode return")
    axes[1].plot(x, m["success_rate"], lw=1.2, label="training episodes")
    ev = np.isfinite(m["eval_success_rate"])
    if ev.any():
        axes[1].plot(x[ev], m["eval_success_rate"][ev], "o-", ms=3, lw=1, color="C2", label="evaluation (tanh(mean))")
    axes[1].set_ylim(-0.02, 1.02)
    axes[1].set_ylabel("success")
    axes[1].legend(loc="lower right", fontsize=8)
    axes[2].semilogy(x, m["q_loss"], lw=1.2)
    axes[2].set_ylabel("critic loss")
    axes[3].semilogy(x, m["alpha"], lw=1.2, label="α")
    axes[3].set_ylabel("temperature α")
    ax2 = axes[3].twinx()
    ax2.plot(x, m["entropy"], lw=1, color="C1")
    ax2.set_ylabel("entropy (nats)", color="C1")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("environment steps")
    if title:
        fig.suptitle(title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return atomic_write(out_path, lambda f: f.write(buf.getvalue()))


# --- quad-train --algo sac ------------------------------------------------------------------


def parse_overrides(items: list[str] | None) -> dict[str, Any]:
    """--set NAME=VALUE items as SACConfig field values, typed by the field (int, float, bool,
    tuple of ints, str, or None for an optional field). Raises ValueError naming the problem."""
    fields = {f.name: f for f in dataclasses.fields(SACConfig)}
    out: dict[str, Any] = {}
    for item in items or []:
        name, sep, text = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or name not in fields:
            known = ", ".join(sorted(fields))
            raise ValueError(f"--set {item!r}: expected NAME=VALUE with NAME a SAC hyper-parameter ({known})")
        kind = str(fields[name].type)
        text = text.strip()
        try:
            if text.lower() == "none" and "None" in kind:
                value: Any = None
            elif kind.startswith("tuple"):
                value = tuple(int(v) for v in text.replace("x", ",").split(",") if v.strip())
            elif kind == "bool":
                if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                    raise ValueError(text)
                value = text.lower() in ("true", "1", "yes")
            elif kind == "int":
                value = int(text.replace("_", ""))
            elif kind.startswith("float"):
                value = float(text)
            else:
                value = text
        except ValueError:
            raise ValueError(f"--set {item!r}: {text!r} is not a valid {kind}") from None
        out[name] = value
    return out


def train_from_cli(args, argv: list[str]) -> int:
    """`quad-train --algo sac ...`: the PPO run's options where they apply (--task, --total-steps,
    --num-envs, --seed, --rollout-steps, --minibatch-size, --threads, --vehicle, --out, --resume,
    --eval-episodes, --eval-every, --checkpoint-every) plus --set NAME=VALUE for any SACConfig field;
    the same run-directory files, evaluation and success bar as our PPO."""
    from .cli import PPO_OPTIONS, RESUME_MAY_CHANGE, UsageError, _Stop

    if args.preset:
        raise UsageError("--preset chooses a PPO recipe; --algo sac takes SACConfig's defaults and --set NAME=VALUE")
    if getattr(args, "randomize", None):
        raise UsageError("--randomize is not wired to --algo sac yet; SAC trains on the nominal plant")
    explicit = {k: getattr(args, k) for k in PPO_OPTIONS if getattr(args, k) is not None}
    try:
        explicit.update(parse_overrides(getattr(args, "set", None)))
    except ValueError as e:
        raise UsageError(str(e)) from None
    seed = explicit.get("seed", SACConfig.seed)
    out = Path(args.out or f"runs/{args.task}-sac-seed{seed}")
    if args.resume:
        sac, cur, elapsed0, first_success = _resume(args, explicit, out, argv, RESUME_MAY_CHANGE)
    else:
        sac, cur, elapsed0, first_success = _start_fresh(args, explicit, out, argv)
    with _Stop() as stop:
        return _loop(args, argv, out, sac, cur, elapsed0, first_success, stop)


def _start_fresh(args, explicit: dict, out: Path, argv: list[str]):
    from .cli import UsageError, _check_fresh_dir, _check_sizes, _claim_fresh_dir, _command, _now
    from .curriculum import CurriculumConfig, WaypointCurriculum
    from .envs import make_config
    from .runlog import write_json

    _check_fresh_dir(out)
    try:
        cfg = SACConfig(**explicit)
    except ValueError as e:
        raise UsageError(f"SAC configuration: {e}") from None
    _check_sizes(cfg)
    env_kw = {"vehicle": args.vehicle} if args.vehicle else {}
    cur_cfg = CurriculumConfig() if args.task == "waypoint" else None
    if cur_cfg is not None:
        env_kw["target_radius"] = cur_cfg.radii[0]
    env_cfg = make_config(args.task, **env_kw)
    sac = SAC(cfg, env_cfg)  # before any file is written
    _claim_fresh_dir(out)
    write_json(
        out / "config.json",
        {
            "schema": "quadpilot.run/1",
            "algo": "sac",
            "task": args.task,
            "sac": cfg.to_json(),
            "update_to_data": cfg.update_to_data,
            "env": env_cfg.to_json(),
            "curriculum": cur_cfg.to_json() if cur_cfg else None,
            "checkpoint_every": args.checkpoint_every,
            "eval_episodes": args.eval_episodes,
            "eval_every": args.eval_every,
            "command": _command(argv),
            "started": _now(),
            "resumes": [],
            "versions": {"torch": torch.__version__, "numpy": np.__version__, "python": sys.version.split()[0]},
        },
    )
    MetricsLog(out / "metrics.csv").close()
    cur = WaypointCurriculum(cur_cfg, cfg.num_envs, cfg.rollout_steps, env_cfg.episode_steps) if cur_cfg else None
    return sac, cur, 0.0, None


def _resume(args, explicit: dict, out: Path, argv: list[str], may_change: tuple[str, ...]):
    from .checkpoint import load_for_resume
    from .cli import (
        UsageError,
        _check_resume_dir,
        _clean_stale_temps,
        _record_resume,
        _restore_curriculum,
        _vehicle_clash,
    )

    _check_resume_dir(out)
    ckpt, used, warning = load_for_resume(out)  # CheckpointError: a bad file, exit 1 (cli.main)
    if ckpt.get("algo", "ppo") != "sac":
        raise UsageError(f"{out} holds a {ckpt.get('algo', 'ppo')} run; resume it without --algo sac")
    if warning:
        print(f"quad-train: warning: {warning}", file=sys.stderr)
    task = ckpt["env_config"]["task"]
    if args.task != task:
        raise UsageError(f"{out} holds a {task} run; --task {args.task} does not match it")
    stored = SACConfig.from_json(ckpt["sac_config"])
    clashes = [
        f"--{k.replace('_', '-')} {v} (checkpoint: {getattr(stored, k)})"
        for k, v in explicit.items()
        if k not in may_change and v != getattr(stored, k)
    ]
    clashes += _vehicle_clash(args, ckpt["env_config"])  # a name or a file's parameters, as PPO's resume
    if clashes:
        raise UsageError(
            f"a resumed run keeps its configuration; only {', '.join('--' + k.replace('_', '-') for k in may_change)} "
            f"may change: {', '.join(clashes)}"
        )
    cfg = dataclasses.replace(stored, **{k: v for k, v in explicit.items() if k in may_change})
    _clean_stale_temps(out)
    for f in (out / REPLAY_DIR).glob(".*.tmp"):
        f.unlink(missing_ok=True)
    sac = sac_from_checkpoint(out, ckpt, cfg, source=str(used))
    extra = ckpt["extra"]
    cur = _restore_curriculum(sac, extra)
    _record_resume(out, argv, used, sac.updates, "sac", cfg.to_json(), COLUMNS)
    print(
        f"quad-train: resuming {out} from {used.name} at iteration {sac.updates} ({sac.global_step:,} steps)",
        flush=True,
    )
    return sac, cur, float(extra.get("elapsed_s", 0.0)), extra.get("first_success")


def _loop(args, argv, out: Path, sac: SAC, cur, elapsed0: float, first_success, stop) -> int:
    from .cli import _command, _evaluate_and_advance, _final_evaluation, _Progress, _resume_argv, _time_breakdown

    cfg = sac.cfg
    t0 = time.perf_counter()
    eval_s = 0.0
    saved_stored = sac.buffer.stored if args.resume else 0
    saved_at = sac.updates if args.resume else -1
    last: dict | None = None

    def train_time() -> float:
        return elapsed0 + time.perf_counter() - t0 - eval_s

    def extra(metrics: dict | None) -> dict:
        return {
            "curriculum": cur.state_dict() if cur else None,
            "metrics": metrics or {},
            "elapsed_s": train_time(),
            "first_success": first_success,
            "command": _command(argv),
        }

    progress = _Progress(f"quad-train {args.task} (sac)", sac.global_step, cfg.num_updates * cfg.batch_size)
    try:
        with MetricsLog(out / "metrics.csv") as log:
            while sac.updates < cfg.num_updates and stop.signal is None:
                m = sac.iterate()
                m["time_s"] = train_time()
                first_success, dt = _evaluate_and_advance(sac, args, cur, m, first_success)
                eval_s += dt
                log.write(m)
                last = m
                if sac.updates % args.checkpoint_every == 0 or sac.updates == cfg.num_updates:
                    saved_stored = save_for_resume(out, sac, saved_stored, extra(m))
                    saved_at = sac.updates
                progress.update(m)
            if saved_at != sac.updates:
                saved_stored = save_for_resume(out, sac, saved_stored, extra(last))
    except KeyboardInterrupt:
        progress.close()
        print(f"\nquad-train: aborted; the checkpoint of iteration {saved_at} in {out} is intact.", file=sys.stderr)
        print(f"Resume with: {_command(_resume_argv(argv))}", file=sys.stderr)
        return 130
    finally:
        progress.close()
    plot_curves(out / "metrics.csv", out / "curves.png", f"{args.task} (SAC), {out.name}")
    if stop.signal is not None and sac.updates < cfg.num_updates:
        print(
            f"quad-train: stopped by {stop.signal} after iteration {sac.updates}/{cfg.num_updates}; checkpoint saved "
            f"in {out / LATEST}.\nResume with: {_command(_resume_argv(argv))}",
            file=sys.stderr,
        )
        return 130
    save_policy(out / POLICY, sac, extra(last))
    summary = f"quad-train: done (sac), {sac.global_step:,} steps in {sac.updates} iterations; policy in {out / POLICY}"
    if args.eval_episodes:
        summary += _final_evaluation(
            sac,
            args,
            cur,
            out,
            lambda: {
                "algo": "sac",
                "policy": POLICY,
                "global_step": sac.global_step,
                "updates": sac.updates,
                "grad_steps": sac.grad_steps,
                "train_time_s": extra(last)["elapsed_s"],
                "first_success": first_success,
                "time_breakdown_s": _time_breakdown(out / "metrics.csv", COLUMNS),
            },
        )
    print(summary, flush=True)
    return 0
