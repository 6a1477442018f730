"""PPO's configuration (`PPOConfig`: every hyper-parameter, with its reason, becomes quad-train's
`--help`) and its presets. The algorithm is `ppo`."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

UPDATE_PATHS = ("auto", "numpy", "torch")


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
    of lstm_hidden units and a linear head each, trained on sequences: `recurrent`)."""
    lstm_hidden: int = 64
    """LSTM width when arch is lstm."""
    bptt_steps: int = 0
    """arch lstm: truncated backprop through time, the length L of the sequences each drone's
    rollout is cut into (each replayed from the LSTM state stored at collection); minibatches hold
    minibatch_size // L whole sequences. 0: the whole rollout (L = rollout_steps)."""
    obs_history: int = 1
    """arch mlp: the network sees the last k observations and the k actions before them, stacked
    (`envs.history`); 1: the current observation only. Evaluated in-process; not exportable."""
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
    # Batched PPO tuned on this project's hover task (see docs/benchmarks.md); 3 M steps, the steps
    # hover needs through quad-train's default timing (core.timing "link": 1 M left the policy 9 cm off)
    "fast": {"total_steps": 3_000_000},
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
