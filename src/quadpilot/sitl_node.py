"""quad-sitl's node side: `--node-only`, the node alone flying a policy file against a simulator that
speaks PX4's Simulator MAVLink API (our own `quad-sitl --sim-only`, RotorPy's PX4Multirotor, PX4's
Gazebo plugins), one flight per run; and the summary of the episodes quad-sitl flies against its own
simulator (`summarise`, `print_summary`).

    quad-sitl POLICY --node-only --connect tcp:HOST:PORT [--home LAT,LON,ALT] [--target E,N,U]
              [--duration S] [--trace OUT.csv] [--json OUT]

- Home (the local frame's origin) is the first valid position the simulator reports, unless
  `--home` gives it; `--target` is metres East, North, Up from home, by default the first valid
  position (hold where the flight starts).
- The node's own rules (`autopilot.node`): HEARTBEAT first, then at 1 Hz; one HIL_ACTUATOR_CONTROLS
  per simulator step; the simulator's MAVLink version; body rates from HIL_SENSOR; the policy at
  its trained rate on simulated time, its command held in between.
- It flies `--duration` seconds of simulated time and prints one line: steps, the steps that fell
  back to the safety monitor's fallback and why, its hand-overs and hand-backs, the error to the
  target (last 2 s and final), the yaw rate, the reply latency. Exit 1 with a one-line reason when
  more than `MAX_FALLBACK_FRACTION` of the steps fell back (not counting the steps the fallback
  flew after bad input while it waited to hand back, "recovering": the price of the hand-back rule,
  `runtime.safety.HAND_BACK_HOLD_S`, not a failure of the policy), when the policy flew less than
  `MIN_POLICY_FRACTION` of the steps, when the flight ended early (failsafe), or when nothing was
  flown.

Success is not judged here: the node does not know where the simulator's ground is (a crash), and
a foreign airframe may hold a point a few centimetres off; the figures are printed and written
(`--json`, `--trace`) for the caller to judge.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np

from quadpilot.atomic_files import atomic_output, atomic_write
from quadpilot.autopilot.state_loss import StateLossConfig, parse_state_loss
from quadpilot.console import float_in
from quadpilot.link.impair import summary_line as impair_summary
from quadpilot.link.spin import LOCKSTEP_SPIN_S, MAX_SPIN_US

POLICY_HELP = (
    "ONNX file from quad-export, or raptor:foundation (the RAPTOR policy PX4's mc_raptor flies, flown through its "
    "contract, runtime.raptor; or an RLtools .h5 checkpoint of its shape, or the policy.tar mc_raptor loads, from "
    "quad-export --format px4-raptor)."
)
POLICY_FILE = "an ONNX policy file from quad-export, an RLtools .h5 checkpoint or a policy.tar"
RAPTOR_NAME = "raptor:"
"""A policy argument starting so is a name the runtime knows (runtime.raptor), not a file."""
MAX_FALLBACK_FRACTION = 0.10
"""More than this share of the steps flown by the fallback (or blind) fails the run (exit 1)."""
MIN_POLICY_FRACTION = 0.5
"""Less than this share of the steps flown by the policy fails the run (exit 1): the policy must fly
the flight, whatever excused the fallback's steps."""
MAX_TARGET_M = 1000.0
"""m, largest |component| of --target: the safety monitor refuses a larger position error as no
state at all (`runtime.safety.ObservationLimits.pos_error`)."""
MAX_ALT_M = 2_147_483.0
"""m, largest |altitude| of --home: HIL_STATE_QUATERNION's int32 millimetres."""
LATE_REPLY_S = 0.01
"""s: a reply later than this misses RotorPy's PX4Multirotor step, which waits 10 ms for it and
then applies zero motors (rotorpy/vehicles/px4_multirotor.py, `_fetch_latest_px4_control`)."""
LINK_TIMEOUT_S = 1.0
"""s of host time without a state before the node's failsafe in real time (`--realtime`): a foreign
simulator need not keep real time (RotorPy's PX4Multirotor integrates each step with scipy's Radau,
5 to 15 ms of CPU for a 4 ms step, and more on a loaded machine), so not the 0.1 s the node allows
our own simulator. In lockstep the node waits while the link holds (`autopilot.node`)."""
JUDGED_WINDOW_S = 2.0
"""s at the end of the flight the error and the yaw rate are averaged over (`core.mission`'s window)."""
NOT_A_REASON = {"fallback_steps", "blind_steps", "fallback_engaged", "handed_back", "fallback_latched"}
NOT_A_REASON |= {"command_clamped"}
"""SafetyMonitor.events counters that count, rather than explain, a fallback."""
FLAGS = ("--home", "--target", "--trace")
COMMANDED_DURATION_S = 600.0
"""s, the default cap of a commanded flight (`--start landed`), which otherwise ends when the vehicle
has flown, landed and been disarmed."""
LOCKSTEP_COMMANDED_WARNING = (
    "quad-sitl: warning: --start landed in lockstep: simulated time, which the commander's timeouts "
    "(COM_DL_LOSS_T, COM_DISARM_PRFLT) run on, goes faster than a ground station's; add --realtime for "
    "MAVSDK, QGroundControl or MAVProxy"
)
LINK_IMPAIR_LOCKSTEP = (
    "--link-impair needs --realtime: in lockstep each side waits for the other's every frame, so a frame lost, "
    "held back or sent twice stalls or desynchronises both sides; add --realtime"
)
NOT_FLOWN_BY_FALLBACK = ("policy", "estimate", "idle")
"""Step sources that are not the fallback: the policy (on the state, or on the node's estimate while
the state is lost: `autopilot.state_loss`), and motors off while disarmed or idle."""


