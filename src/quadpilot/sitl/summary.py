"""What quad-sitl prints and writes about its flights: the summary of the episodes flown against its
own simulator (`summarise`, `print_summary`), and of one `--node-only` flight (`flight_summary`,
`summary_line`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from quadpilot.link.impair import summary_line as impair_summary

LATE_REPLY_S = 0.01
"""s: a reply later than this misses RotorPy's PX4Multirotor step, which waits 10 ms for it and
then applies zero motors (rotorpy/vehicles/px4_multirotor.py, `_fetch_latest_px4_control`)."""
JUDGED_WINDOW_S = 2.0
"""s at the end of the flight the error and the yaw rate are averaged over (`core.mission`'s window)."""
NOT_A_REASON = {"fallback_steps", "blind_steps", "fallback_engaged", "handed_back", "fallback_latched"}
NOT_A_REASON |= {"command_clamped"}
"""SafetyMonitor.events counters that count, rather than explain, a fallback."""
NOT_FLOWN_BY_FALLBACK = ("policy", "estimate", "idle")
"""Step sources that are not the fallback: the policy (on the state, or on the node's estimate while
the state is lost: `autopilot.state_loss`), and motors off while disarmed or idle."""


def flight_summary(log, monitor, policy_period_s: float) -> dict:
    """What a `--node-only` run prints and writes to --json (see `node_only`'s docstring)."""
    from quadpilot.core.state import POS, STATE_DIM, YAW, R

    states = np.asarray(log.states, np.float64).reshape(-1, STATE_DIM)
    targets = np.asarray(log.targets, np.float64).reshape(-1, 3)
    step_s = log.step_s
    fallback = log.replies - log.steps + sum(1 for s in log.sources if s not in NOT_FLOWN_BY_FALLBACK)
    recovering = sum(1 for s in log.sources if s == "recovering")
    policy_steps = sum(1 for s in log.sources if s == "policy")
    lat = np.asarray(log.latency_s, np.float64)
    out: dict = {
        "steps": int(log.replies),
        "step_s": step_s,
        "simulator_rate_hz": 1.0 / step_s if step_s > 0 else math.nan,
        "policy_rate_hz": 1.0 / policy_period_s,
        "policy_steps": int(sum(log.ticks)),
        "sim_time_s": float(log.t[-1] - log.t[0] + step_s) if len(log.t) > 1 else 0.0,
        "fallback_steps": int(fallback),
        "fallback_fraction": fallback / log.replies if log.replies else math.nan,
        "fallback_reasons": {k: int(v) for k, v in sorted(monitor.events.items()) if k not in NOT_A_REASON},
        "recovering_steps": int(recovering),
        "judged_fallback_fraction": (fallback - recovering) / log.replies if log.replies else math.nan,
        "policy_fraction": policy_steps / log.replies if log.replies else math.nan,
        **handover_counts(log),
        "handovers": [list(h) for h in log.handovers],
        "failsafe": log.failsafe,
        "home": None
        if log.home is None
        else {"lat_deg": log.home.lat_deg, "lon_deg": log.home.lon_deg, "alt_m": log.home.alt_m},
        "target_enu_m": targets[-1].tolist() if len(targets) else None,
        "error_last_2s_m": math.nan,
        "final_error_m": math.nan,
        "mean_abs_yaw_rate_last_2s_radps": math.nan,
        "yaw_change_deg": math.nan,
        "reply_latency_p50_us": float(np.percentile(lat, 50) * 1e6) if lat.size else math.nan,
        "reply_latency_p99_us": float(np.percentile(lat, 99) * 1e6) if lat.size else math.nan,
        "reply_latency_max_us": float(lat.max() * 1e6) if lat.size else math.nan,
        "late_replies": int(np.sum(lat > LATE_REPLY_S)),
        "wall_s": float(log.wall_s),
        "mavlink_version": int(log.mavlink_version),
        "packets_dropped": dict(log.dropped),
        "monitor_events": dict(monitor.events),
    }
    if len(states):
        dist = np.linalg.norm(states[:, POS] - targets, axis=1)
        k = max(1, round(JUDGED_WINDOW_S / step_s)) if step_s > 0 else len(states)
        out["error_last_2s_m"] = float(dist[-k:].mean())
        out["final_error_m"] = float(dist[-1])
        # |r|: the sign does not matter, and a simulator that sends HIL_STATE_QUATERNION's rates in
        # FLU instead of FRD (RotorPy 3.0.0) flips only the sign of q and r
        out["mean_abs_yaw_rate_last_2s_radps"] = float(np.abs(states[-k:, R]).mean())
        turn = states[-1, YAW] - states[0, YAW]
        out["yaw_change_deg"] = float(np.degrees(math.atan2(math.sin(turn), math.cos(turn))))
    return out


def handover_counts(log) -> dict:
    """Who-flies changes of one flight (`EpisodeLog.handovers`), counted by kind."""
    kinds = [h[1] for h in log.handovers]
    return {k.replace("-", "_") + "s": kinds.count(k) for k in ("hand-over", "hand-back")} | {
        "latched": "latched" in kinds
    }


def summary_line(s: dict) -> str:
    """The one line a run prints."""
    reasons = ", ".join(f"{k} {v}" for k, v in s["fallback_reasons"].items())
    home = s["home"]
    where = "no position" if home is None else f"{home['lat_deg']:.7f},{home['lon_deg']:.7f},{home['alt_m']:.3f}"
    return (
        f"quad-sitl: {s['steps']:,} steps of {s['step_s'] * 1e3:.2f} ms (policy {s['policy_rate_hz']:.0f} Hz, "
        f"{s['policy_steps']:,} runs), fallback {s['fallback_steps']} steps"
        + (f" ({reasons})" if reasons else "")
        + (f", {s['recovering_steps']} of them recovering" if s["recovering_steps"] else "")
        + f", hand-overs {s['hand_overs']}, hand-backs {s['hand_backs']}"
        + (" (latched)" if s["latched"] else "")
        + f", error last 2 s {s['error_last_2s_m'] * 100:.2f} cm, final {s['final_error_m'] * 100:.2f} cm, "
        f"|yaw rate| {s['mean_abs_yaw_rate_last_2s_radps']:.3f} rad/s, reply p50 {s['reply_latency_p50_us']:.0f} µs "
        f"p99 {s['reply_latency_p99_us']:.0f} µs, MAVLink {s['mavlink_version']}, home {where}"
        + (f", failsafe: {s['failsafe']}" if s["failsafe"] else "")
    )


def maneuver_summary(maneuver, logs, period: float) -> dict:
    """`core.maneuver.summarise` of the flights in `logs`."""
    from quadpilot.core.maneuver import summarise

    return summarise(
        maneuver,
        [
            (
                np.asarray(log.states, np.float64).reshape(-1, 12),
                np.asarray(log.targets, np.float64).reshape(-1, 3),
                log.step_s if math.isfinite(log.step_s) else period,
            )
            for log in logs
        ],
    )


def _mean_of(eps: list[dict], key: str, reduce=np.mean) -> float:
    values = [e[key] for e in eps if key in e]
    return float(reduce(values)) if values else math.nan


def summarise(logs, period: float, task: str = "hover") -> dict:
    from quadpilot.autopilot.flight_log import episode_summary

    eps = [episode_summary(log, period, task) for log in logs]
    for e, log in zip(eps, logs, strict=True):  # what the node did in each
        e["failsafe"] = log.failsafe
        e["fallback_steps"] = sum(1 for s in log.sources if s not in NOT_FLOWN_BY_FALLBACK)
        e["blind_replies"] = log.blind_replies
    lat = np.concatenate([np.asarray(log.latency_s) for log in logs]) * 1e6 if logs else np.zeros(0)
    steps = sum(log.steps for log in logs)
    wall = sum(log.wall_s for log in logs)
    dropped: dict[str, int] = {}
    for log in logs:
        for k, v in log.dropped.items():
            dropped[k] = dropped.get(k, 0) + v
    fallback = sum(sum(1 for s in log.sources if s not in NOT_FLOWN_BY_FALLBACK) for log in logs)
    changes = [handover_counts(log) for log in logs]
    finite = [e for e in eps if math.isfinite(e["rms_error_m"])]
    out = {
        "episodes": len(eps),
        "success_rate": float(np.mean([e["success"] for e in eps])) if eps else math.nan,
        "crashes": int(sum(e["crashed"] for e in eps)),
        "position_rms_error_m": float(np.mean([e["rms_error_m"] for e in finite])) if finite else math.nan,
        "mean_error_last_2s_m": float(np.mean([e["mean_error_last_window_m"] for e in finite])) if finite else math.nan,
        "final_distance_m": float(np.mean([e["final_distance_m"] for e in finite])) if finite else math.nan,
        # the yaw rule (core.mission): per episode, over its last 2 s
        "mean_abs_yaw_rate_last_2s_radps": _mean_of(finite, "mean_abs_yaw_rate_last_window_rad_s"),
        "max_abs_yaw_rate_last_2s_radps": _mean_of(finite, "mean_abs_yaw_rate_last_window_rad_s", np.max),
        "max_heading_error_last_2s_deg": _mean_of(finite, "mean_heading_error_last_window_deg", np.max),
        "steps": int(steps),
        "steps_per_s": steps / wall if wall > 0 else math.nan,
        "control_latency_p50_us": float(np.percentile(lat, 50)) if lat.size else math.nan,
        "control_latency_p99_us": float(np.percentile(lat, 99)) if lat.size else math.nan,
        "failsafe_events": sum(1 for log in logs if log.failsafe),
        "state_lost_steps": int(sum(log.state_lost_steps for log in logs)),
        "fallback_steps": int(fallback),
        "hand_overs": sum(c["hand_overs"] for c in changes),
        "hand_backs": sum(c["hand_backs"] for c in changes),
        "handovers": [[list(h) for h in log.handovers] for log in logs],
        "telemetry_messages": int(sum(log.telemetry_sent for log in logs)),
        "packets_dropped": dropped,
        "per_episode": eps,
    }
    if task == "circle" and finite:
        from quadpilot.core.mission import circle_summary

        out.update(circle_summary(finite))
    return out


def print_summary(s: dict, policy: Path) -> None:
    print(f"quad-sitl: {policy} — {s['episodes']} episodes, {s['steps']:,} steps at {s['steps_per_s']:,.0f} steps/s")
    if not s.get("commanded"):
        # a commanded flight has no fixed target to judge against: where it ends is the ground
        # station's business, so only its own line below says how it went
        print(f"  success rate            {s['success_rate']:.0%}   crashes {s['crashes']}")
        print(
            f"  position error          RMS {s['position_rms_error_m'] * 100:.2f} cm, last 2 s mean "
            f"{s['mean_error_last_2s_m'] * 100:.2f} cm, final {s['final_distance_m'] * 100:.2f} cm"
        )
        print(
            f"  heading, last 2 s       |yaw rate| mean {s['mean_abs_yaw_rate_last_2s_radps']:.3f} rad/s "
            f"(worst episode {s['max_abs_yaw_rate_last_2s_radps']:.3f}), "
            f"worst heading error {s['max_heading_error_last_2s_deg']:.1f}°"
        )
    if "circle_lap_s" in s:
        from quadpilot.core.mission import circle_line

        print(circle_line(s))
    print(
        f"  control-loop latency    p50 {s['control_latency_p50_us']:.0f} µs, p99 {s['control_latency_p99_us']:.0f} µs"
    )
    dropped = ", ".join(f"{k} {v}" for k, v in sorted(s["packets_dropped"].items())) or "none"
    print(
        f"  failsafes {s['failsafe_events']}, fallback steps {s['fallback_steps']} (hand-overs "
        f"{s['hand_overs']}, hand-backs {s['hand_backs']}), packets dropped: {dropped}"
    )
    if s.get("state_lost_steps"):
        landed = sum(1 for e in s["per_episode"] if e.get("failsafe") == "state lost: landed")
        print(
            f"  state lost              {s['state_lost_steps']:,} steps flown on the node's estimate from HIL_SENSOR"
            + (f"; landed in {landed} of {s['episodes']} episodes" if landed else "")
        )
    if "link_impair" in s:
        print(impair_summary(s["link_impair"]))
    for c in s.get("commanded", []):
        gcs_dropped = ", ".join(f"{k} {v}" for k, v in sorted(c["gcs_dropped"].items())) or "none dropped"
        end = "never disarmed after flying" if c["disarmed_at_s"] is None else f"disarmed at {c['disarmed_at_s']:.1f} s"
        armed = "armed" if c["armed"] else "disarmed"
        print(
            f"  commanded flight        {c['landed_state']}, {armed}, mode {c['mode']}, {end}; "
            f"{c['gcs_messages']:,} ground-station messages ({gcs_dropped})"
        )


def commanded_summary(logs) -> list[dict]:
    """Per commanded episode: the commander at the end (`EpisodeLog.commander`) and its STATUSTEXTs."""
    return [{**(log.commander or {}), "events": [[t, text] for t, text in log.events]} for log in logs]
