"""Actor and critic networks (the course brief's step 3), written out so each piece can be read.

Actor: MLP → Gaussian mean per action dimension, with a state-independent log-std parameter.
Critic: MLP → scalar V(s). Separate networks (no shared trunk), so value-loss gradients never
reach the policy's features. Orthogonal initialisation with gain √2 for hidden layers, 0.01 for
the policy output (a near-zero initial mean = rotors at hover trim) and 1 for the value output:
"Implementation Matters in Deep Policy Gradients" (Engstrom et al. 2020) found this choice matters.
"""

from __future__ import annotations

import itertools
import math

import torch
from torch import nn

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


def mlp(in_dim: int, hidden: tuple[int, ...], out_dim: int, activation: str, out_gain: float) -> nn.Sequential:
    if activation not in ACTIVATIONS:
        raise ValueError(f"unknown activation {activation!r}; expected one of {sorted(ACTIVATIONS)}")
    layers: list[nn.Module] = []
    d = in_dim
    for h in hidden:
        lin = nn.Linear(d, h)
        nn.init.orthogonal_(lin.weight, math.sqrt(2.0))
        nn.init.zeros_(lin.bias)
        layers += [lin, ACTIVATIONS[activation]()]
        d = h
    out = nn.Linear(d, out_dim)
    nn.init.orthogonal_(out.weight, out_gain)
    nn.init.zeros_(out.bias)
    layers.append(out)
    return nn.Sequential(*layers)


class ActorCritic(nn.Module):
    """π(a|s) = N(μ_θ(s), diag(exp(log_std)²)) and V_φ(s). Observations arrive normalised."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        actor_hidden: tuple[int, ...] = (64, 64),
        critic_hidden: tuple[int, ...] = (64, 64),
        activation: str = "tanh",
        init_log_std: float = -1.0,
    ) -> None:
        super().__init__()
        self.obs_dim, self.act_dim = obs_dim, act_dim
        self.actor = mlp(obs_dim, tuple(actor_hidden), act_dim, activation, out_gain=0.01)
        self.critic = mlp(obs_dim, tuple(critic_hidden), 1, activation, out_gain=1.0)
        self.log_std = nn.Parameter(torch.full((act_dim,), float(init_log_std)))

    def distribution(self, obs: torch.Tensor) -> torch.distributions.Normal:
        mean = self.actor(obs)
        return torch.distributions.Normal(mean, self.log_std.exp().expand_as(mean))

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        return self.critic(obs).squeeze(-1)

    def mean_action(self, obs: torch.Tensor) -> torch.Tensor:
        """The deterministic action (what is exported and flown), clipped to the action box."""
        return self.actor(obs).clamp(-1.0, 1.0)


class RecurrentActorCritic(nn.Module):
    """π(a|s₀…s_t) and V(s₀…s_t) with memory: each of actor and critic is one LSTM layer
    (Hochreiter & Schmidhuber 1997, torch's gate order i, f, g, o) followed by a linear head.
    Separate actor and critic LSTMs, like the MLP pair, so value gradients never shape the
    policy's memory. The log-std is state-independent, as in `ActorCritic`.

    State is explicit: `initial_state(B)` gives zeros, and `actor_sequence` takes a boolean
    `episode_start` (T, B) that zeroes the state of a drone before the step where its episode
    starts, the convention training, export and the runtime share."""

    recurrent = True

    def __init__(self, obs_dim: int, act_dim: int, hidden: int = 64, init_log_std: float = -1.0) -> None:
        super().__init__()
        self.obs_dim, self.act_dim, self.hidden = obs_dim, act_dim, hidden
        self.actor_lstm = nn.LSTM(obs_dim, hidden)
        self.actor_head = nn.Linear(hidden, act_dim)
        self.critic_lstm = nn.LSTM(obs_dim, hidden)
        self.critic_head = nn.Linear(hidden, 1)
        for head, gain in ((self.actor_head, 0.01), (self.critic_head, 1.0)):
            nn.init.orthogonal_(head.weight, gain)
            nn.init.zeros_(head.bias)
        self.log_std = nn.Parameter(torch.full((act_dim,), float(init_log_std)))

    def initial_state(self, batch: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(h, c) of the actor, each (batch, hidden) zeros."""
        z = torch.zeros(batch, self.hidden)
        return z, z.clone()

    @staticmethod
    def _run(
        lstm: nn.LSTM,
        obs: torch.Tensor,
        state: tuple[torch.Tensor, torch.Tensor],
        episode_start: torch.Tensor | None,
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """obs (T, B, D) → features (T, B, H); state (h, c) each (B, H). Runs whole stretches
        between resets through the fused LSTM and zeroes the state where an episode starts."""
        h, c = state
        if episode_start is None:
            out, (h1, c1) = lstm(obs, (h.unsqueeze(0), c.unsqueeze(0)))
            return out, (h1[0], c1[0])
        keep = (~episode_start).to(obs.dtype).unsqueeze(-1)  # (T, B, 1)
        # Cut the sequence only at the steps where some drone starts an episode: between two such
        # steps nothing resets, and one fused call is much faster (forward and backward) than a
        # call per step. At a cut, the state of the drones that start is zeroed.
        cuts = torch.nonzero(episode_start.any(dim=1)).flatten().tolist()
        bounds = sorted({0, *cuts, obs.shape[0]})
        outs = []
        for a, b in itertools.pairwise(bounds):
            if episode_start[a].any():
                h, c = h * keep[a], c * keep[a]
            o, (h1, c1) = lstm(obs[a:b], (h.unsqueeze(0), c.unsqueeze(0)))
            h, c = h1[0], c1[0]
            outs.append(o)
        return torch.cat(outs), (h, c)

    def actor_sequence(
        self,
        obs: torch.Tensor,
        state: tuple[torch.Tensor, torch.Tensor],
        episode_start: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """Gaussian means (T, B, act_dim), unclipped, and the actor state after the last step."""
        feats, state = self._run(self.actor_lstm, obs, state, episode_start)
        return self.actor_head(feats), state

    def value_sequence(
        self,
        obs: torch.Tensor,
        state: tuple[torch.Tensor, torch.Tensor],
        episode_start: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """V (T, B) and the critic state after the last step."""
        feats, state = self._run(self.critic_lstm, obs, state, episode_start)
        return self.critic_head(feats).squeeze(-1), state

    def mean_action_step(
        self, obs: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor]
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """One control step: obs (B, D) → clipped deterministic action (B, act_dim), new state."""
        mean, state = self.actor_sequence(obs.unsqueeze(0), state)
        return mean[0].clamp(-1.0, 1.0), state


def build_actor_critic(obs_dim: int, act_dim: int, cfg) -> ActorCritic | RecurrentActorCritic:
    """The network a PPOConfig describes (`cfg.arch`: mlp or lstm)."""
    if cfg.arch == "mlp":
        return ActorCritic(obs_dim, act_dim, cfg.actor_hidden, cfg.critic_hidden, cfg.activation, cfg.init_log_std)
    if cfg.arch == "lstm":
        return RecurrentActorCritic(obs_dim, act_dim, cfg.lstm_hidden, cfg.init_log_std)
    raise ValueError(f"unknown network architecture {cfg.arch!r}; expected 'mlp' or 'lstm'")
