"""Generalised Advantage Estimation (Schulman et al. 2016, "High-Dimensional Continuous Control
Using Generalized Advantage Estimation", eqs. 11–16), as a pure function.

    δ_t = r_t + γ·(1 − terminated_t)·V(s_{t+1}) − V(s_t)                   (eq. 10, TD residual)
    Â_t = δ_t + γλ·(1 − done_t)·Â_{t+1},  done_t = terminated_t or truncated_t   (eq. 16)
    R_t = Â_t + V(s_t)                                                     (the value target)

`next_values[t]` is V of the state the environment actually reached after step t: on a time-limit
truncation that is the final observation (kept by the vector env), not the reset observation that
follows. Terminated steps do not bootstrap (the future is worth nothing after a crash); truncated
steps do (the time limit is not part of the task), which SB3 does and many scripts get wrong.
"""

from __future__ import annotations

import numpy as np


def compute_gae(
    rewards: np.ndarray,
    values: np.ndarray,
    next_values: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
    gamma: float = 0.99,
    lam: float = 0.95,
) -> tuple[np.ndarray, np.ndarray]:
    """Advantages and returns, each (T, N). All inputs (T, N); terminated/truncated boolean.

    Vectorised over N; one pass backwards over T."""
    shapes = {a.shape for a in (rewards, values, next_values, terminated, truncated)}
    if len(shapes) != 1 or rewards.ndim != 2:
        raise ValueError(f"all inputs must share one (T, N) shape, got {sorted(shapes)}")
    # The masks are float64 (Python floats in np.where), so deltas, and with them the advantages
    # and returns, are float64 for float32 or float64 rewards and values.
    not_term = np.where(terminated, 0.0, 1.0)
    not_done = np.where(terminated | truncated, 0.0, 1.0)
    deltas = rewards + gamma * not_term * next_values - values
    adv = np.empty_like(deltas)  # every row is written below
    last = 0.0  # Â_T = 0: nothing after the rollout's last step
    for t in range(rewards.shape[0] - 1, -1, -1):
        last = deltas[t] + gamma * lam * not_done[t] * last
        adv[t] = last
    return adv, adv + values


def bootstrapped_gae(
    rewards: np.ndarray,
    values: np.ndarray,
    final_values: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
    gamma: float,
    lam: float,
) -> tuple[np.ndarray, np.ndarray]:
    """GAE over a rollout as it was collected: `values` (T + 1, N) is V(s_0 … s_T), the states the
    policy saw (after an episode ended, s_{t+1} is the next episode's reset state), and
    `final_values` (T, N) is V of the final observation where step t was truncated by the time
    limit. The value after a truncated step is that final value (the bootstrap), never the reset
    state's; a terminated step takes none (`compute_gae`). Returns (advantages, returns), (T, N)."""
    next_values = values[1:].copy()
    next_values[truncated] = final_values[truncated]
    return compute_gae(rewards, values[:-1], next_values, terminated, truncated, gamma, lam)
