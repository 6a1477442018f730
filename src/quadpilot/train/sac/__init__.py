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
  truncation stores the true final observation as s' and bootstraps from it (docs/architecture.md style 4).
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
--eval-every, --checkpoint-every and --snapshot-every count iterations. The run loop, the
environment options and the checkpoint layout are every algorithm's (`runs.loop`, `runs.options`, `runs.trainer`);
what SAC adds to a checkpoint is its critics, temperature and replay count, and beside it the
replay buffer's chunks (`replay`), so a save costs what was added, not the whole buffer.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from ..envs import EnvConfig, QuadVectorEnv
from ..networks import ACTIVATIONS, mlp
from ..runs import plotting, trainer
from ..runs.checks import CheckpointError, check_count, check_tensor, check_weights, short
from .replay import ACT_DIM, REPLAY_DIR, ReplayBuffer, load_replay, prune_replay, save_replay_chunk

LOG2 = math.log(2.0)
HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


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

    def unsquashed_mean(self, obs: torch.Tensor) -> torch.Tensor:
        """The mean before the tanh, `actor` without its last layer: what an exporter squashes itself."""
        return self.actor[:-1](obs)


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
    """The actor a SACConfig describes (also what `runs.checkpoint.TrainedPolicy` builds for export,
    through `SAC.policy_network`)."""
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


# --- metrics.csv ----------------------------------------------------------------------------

# The PPO file's column names where they mean the same (runlog.COLUMNS), SAC's own in between.
COLUMNS = (
    *("global_step", "update", "time_s", "q_loss", "policy_loss", "alpha", "alpha_loss", "entropy", "q_mean"),
    *("grad_steps", "steps_per_s", "rollout_s", "env_s", "inference_s", "update_s", "ep_return", "ep_length"),
    *("success_rate", "episodes", "buffer_size", "nonfinite_skipped", "curriculum_stage", "target_radius"),
    *("eval_success_rate", "eval_error_m"),
)
HEADER = ",".join(COLUMNS)
PANELS = (
    *(("ep_return", "episode return"), ("success_rate", "success"), ("q_loss", "critic loss", True)),
    ("alpha", "temperature α", True, ("entropy", "entropy (nats)")),
)
"""curves.png's panels (`runs.plotting.plot_curves`)."""


# --- the trainer ----------------------------------------------------------------------------


