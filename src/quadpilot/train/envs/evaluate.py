"""Deterministic evaluation with one success definition for every policy (ours, SB3's, the
runtime's): a policy is any callable mapping raw observations (N, obs_dim) float32 to actions
(N, 4) in [−1, 1], or a stateful one (an LSTM, an observation history: `stateful` or `recurrent`
true) with `initial_state(n)` and `step(obs, state)` → (actions, state), started once per
evaluation (every episode starts together at step 0).

The figures over the episodes that did not crash (errors, yaw, circle tracking) are None when every
episode crashed: the dict is JSON-able as standard JSON (`json.dumps(..., allow_nan=False)`).

Success is `core.mission`'s definition (`window_success`), the one SITL judges by too.
Hover/waypoint: the episode does not crash, the mean position error over its last 2 s is ≤ 0.05 m,
and over the same 2 s the mean |yaw rate| is ≤ 0.2 rad/s and the mean heading error ≤ 10° (the
heading at the start of the episode). Circle: radial RMS error and speed error measured after the
first lap, over an episode of two laps, and the same held heading over the last 2 s.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from quadpilot.core.mission import (
    CIRCLE_RADIAL_TOLERANCE_M,
    CIRCLE_SPEED_TOLERANCE_MPS,
    holds_heading,
    window_success,
    yaw_errors,
)
from quadpilot.core.state import POS, YAW

from . import EnvConfig, QuadBatch

Policy = Callable[[np.ndarray], np.ndarray]


def _park(batch: QuadBatch, out: np.ndarray) -> None:
    """Put the drones `out` (crashed, out of the evaluation) back at rest at their targets, level and
    at their headings. Every figure of theirs is masked from the crash on; parked, they do not tumble
    on to overflow and NaN while the others fly (the policy still sees them, batched)."""
    s = batch.state
    s[out] = 0.0
    s[out, POS] = batch.target[out]
    s[out, YAW] = batch.heading[out]


def _over_alive(values: np.ndarray, alive: np.ndarray, reduce) -> float | None:
    """`reduce` over the episodes that did not crash; None (JSON null) when every one crashed, so that
    the result stays standard JSON (RFC 8259 has no NaN)."""
    return float(reduce(values[alive])) if alive.any() else None


def evaluate(policy: Policy, env_cfg: EnvConfig, episodes: int = 100, seed: int = 12345) -> dict:
    """Run `episodes` episodes side by side from seeded random starts; returns a JSON-able dict."""
    cfg = env_cfg
    if cfg.task == "circle":  # two laps; the first is the approach
        lap_steps = math.ceil(2 * math.pi * cfg.circle_radius / cfg.circle_speed / cfg.dt)
        cfg = dataclasses.replace(cfg, episode_steps=2 * lap_steps)
    batch = QuadBatch(cfg, episodes)
    batch.reset(np.ones(episodes, bool), np.random.default_rng(seed))
    T, window = cfg.episode_steps, cfg.success_steps
    alive = np.ones(episodes, bool)
    length = np.full(episodes, T)
    err_sum = np.zeros(episodes)
    rate_sum = np.zeros(episodes)  # |yaw rate| over the window, rad/s
    head_sum = np.zeros(episodes)  # |heading error| over the window, rad (heading: the start yaw)
    final_err = np.zeros(episodes)
    ep_return = np.zeros(episodes)
    rad_sq = np.zeros(episodes)
    spd_abs = np.zeros(episodes)
    tracked = 0
    stateful = bool(getattr(policy, "stateful", False) or getattr(policy, "recurrent", False))
    state = policy.initial_state(episodes) if stateful else None
    for t in range(T):
        if stateful:
            action, state = policy.step(batch.obs.copy(), state)
            action = np.asarray(action, dtype=np.float32)
        else:
            action = np.asarray(policy(batch.obs.copy()), dtype=np.float32)
        _, reward, term, _, err = batch.step(action)
        ep_return += np.where(alive, reward, 0.0)
        newly = alive & term
        length[newly] = t + 1
        final_err = np.where(alive, err, final_err)
        alive &= ~term
        if not alive.all():
            _park(batch, ~alive)
        if t >= T - window:
            err_sum += err
            rate, head = yaw_errors(batch.state, batch.heading)
            rate_sum += rate
            head_sum += head
        if cfg.task == "circle" and t >= T // 2:
            e_r, e_v = batch.circle_metrics()
            rad_sq += e_r**2
            spd_abs += np.abs(e_v)
            tracked += 1
    mean_err = err_sum / window
    mean_rate, mean_head = rate_sum / window, head_sum / window
    success = window_success(alive, mean_err, mean_rate, mean_head, cfg.success_tolerance)
    out = {
        "task": cfg.task,
        "episodes": episodes,
        "seed": seed,
        "episode_steps": T,
        "success_rate": float(success.mean()),
        "crash_rate": float((~alive).mean()),
        "mean_return": float(ep_return.mean()),
        "mean_length": float(length.mean()),
        "mean_error_last_window_m": _over_alive(mean_err, alive, np.mean),
        "max_error_last_window_m": _over_alive(mean_err, alive, np.max),
        "mean_final_distance_m": _over_alive(final_err, alive, np.mean),
        "success_tolerance_m": cfg.success_tolerance,
        "window_s": cfg.success_window,
        "mean_abs_yaw_rate_last_window_rad_s": _over_alive(mean_rate, alive, np.mean),
        "max_mean_abs_yaw_rate_last_window_rad_s": _over_alive(mean_rate, alive, np.max),
        "max_mean_heading_error_last_window_deg": _over_alive(np.degrees(mean_head), alive, np.max),
    }
    if cfg.task == "circle":
        rms = np.sqrt(rad_sq / max(tracked, 1))
        spd = spd_abs / max(tracked, 1)
        ok = (
            alive
            & (rms <= CIRCLE_RADIAL_TOLERANCE_M)
            & (spd <= CIRCLE_SPEED_TOLERANCE_MPS)
            & holds_heading(mean_rate, mean_head)
        )
        out.update(
            radial_rms_m=_over_alive(rms, alive, np.mean),
            speed_error_mps=_over_alive(spd, alive, np.mean),
            circle_success_rate=float(ok.mean()),
        )
    return out