def commanded(args) -> bool:
    """quad-sitl answers a ground station's commands (`--start landed`: only commands can fly it)."""
    return getattr(args, "start", None) == "landed"


def _numbers(text: str, what: str, example: str) -> list[float]:
    parts = text.split(",")
    try:
        values = [float(v) for v in parts]
    except ValueError:
        values = []
    if len(parts) != 3 or len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected {what}, e.g. {example}; got {text!r}")
    if not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected finite numbers ({what}), got {text!r}")
    return values


def home_type(text: str):
    """--home LAT,LON,ALT: degrees north, degrees east, metres above mean sea level."""
    from quadpilot.link.wire import Home

    lat, lon, alt = _numbers(text, "LAT,LON,ALT (degrees, degrees, metres above sea level)", "47.397742,8.545594,488")
    if not -90.0 < lat < 90.0:
        raise argparse.ArgumentTypeError(f"latitude {lat:g} is outside (-90, 90) degrees in {text!r}")
    if not -180.0 <= lon <= 180.0:
        raise argparse.ArgumentTypeError(f"longitude {lon:g} is outside [-180, 180] degrees in {text!r}")
    if not abs(alt) <= MAX_ALT_M:
        raise argparse.ArgumentTypeError(f"altitude {alt:g} m is beyond ±{MAX_ALT_M:,.0f} m in {text!r}")
    return Home(lat, lon, alt)


home_type.__name__ = "home"


def target_type(text: str) -> tuple[float, float, float]:
    """--target E,N,U: metres East, North, Up from home."""
    values = _numbers(text, "E,N,U (metres East, North, Up from home)", "-0.5,0.7,0.3")
    if not all(abs(v) <= MAX_TARGET_M for v in values):
        raise argparse.ArgumentTypeError(f"each of E,N,U must be within ±{MAX_TARGET_M:g} m, got {text!r}")
    return values[0], values[1], values[2]


target_type.__name__ = "target"


def impair_type(text: str):
    from quadpilot.link.impair import ImpairSpecError, parse_spec

    try:
        return parse_spec(text)
    except ImpairSpecError as e:
        raise argparse.ArgumentTypeError(str(e).removeprefix("--link-impair ")) from None


impair_type.__name__ = "impairment"


def start_impair(args, address: str):
    """(proxy, the address the node connects to): with --link-impair, `link.impair.start_proxy`
    relaying to `address`, seeded by the spec or --seed; else (None, address)."""
    if args.link_impair is None:
        return None, address
    from quadpilot.link.impair import start_proxy

    return start_proxy(args.link_impair, address, getattr(args, "seed", 0))


