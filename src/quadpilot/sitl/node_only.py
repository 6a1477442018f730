"""`quad-sitl --node-only`: the node alone flying a policy file against a simulator that speaks PX4's
Simulator MAVLink API (our own `quad-sitl --sim-only`, RotorPy's PX4Multirotor, PX4's Gazebo
plugins), one flight per run, set up as every flight of quad-sitl's is (`flight.fly`).

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

import csv
import dataclasses
import json
import sys
from pathlib import Path

from quadpilot.atomic_files import atomic_output, atomic_write
from quadpilot.link.impair import summary_line as impair_summary
from quadpilot.sitl.flight import draw
from quadpilot.sitl.flight import fly as fly_node
from quadpilot.sitl.summary import flight_summary, maneuver_summary, summary_line

MAX_FALLBACK_FRACTION = 0.10
"""More than this share of the steps flown by the fallback (or blind) fails the run (exit 1)."""
MIN_POLICY_FRACTION = 0.5
"""Less than this share of the steps flown by the policy fails the run (exit 1): the policy must fly
the flight, whatever excused the fallback's steps."""
LINK_TIMEOUT_S = 1.0
"""s of host time without a state before the node's failsafe in real time (`--realtime`): a foreign
simulator need not keep real time (RotorPy's PX4Multirotor integrates each step with scipy's Radau,
5 to 15 ms of CPU for a 4 ms step, and more on a loaded machine), so not the 0.1 s the node allows
our own simulator. In lockstep the node waits while the link holds (`autopilot.node`)."""


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


def fly(args, policy, policy_path: Path, key: bytes | None) -> int:
    """One flight against `args.connect`; prints the summary line, writes --json/--trace/--tlog and
    the pictures; the exit code."""
    from quadpilot.core.mission import default_duration_s

    period = policy.info.control_period_s
    maneuver = targets = None
    if args.maneuver is not None:  # from where the flight starts: the local origin (home from the first fix)
        maneuver = dataclasses.replace(args.maneuver, home=(0.0, 0.0, 0.0))
        targets = maneuver.target_at
    duration = args.duration or (maneuver.duration_s if maneuver else default_duration_s("hover"))
    flown = fly_node(
        args, policy, key, args.connect, duration, lambda k: targets,
        home=args.home, target=args.target, link_timeout_s=LINK_TIMEOUT_S,
    )  # fmt: skip
    if isinstance(flown, int):
        return flown
    if flown.interrupted:  # one flight: nothing to summarise (cli.main says so)
        raise KeyboardInterrupt
    log, monitor, proxy, cfg = flown.logs[0], flown.monitor, flown.proxy, flown.config
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


def _failed(reason: str) -> int:
    print(f"quad-sitl: {reason}", file=sys.stderr)
    return 1
