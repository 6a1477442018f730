"""Actor and critic networks (seed 000 step 3), written out so each piece can be read.

Actor: MLP → Gaussian mean per action dimension, with a state-independent log-std parameter.
Critic: MLP → scalar V(s). Separate networks (no shared trunk), so value-loss gradients never
reach the policy's features. Orthogonal initialisation with gain √2 for hidden layers, 0.01 for
the policy output (a near-zero initial mean = rotors at hover trim) and 1 for the value output:
"Implementation Matters in Deep Policy Gradients" (Engstrom et al. 2020) found this choice matters.
"""

from __future__ import annotations

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
