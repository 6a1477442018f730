"""quad-sitl: fly an exported policy against a software-in-the-loop quadrotor over MAVLink.

Starts the simulator (`quadpilot.firmware_sim`) as a separate process listening on loopback TCP,
runs the autopilot node (`quadpilot.runtime.node`) in this process for each episode, and prints
a summary: success rate, position errors, crashes, steps/s, control-loop latency, failsafes and
dropped packets. With no policy it flies the shipped hover model.

Each side also runs alone: `quad-sitl --sim-only [--listen tcp:127.0.0.1:4560]` serves the
simulator until stopped; `quad-sitl POLICY.onnx --node-only --connect tcp:127.0.0.1:4560` flies a
simulator that listens there.
"""

from __future__ import annotations

import argparse
import json
import math
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np

SHIPPED_HOVER = Path(__file__).resolve().parents[2] / "models" / "hover" / "policy.onnx"


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        print(f"quad-sitl: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


SIM_FLAGS = {
    "--mass-scale": "X",
    "--inertia-scale": "X",
    "--motor-scale": "X",
    "--motor-tau": "S",
    "--wind": "E,N,U",
    "--gust": "M/S",
    "--init-pos-radius": "M",
    "--init-vel": "M/S",
    "--init-tilt": "DEG",
    "--drag": "D",
    "--imu-noise": None,
    "--estimator-noise": None,
    "--vehicle": "NAME",
}


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="quad-sitl", description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("policy", nargs="?", type=Path, help=f"ONNX file from quad-export. Default: {SHIPPED_HOVER}")
    p.add_argument("--episodes", type=int, default=10, metavar="N", help="Episodes to fly. Default: 10")
    p.add_argument("--task", choices=("hover", "waypoint", "circle"), help="What to fly. Default: the policy's task.")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="Seconds per episode. Default: 5 (circle: two laps, 12.6 s; success is judged on the second)",
    )
    p.add_argument("--seed", type=int, default=0, help="Seed of the start states. Default: 0")
    p.add_argument("--backend", choices=("onnxruntime", "numpy", "c"), default="numpy", help="Default: numpy")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--lockstep", dest="lockstep", action="store_true", default=True, help="(default)")
    mode.add_argument("--realtime", dest="lockstep", action="store_false", help="Run on the wall clock.")
    # handled before parsing (main_sim_only has its own flags); listed here for --help
    p.add_argument("--sim-only", action="store_true", help="Serve the simulator only (see above).")
    p.add_argument("--node-only", action="store_true", help="Run the node only, against --connect.")
    p.add_argument("--connect", default=None, help="Simulator address for --node-only (tcp:HOST:PORT).")
    p.add_argument(
        "--listen", default=None, help="Where the simulator listens (tcp:HOST:PORT). Default: a free loopback port."
    )
    p.add_argument("--json", type=Path, metavar="OUT", help="Write the summary as JSON.")
    p.add_argument(
        "--plot", type=Path, metavar="OUT.png", help="Draw the 3-D paths and position/attitude/motor traces."
    )
    p.add_argument(
        "--video", type=Path, metavar="OUT.gif", help="Render the first episode (.gif, or .mp4 with ffmpeg)."
    )
    p.add_argument(
        "--tlog", type=Path, metavar="OUT.tlog", help="Log every MAVLink message (pymavlink's mavlogdump.py reads it)."
    )
    p.add_argument(
        "--gcs",
        default="udp:127.0.0.1:14550",
        metavar="ADDR",
        help="Ground-station telemetry destination (QGroundControl/MAVProxy listen on UDP 14550); 'none': off. "
        "Default: udp:127.0.0.1:14550",
    )
    p.add_argument(
        "--key",
        type=Path,
        metavar="FILE",
        help="MAVLink 2 signing key (32 raw bytes or 64 hex digits) for the simulator link, both sides.",
    )
    sim = p.add_argument_group("simulator (passed on to the simulator process; see quad-sitl --sim-only --help)")
    for flag, metavar in SIM_FLAGS.items():
        if metavar is None:
            sim.add_argument(flag, action="store_true")
        else:
            sim.add_argument(flag, metavar=metavar)
    return p


def _sim_args(args: argparse.Namespace) -> list[str]:
    out = []
    for flag, metavar in SIM_FLAGS.items():
        value = getattr(args, flag[2:].replace("-", "_"))
        if metavar is None and value:
            out.append(flag)
        elif metavar is not None and value is not None:
            out += [flag, value]
    return out


def _start_simulator(cmd: list[str], timeout_s: float = 30.0):
    """Start the simulator process and wait until it listens: (process, address it listens on),
    or (None, why not) if it exits first (e.g. its port is taken) or stays silent for `timeout_s`."""
    import select
    import threading

    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
    line = proc.stdout.readline() if ready else ""
    if "listening on" not in line:
        proc.kill()
        err = proc.stderr.read().strip() if proc.wait(5) is not None else ""
        last = err.splitlines()[-1] if err else f"no answer within {timeout_s:g} s"
        return None, last.removeprefix("quad-sitl: error: ")

    def drain(stream):  # per-episode lines: read them so the pipe never fills and blocks it
        for _ in stream:
            pass

    threading.Thread(target=drain, args=(proc.stdout,), daemon=True).start()
    threading.Thread(target=drain, args=(proc.stderr,), daemon=True).start()
    return proc, line.split("listening on ", 1)[1].split()[0]