def state_loss_type(text: str) -> StateLossConfig:
    try:
        return parse_state_loss(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    """--spin-us, and the flags only --node-only takes."""
    p.add_argument(
        "--spin-us",
        type=float_in(0.0, MAX_SPIN_US),
        default=LOCKSTEP_SPIN_S * 1e6,
        metavar="US",
        help="In lockstep, µs the node and the simulator poll for each other's answer before they sleep: "
        f"faster on an idle machine, a busy core each while waiting. 0: off. Default: {LOCKSTEP_SPIN_S * 1e6:g}",
    )
    p.add_argument(
        "--link-impair",
        type=impair_type,
        metavar="SPEC",
        help="With --realtime, relay the node's link through an impairment proxy on loopback: whole MAVLink frames "
        "lost, delayed, "
        "duplicated, reordered, e.g. loss=5%%,delay=20ms,jitter=5ms,reorder=1%%,duplicate=1%%,burst=1%%,burst-len=5,"
        "seed=N (default seed: --seed); see quadpilot.link.impair",
    )
    p.add_argument(
        "--state-loss",
        type=state_loss_type,
        default=StateLossConfig(),
        metavar="POLICY_S,DESCEND_S",
        help="No state but HIL_SENSOR: the policy flies on the node's estimate for POLICY_S s, the fallback holds "
        "attitude and height until DESCEND_S s, then it lands; the motors stop on the ground. Default: 1,2",
    )
    g = p.add_argument_group("--node-only (against any PX4-API simulator)")
    g.add_argument(
        "--home",
        type=home_type,
        metavar="LAT,LON,ALT",
        help="Origin of the local frame (degrees, degrees, metres above sea level). Default: the first "
        "valid position the simulator reports.",
    )
    g.add_argument(
        "--target",
        type=target_type,
        metavar="E,N,U",
        help="Where to hover, metres East, North, Up from home. Default: hold the start position.",
    )
    g.add_argument("--trace", type=Path, metavar="OUT.csv", help="Write one CSV row per simulator step.")


def _not_loopback(address: str | None) -> str | None:
    """Why --link-impair cannot relay to `address` (not loopback TCP), or None (None: a free loopback port)."""
    from quadpilot.link.impair import ImpairSpecError, check_loopback
    from quadpilot.link.transport import parse_address

    try:
        if address is not None:
            check_loopback(parse_address(address), "the simulator address")
    except ImpairSpecError as e:
        return str(e)
    return None


def misused(args) -> str | None:
    """Why the flags do not go together (one line), or None."""
    if commanded(args) and args.gcs.lower() == "none":
        return "--start landed waits for a ground station's commands; --gcs none leaves it without one"
    if commanded(args) and args.min_success > 0:
        return "--min-success: a commanded flight has no success criterion of its own; read its --json"
    if args.link_impair is not None and (why := _not_loopback(args.connect if args.node_only else args.listen)):
        return why
    if args.link_impair is not None and args.lockstep:
        return LINK_IMPAIR_LOCKSTEP
    if not args.node_only:
        given = [f for f in FLAGS if getattr(args, f[2:]) is not None]
        return f"{', '.join(given)}: for --node-only" if given else None
    if args.episodes is not None and args.episodes != 1:
        return f"--episodes {args.episodes}: --node-only flies one flight per run"
    if args.listen is not None:
        return "--listen: --node-only starts no simulator; give its address with --connect"
    if args.min_success > 0:
        return "--min-success: --node-only does not judge success (it knows no ground); read its --json"
    return None


def flight_summary(log, monitor, policy_period_s: float) -> dict:
    """What the run prints and writes to --json (see the module docstring)."""
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


TRACE_COLUMNS = (
    "t_s", "x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps", "roll_rad", "pitch_rad", "yaw_rad",
    "p_radps", "q_radps", "r_radps", "target_x_m", "target_y_m", "target_z_m",
    "motor1", "motor2", "motor3", "motor4", "source", "policy_step", "reply_latency_us", "host_time_s",
)  # fmt: skip
"""--trace: world ENU, body FLU, SI (the project's frames), as the simulator reported the state; motor
commands ω/ω_max in actuator output order; policy_step 1 where the policy ran, 0 where it was held;
host_time_s the host's monotonic clock (time.perf_counter) when the step's HIL_SENSOR was handled,
to line the node's replies up with a simulator's own timestamps."""


def write_trace(log, path: Path) -> None:
    with atomic_output(path) as tmp, open(tmp, "x", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(TRACE_COLUMNS)
        for t, s, tgt, cmd, src, tick, lat, wall in zip(
            log.t, log.states, log.targets, log.commands, log.sources, log.ticks, log.latency_s, log.wall, strict=True
        ):
            numbers = (f"{v:.6g}" for v in (*s, *tgt, *cmd))
            w.writerow([f"{t:.6f}", *numbers, src, int(tick), f"{lat * 1e6:.0f}", f"{wall:.6f}"])


def fly(args, policy, policy_path: Path, key: bytes | None, draw) -> int:
    """One flight against `args.connect`; prints the summary line, writes --json/--trace/--tlog and
    the pictures (`draw(args, logs, period)`); the exit code."""
    from quadpilot.autopilot.node import Node, NodeConfig, NodeError
    from quadpilot.core.mission import default_duration_s
    from quadpilot.runtime import SafetyMonitor

    period = policy.info.control_period_s
    monitor = SafetyMonitor(policy)
    gcs = None if args.gcs.lower() == "none" else args.gcs
    from quadpilot.link.impair import ImpairSpecError

    try:
        proxy, connect = start_impair(args, args.connect)
    except ImpairSpecError as e:
        print(f"quad-sitl: error: {e}", file=sys.stderr)
        return 2
    maneuver = targets = None
    if args.maneuver is not None:  # from where the flight starts: the local origin (home from the first fix)
        maneuver = dataclasses.replace(args.maneuver, home=(0.0, 0.0, 0.0))
        targets = maneuver.target_at
    cfg = NodeConfig(
        connect=connect,
        duration_s=args.duration or (maneuver.duration_s if maneuver else default_duration_s("hover")),
        lockstep=args.lockstep,
        gcs=gcs,
        signing_key=key,
        home=args.home,
        target=args.target,
        link_timeout_s=LINK_TIMEOUT_S,
        spin_s=args.spin_us / 1e6,
        state_loss=args.state_loss,
    )
    tlog = None
    try:
        if args.tlog is not None:
            from quadpilot.link.tlog import TlogWriter

            tlog = TlogWriter(args.tlog)
        log = Node(cfg).fly(monitor, tap=None if tlog is None else tlog.tap, targets=targets)
    except NodeError as e:
        print(f"quad-sitl: error: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        print(f"quad-sitl: error: {e.filename + ': ' if e.filename else ''}{e.strerror or e}", file=sys.stderr)
        return 1
    finally:
        if tlog is not None:
            tlog.close()
        if proxy is not None:
            proxy.stop()
    s = flight_summary(log, monitor, period)
    s.update(mode="node-only", policy=str(policy_path), backend=args.backend, simulator=args.connect)
    if proxy is not None:
        s["link_impair"] = proxy.summary()
        print(impair_summary(s["link_impair"]))
    s["home_source"] = "--home" if args.home is not None else "first valid position"
    print(summary_line(s))
    if maneuver is not None:
        s.update(maneuver_summary(maneuver, [log], period))
        from quadpilot.core.maneuver import summary_line as maneuver_line

        print(maneuver_line(s))
    for flag, path, write in (
        ("--json", args.json, lambda p: atomic_write(p, lambda f: f.write((json.dumps(s, indent=2) + "\n").encode()))),
        ("--trace", args.trace, lambda p: write_trace(log, p)),
    ):
        if path is not None:
            try:
                write(path)
            except OSError as e:
                print(f"quad-sitl: error: {flag} {path}: {e.strerror or e}", file=sys.stderr)
                return 1
    code = draw(args, [log], period) if log.steps else 0
    if not log.replies:
        return _failed(f"nothing flown: {log.failsafe or 'no step from the simulator'}")
    if log.failsafe is not None:
        return _failed(log.ended_early(cfg.duration_s))
    if s["judged_fallback_fraction"] > MAX_FALLBACK_FRACTION:
        reasons = ", ".join(f"{k} {v}" for k, v in s["fallback_reasons"].items()) or "no reason recorded"
        counted = s["fallback_steps"] - s["recovering_steps"]
        return _failed(
            f"{counted:,} of {s['steps']:,} steps ({s['judged_fallback_fraction']:.1%}) fell back ({reasons}"
            + (f"; {s['recovering_steps']} recovering steps not counted" if s["recovering_steps"] else "")
            + f"): more than {MAX_FALLBACK_FRACTION:.0%}"
        )
    if s["policy_fraction"] < MIN_POLICY_FRACTION:
        return _failed(
            f"the policy flew {s['policy_fraction']:.1%} of {s['steps']:,} steps ({s['hand_overs']} hand-overs, "
            f"{s['hand_backs']} hand-backs): less than {MIN_POLICY_FRACTION:.0%}"
        )
    return code


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


def maneuver_flag(text: str):
    """--maneuver's type: `core.maneuver.parse_maneuver`, its refusal as a usage error."""
    from quadpilot.core.maneuver import parse_maneuver

    try:
        return parse_maneuver(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def maneuver_misused(args, task: str, policy, policy_path) -> str | None:
    """Why --maneuver cannot be flown with these flags and this policy, or None."""
    if task != "hover" or policy.info.layout.tracks:
        return f"--maneuver flies from a hover; {policy_path} is a {policy.info.task} policy (--task {task})"
    if commanded(args):
        return "--maneuver flies its own targets; --start landed takes the ground station's"
    if args.node_only and (args.home is not None or args.target is not None):
        return "--maneuver with --node-only is flown from where the vehicle starts; --home and --target move it"
    return None


MANEUVER_START = {"--init-pos-radius": "0", "--init-vel": "0", "--init-tilt": "0"}
"""A maneuver starts at rest, level, at home: these simulator flags unless given."""


# --- quad-sitl's summary of episodes flown against its own simulator ------------------------------
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


def _failed(reason: str) -> int:
    print(f"quad-sitl: {reason}", file=sys.stderr)
    return 1