class SAC(trainer.Trainer):
    """The trainer: vector environment, actor, twin critics and their targets, temperature,
    optimisers, replay buffer and RNGs. `iterate()` runs one iteration and returns its metrics;
    `runs.trainer.Trainer` has what it shares with PPO (the episode log, the checkpoint layout, the files)."""

    algo = "sac"
    unit = "iteration"
    tag = "sac"
    Config = SACConfig
    columns = COLUMNS
    run_keys = (
        *("schema", "algo", "task", "sac", "update_to_data", "env", "curriculum", "checkpoint_every"),
        *("snapshot_every", "eval_episodes", "eval_every", "command", "started", "resumes", "versions", "machine"),
    )
    eval_keys = (
        *("algo", "policy", "global_step", "updates", "grad_steps", "train_time_s", "first_success"),
        "time_breakdown_s",
    )
    required = ("critic", "critic_target", "log_alpha", "replay")

    def __init__(self, cfg: SACConfig, env_cfg: EnvConfig) -> None:
        self.cfg, self.env_cfg = cfg, env_cfg
        torch.set_num_threads(cfg.threads)
        env = QuadVectorEnv(cfg.num_envs, config=env_cfg)
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
        self.grad_steps = 0
        self._saved_stored = 0  # the buffer's count at the last save_for_resume: its chunks reach there
        self._start(env)  # updates counts iterations
        self.reseed(cfg.seed)

    @property
    def model(self) -> SquashedGaussianActor:
        """The policy network (the name the export path and PPO use)."""
        return self.actor

    @property
    def alpha(self) -> float:
        return float(self.log_alpha.detach().exp())

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
            if "_final_obs" in infos:
                self._record_episodes(infos)
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
        self._count_nonfinite(
            bool(skipped),
            f"SAC iterations met NaN/Inf losses (this one: {skipped} skipped gradient steps; the weights were not "
            "touched by them). Lower the learning rates or the reward scale, or check the environment and reward "
            "for NaN.",
        )
        t1 = time.perf_counter()
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
            **self._episode_metrics(n_before),
            buffer_size=len(self.buffer),
            nonfinite_skipped=skipped,
        )
        return out

    @torch.inference_mode()
    def act_deterministic(self, raw_obs: np.ndarray) -> np.ndarray:
        """tanh(mean) for raw observations (N, obs_dim): what evaluation and export use."""
        return self.actor.mean_action(torch.from_numpy(np.asarray(raw_obs, np.float32))).numpy()

    # --- checkpoint entries (`trainer.Trainer.state_dict`) and replay files ------------------
    def own_state(self) -> dict:
        """`model` is the actor, as in a PPO checkpoint, and `obs_rms` the identity (SAC trains on raw
        observations), so export reads both alike. The replay rows are not in it: they live in replay/
        chunks; `replay` records how many transitions the checkpoint covers."""
        obs_dim = self.env_cfg.layout.dim
        clone = lambda m: copy.deepcopy(m.state_dict())  # noqa: E731
        return {
            "model": clone(self.actor),
            "critic": clone(self.critic),
            "critic_target": clone(self.critic_target),
            "log_alpha": self.log_alpha.detach().clone(),
            "optimizer": {k: clone(o) for k, o in self._optimizers().items()},
            "obs_rms": {"mean": np.zeros(obs_dim), "var": np.ones(obs_dim), "count": 1e-4, "clip": 10.0},
            "grad_steps": int(self.grad_steps),
            "replay": {"stored": int(self.buffer.stored), "capacity": self.buffer.capacity, "dir": REPLAY_DIR},
        }

    @staticmethod
    def check_entries(ckpt: dict) -> None:
        """SAC's own entries of a checkpoint file (`checkpoint.check_content`); ValueError."""
        check_weights(ckpt["critic"], "critic")
        check_weights(ckpt["critic_target"], "critic_target")
        check_tensor(ckpt["log_alpha"], "log_alpha", shape=())
        replay = ckpt["replay"]
        if not isinstance(replay, dict) or replay.get("dir") != REPLAY_DIR:
            raise ValueError(f"replay: expected a table naming the replay directory, found {short(replay)}")
        check_count(replay.get("stored"), "replay.stored")
        check_count(ckpt.get("grad_steps"), "grad_steps")

    def own_optimizers(self, ckpt: dict, source: str) -> dict:
        opt, mine = ckpt["optimizer"], self._optimizers()
        if not isinstance(opt, dict) or set(opt) != set(mine):
            raise CheckpointError(f"{source}: optimizer: expected the actor, critic and alpha optimizers' states")
        return {f"optimizer.{k}": (opt[k], o) for k, o in mine.items()}

    def _optimizers(self) -> dict:
        return {"actor": self.actor_opt, "critic": self.critic_opt, "alpha": self.alpha_opt}

    def load_own_state(self, ckpt: dict) -> None:
        self.actor.load_state_dict(ckpt["model"])
        self.critic.load_state_dict(ckpt["critic"])
        self.critic_target.load_state_dict(ckpt["critic_target"])
        for k, o in self._optimizers().items():
            o.load_state_dict(ckpt["optimizer"][k])

    def load_own_numbers(self, ckpt: dict) -> None:
        with torch.no_grad():
            self.log_alpha.copy_(ckpt["log_alpha"])
        self.grad_steps = int(ckpt["grad_steps"])
        self._replay_stored = int(ckpt["replay"]["stored"])

    def load_files(self, directory: Path | None) -> None:
        """The replay buffer from the chunks in directory/replay (CheckpointError if they do not
        reach the checkpoint's count)."""
        if directory is None:
            raise CheckpointError("a SAC checkpoint's replay buffer is read from its run directory; none was given")
        load_replay(directory, self.buffer, self._replay_stored)
        self._saved_stored = self.buffer.stored

    @classmethod
    def clean_stale_files(cls, directory: Path) -> None:
        for f in (directory / REPLAY_DIR).glob(".*.tmp"):
            f.unlink(missing_ok=True)

    def save_for_resume(self, directory: str | os.PathLike, extra: dict | None = None) -> Path:
        """The replay rows added since the last save as a chunk, then checkpoint.pt (the previous one
        kept as checkpoint.prev.pt), then the chunks neither generation needs are deleted."""
        directory = Path(directory)
        save_replay_chunk(directory, self.buffer, self._saved_stored)
        path = super().save_for_resume(directory, extra)
        prune_replay(directory, self._saved_stored - self.buffer.capacity)  # what checkpoint.prev.pt needs stays
        self._saved_stored = self.buffer.stored
        return path

    def run_entries(self) -> dict:
        return {"sac": self.cfg.to_json(), "update_to_data": self.cfg.update_to_data}

    @classmethod
    def policy_network(cls, ckpt: dict, obs_dim: int, cfg=None) -> tuple[SquashedGaussianActor, SACConfig]:
        """The actor (tanh of its mean is the action) on raw observations."""
        cfg = SACConfig.from_json(ckpt["sac_config"])
        return build_actor(obs_dim, cfg).eval(), cfg

    def plot_curves(self, metrics_path, out_path, title: str, radii: tuple[float, ...] = ()) -> Path:
        """curves.png: return, success (training and evaluation), critic loss, α and entropy."""
        return plotting.plot_curves(metrics_path, out_path, title, radii, COLUMNS, PANELS)