def summarise(logs, period: float, task: str = "hover") -> dict:
    from quadpilot.runtime.node import episode_summary

    eps = [episode_summary(log, period, task) for log in logs]
    lat = np.concatenate([np.asarray(log.latency_s) for log in logs]) * 1e6 if logs else np.zeros(0)
    steps = sum(log.steps for log in logs)
    wall = sum(log.wall_s for log in logs)
    dropped: dict[str, int] = {}
    for log in logs:
        for k, v in log.dropped.items():
            dropped[k] = dropped.get(k, 0) + v
    fallback = sum(sum(1 for s in log.sources if s != "policy") for log in logs)
    finite = [e for e in eps if math.isfinite(e["rms_error_m"])]
    out = {
        "episodes": len(eps),
        "success_rate": float(np.mean([e["success"] for e in eps])) if eps else math.nan,
        "crashes": int(sum(e["crashed"] for e in eps)),
        "position_rms_error_m": float(np.mean([e["rms_error_m"] for e in finite])) if finite else math.nan,
        "mean_error_last_2s_m": float(np.mean([e["mean_error_last_window_m"] for e in finite])) if finite else math.nan,
        "final_distance_m": float(np.mean([e["final_distance_m"] for e in finite])) if finite else math.nan,
        "steps": int(steps),
        "steps_per_s": steps / wall if wall > 0 else math.nan,
        "control_latency_p50_us": float(np.percentile(lat, 50)) if lat.size else math.nan,
        "control_latency_p99_us": float(np.percentile(lat, 99)) if lat.size else math.nan,
        "failsafe_events": sum(1 for log in logs if log.failsafe),
        "fallback_steps": int(fallback),
        "telemetry_messages": int(sum(log.telemetry_sent for log in logs)),
        "packets_dropped": dropped,
        "per_episode": eps,
    }
    if task == "circle" and finite:
        out["radial_rms_m"] = float(np.mean([e["radial_rms_m"] for e in finite]))
        out["speed_error_mps"] = float(np.mean([e["speed_error_mps"] for e in finite]))
    return out


