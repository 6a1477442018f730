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
import time
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
    "--wind": "E,N,U",
    "--drag": "D",
    "--imu-noise": None,
    "--vehicle": "NAME",
}


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="quad-sitl", description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("policy", nargs="?", type=Path, help=f"ONNX file from quad-export. Default: {SHIPPED_HOVER}")
    p.add_argument("--episodes", type=int, default=10, metavar="N", help="Episodes to fly. Default: 10")
    p.add_argument("--duration", type=float, default=5.0, metavar="S", help="Seconds per episode. Default: 5")
    p.add_argument("--seed", type=int, default=0, help="Seed of the start states. Default: 0")
    p.add_argument("--backend", choices=("onnxruntime", "numpy"), default="numpy", help="Default: numpy")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--lockstep", dest="lockstep", action="store_true", default=True, help="(default)")
    mode.add_argument("--realtime", dest="lockstep", action="store_false", help="Run on the wall clock.")
    # handled before parsing (main_sim_only has its own flags); listed here for --help
    p.add_argument("--sim-only", action="store_true", help="Serve the simulator only (see above).")
    p.add_argument("--node-only", action="store_true", help="Run the node only, against --connect.")
    p.add_argument("--connect", default=None, help="Simulator address for --node-only (tcp:HOST:PORT).")
    p.add_argument("--json", type=Path, metavar="OUT", help="Write the summary as JSON.")
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


def summarise(logs, target, period: float) -> dict:
    from quadpilot.runtime.node import episode_summary

    eps = [episode_summary(log, target, period) for log in logs]
    lat = np.concatenate([np.asarray(log.latency_s) for log in logs]) * 1e6 if logs else np.zeros(0)
    steps = sum(log.steps for log in logs)
    wall = sum(log.wall_s for log in logs)
    dropped: dict[str, int] = {}
    for log in logs:
        for k, v in log.dropped.items():
            dropped[k] = dropped.get(k, 0) + v
    fallback = sum(sum(1 for s in log.sources if s != "policy") for log in logs)
    finite = [e for e in eps if math.isfinite(e["rms_error_m"])]
    return {
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
        "packets_dropped": dropped,
        "per_episode": eps,
    }


def print_summary(s: dict, policy: Path) -> None:
    print(f"quad-sitl: {policy} — {s['episodes']} episodes, {s['steps']:,} steps at {s['steps_per_s']:,.0f} steps/s")
    print(f"  success rate            {s['success_rate']:.0%}   crashes {s['crashes']}")
    print(
        f"  position error          RMS {s['position_rms_error_m'] * 100:.2f} cm, last 2 s mean "
        f"{s['mean_error_last_2s_m'] * 100:.2f} cm, final {s['final_distance_m'] * 100:.2f} cm"
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
    if args.episodes < 1 or not (args.duration > 0):
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
    if policy.info.task != "hover":
        print(
            f"quad-sitl: error: {policy_path} is a {policy.info.task} policy; SITL flies hover policies so far",
            file=sys.stderr,
        )
        return 2
    monitor = SafetyMonitor(policy)
    sim = None
    if args.node_only:
        if not args.connect:
            print("quad-sitl: error: --node-only needs --connect tcp:HOST:PORT", file=sys.stderr)
            return 2
        address = args.connect
    else:
        port = _free_port()
        address = f"tcp:127.0.0.1:{port}"
        cmd = [
            sys.executable,
            "-m",
            "quadpilot.firmware_sim",
            "--sim-only",
            "--listen",
            address,
            "--episodes",
            str(args.episodes),
            "--seed",
            str(args.seed),
            "--lockstep" if args.lockstep else "--realtime",
            *rest,
        ]
        sim = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
    node = Node(NodeConfig(connect=address, duration_s=args.duration, lockstep=args.lockstep))
    logs = []
    try:
        for _ in range(args.episodes):
            logs.append(node.fly(monitor))
            time.sleep(0.02)  # let the simulator finish the episode and listen again
    except NodeError as e:
        print(f"quad-sitl: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("quad-sitl: interrupted; summary of the episodes flown so far", file=sys.stderr)
    finally:
        if sim is not None:
            sim.terminate()
            try:
                sim.wait(timeout=5)
            except subprocess.TimeoutExpired:
                sim.kill()
    summary = summarise(logs, NodeConfig().target, policy.info.control_period_s)
    summary["policy"] = str(policy_path)
    summary["backend"] = args.backend
    summary["monitor_events"] = dict(monitor.events)
    print_summary(summary, policy_path)
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