def print_summary(s: dict, policy: Path) -> None:
    print(f"quad-sitl: {policy} — {s['episodes']} episodes, {s['steps']:,} steps at {s['steps_per_s']:,.0f} steps/s")
    print(f"  success rate            {s['success_rate']:.0%}   crashes {s['crashes']}")
    print(
        f"  position error          RMS {s['position_rms_error_m'] * 100:.2f} cm, last 2 s mean "
        f"{s['mean_error_last_2s_m'] * 100:.2f} cm, final {s['final_distance_m'] * 100:.2f} cm"
    )
    if "radial_rms_m" in s:
        print(
            f"  circle (second lap)     radial RMS {s['radial_rms_m'] * 100:.2f} cm, "
            f"speed error {s['speed_error_mps'] * 100:.2f} cm/s"
        )
    print(
        f"  control-loop latency    p50 {s['control_latency_p50_us']:.0f} µs, p99 {s['control_latency_p99_us']:.0f} µs"
    )
    dropped = ", ".join(f"{k} {v}" for k, v in sorted(s["packets_dropped"].items())) or "none"
    print(f"  failsafes {s['failsafe_events']}, fallback steps {s['fallback_steps']}, packets dropped: {dropped}")


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--sim-only" in argv:
        from quadpilot.firmware_sim.sim import main_sim_only

        return main_sim_only(argv)
    try:
        args = p.parse_args(argv)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else 0
    rest = _sim_args(args)
    if rest:  # the simulator's own flags (--mass-scale, --wind, --imu-noise, ...): checked here, passed on
        from quadpilot.firmware_sim.sim import UsageError, build_sim_parser, config_from_args

        try:
            config_from_args(build_sim_parser("quad-sitl").parse_args(rest))  # the same checks as the simulator's
        except UsageError as e:
            print(f"quad-sitl: error: {e}", file=sys.stderr)
            return 2
        if args.node_only:
            print(
                f"quad-sitl: error: {' '.join(rest)}: simulator flags, but --node-only runs no simulator",
                file=sys.stderr,
            )
            return 2
    if args.episodes < 1 or not (args.duration is None or args.duration > 0):
        print("quad-sitl: error: --episodes must be ≥ 1 and --duration > 0", file=sys.stderr)
        return 2
    from quadpilot.runtime import ModelContractError, SafetyMonitor, load_policy
    from quadpilot.runtime.node import Node, NodeConfig, NodeError

    policy_path = args.policy or SHIPPED_HOVER
    try:
        policy = load_policy(policy_path, args.backend)
    except (ModelContractError, ValueError) as e:
        print(f"quad-sitl: error: {e}", file=sys.stderr)
        return 2
    from quadpilot.core.mission import default_duration_s, plan_episode
    from quadpilot.core.observation import TRACK_LAYOUT

    task = args.task or policy.info.task
    if (task == "circle") != (policy.info.layout.name == TRACK_LAYOUT.name):
        print(
            f"quad-sitl: error: {policy_path} observes the {policy.info.layout.name} layout "
            f"({policy.info.task} policy); --task {task} needs "
            + (
                "a circle (track layout) policy, e.g. models/circle/policy.onnx"
                if task == "circle"
                else "a hover-layout policy"
            ),
            file=sys.stderr,
        )
        return 2
    duration = args.duration or default_duration_s(task)
    key = None
    if args.key is not None:
        from quadpilot.link.transport import SigningError, read_key

        try:
            key = read_key(args.key)
        except SigningError as e:
            print(f"quad-sitl: error: {e}", file=sys.stderr)
            return 2
    for out in (args.json, args.plot, args.video, args.tlog):
        if out is not None and not out.parent.is_dir():
            print(f"quad-sitl: error: {out}: directory {out.parent} does not exist", file=sys.stderr)
            return 2
    if args.plot is not None or args.video is not None:  # refuse before flying, not after
        from quadpilot.viz import VizUnavailable, check_plot_output, check_video_output

        try:
            if args.plot is not None:
                check_plot_output(args.plot)
            if args.video is not None:
                check_video_output(args.video)
        except (ValueError, VizUnavailable) as e:
            print(f"quad-sitl: error: {e}", file=sys.stderr)
            return 2
    monitor = SafetyMonitor(policy)
    sim = None
    if args.node_only:
        if not args.connect:
            print("quad-sitl: error: --node-only needs --connect tcp:HOST:PORT", file=sys.stderr)
            return 2
        address = args.connect
    else:
        listen = args.listen or f"tcp:127.0.0.1:{_free_port()}"
        cmd = [sys.executable, "-m", "quadpilot.firmware_sim", "--sim-only", "--listen", listen]
        cmd += ["--episodes", str(args.episodes), "--seed", str(args.seed), "--task", task]
        cmd += ["--lockstep" if args.lockstep else "--realtime", *rest]
        if args.key is not None:
            cmd += ["--key", str(args.key)]
        sim, address = _start_simulator(cmd)
        if sim is None:
            print(f"quad-sitl: error: the simulator did not start: {address}", file=sys.stderr)
            return 1
    gcs = None if args.gcs.lower() == "none" else args.gcs
    node = Node(NodeConfig(connect=address, duration_s=duration, lockstep=args.lockstep, gcs=gcs, signing_key=key))
    tlog = None
    if args.tlog is not None:
        from quadpilot.link.tlog import TlogWriter

        tlog = TlogWriter(args.tlog)
    logs = []
    try:
        for k in range(args.episodes):
            mission = plan_episode(task, args.seed, k, policy.info.control_period_s)
            logs.append(node.fly(monitor, tap=None if tlog is None else tlog.tap, targets=mission.target_at))
    except NodeError as e:
        print(f"quad-sitl: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("quad-sitl: interrupted; summary of the episodes flown so far", file=sys.stderr)
    finally:
        if tlog is not None:
            tlog.close()
        if sim is not None:
            sim.terminate()
            try:
                sim.wait(timeout=5)
            except subprocess.TimeoutExpired:
                sim.kill()
    summary = summarise(logs, policy.info.control_period_s, task)
    summary["task"] = task
    summary["policy"] = str(policy_path)
    summary["backend"] = args.backend
    summary["monitor_events"] = dict(monitor.events)
    print_summary(summary, policy_path)
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2) + "\n")
    if tlog is not None:
        print(f"  MAVLink log             {args.tlog} ({tlog.messages:,} messages; read it with mavlogdump.py)")
    return _draw(args, logs, policy.info.control_period_s)


def _traces(logs):
    from quadpilot.viz import FlightTrace

    return [
        FlightTrace.from_episode_log(log, np.asarray(log.targets), label=f"episode {i}")
        for i, log in enumerate(logs)
        if log.states
    ]


def _draw(args, logs, period: float) -> int:
    if args.plot is None and args.video is None:
        return 0
    from quadpilot.viz import VizUnavailable, plot_flight, render_flight_video

    traces = _traces(logs)
    if not traces:
        print("quad-sitl: nothing flown, nothing to draw", file=sys.stderr)
        return 1
    try:
        if args.plot is not None:
            plot_flight(traces, args.plot, title=f"quad-sitl: {args.policy or SHIPPED_HOVER}")
            print(f"  plot                    {args.plot}")
        if args.video is not None:
            render_flight_video(traces[0], args.video)
            print(f"  video                   {args.video}")
    except VizUnavailable as e:
        print(f"quad-sitl: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
