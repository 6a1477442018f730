"""quad-sitl: fly an exported policy against a software-in-the-loop quadrotor over MAVLink.

Starts the simulator (`quadpilot.simulator`) as a separate process listening on loopback TCP,
runs the autopilot node (`quadpilot.autopilot.node`) in this process for each episode, and prints
a summary: success rate, position errors, crashes, steps/s, control-loop latency, failsafes and
dropped packets. With no policy it flies the shipped hover model.

Each side also runs alone: `quad-sitl --sim-only [--listen tcp:127.0.0.1:4560]` serves the
simulator until stopped; `quad-sitl POLICY.onnx --node-only --connect tcp:HOST:PORT [--home
LAT,LON,ALT] [--target E,N,U] [--duration S] [--trace OUT.csv] [--json OUT]` flies one flight against
any simulator that speaks PX4's Simulator MAVLink API and listens there (ours, RotorPy's
PX4Multirotor, ...): see `quadpilot.sitl.node_only`.

`--start landed --realtime [--gcs udp:HOST:PORT]`: the vehicle starts on the ground, disarmed, and the
node answers the ground station there as a PX4 vehicle (`autopilot.commander`); one episode, which ends
after the vehicle has flown, landed and been disarmed (`--duration` caps it: 600 s by default).

The simulator flies the policy's own vehicle (the parameter set in its ONNX metadata, trained with
quad-train --vehicle); --vehicle NAME|FILE.toml flies another, with a warning when it differs.

Exit codes: 0 flown; 1 a file that cannot be used (a policy or signing key that fails its checks),
the simulator did not start, or the link failed; 2 a bad flag (including a path that does not exist,
is of the wrong kind, or cannot be written); 130 interrupted; 143 terminated (SIGTERM). Every flag
is checked before the simulator starts, and the simulator process never outlives this one.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import signal
import sys
import tempfile
import threading
from pathlib import Path

from quadpilot.console import Parser, UsageError, check_output_path, input_path_problem
from quadpilot.console import int_in as _int_in
from quadpilot.sitl import node_only
from quadpilot.sitl import options as sitl_options
from quadpilot.sitl.flight import fly_with_simulator
from quadpilot.sitl.options import add_passed_on_flags, policy_vehicle_args, sim_args

# The shipped models are package data (`runtime.shipped`): in a source checkout this is models/.
SHIPPED_HOVER = (Path(__file__).parents[1] / "models").resolve() / "hover" / "policy.onnx"
MAX_EPISODES = 100_000
MAX_DURATION_S = 3600.0  # an hour of 100 Hz flight is 360 000 logged steps per episode
# A flag value that starts with "-" and a digit is a value (--wind -0.9,0,0), not an unknown
# option; argparse's own pattern admits only plain numbers like -1 or -.5.


def _seconds(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not (math.isfinite(v) and 0 < v <= MAX_DURATION_S):
        raise argparse.ArgumentTypeError(f"expected seconds > 0 and ≤ {MAX_DURATION_S:g}, got {text!r}")
    return v


def _address(flag: str, *, port_zero: bool = False, none: bool = False):
    """An argparse type for a MAVLink address tcp:HOST:PORT or udp:HOST:PORT (`none`: also 'none')."""

    def parse(text: str) -> str:
        from quadpilot.link.transport import parse_address

        if none and text.lower() == "none":
            return text
        try:
            address = parse_address(text, flag)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e).removeprefix(f"{flag} ")) from None
        if address.port == 0 and not port_zero:
            raise argparse.ArgumentTypeError(f"{text!r}: port 0 names no peer; expected the port it listens on")
        return text

    parse.__name__ = "address"
    return parse


def _fraction(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1], got {text!r}") from None
    if not 0.0 <= v <= 1.0:  # False for NaN too
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1] (0.95 = 95 %), got {text!r}")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="quad-sitl", description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument(
        "policy", nargs="?", type=Path, help=sitl_options.POLICY_HELP + " Default: the shipped hover model (--model)"
    )
    p.add_argument("--model", metavar="NAME", help="Fly the shipped model NAME (--list-models). Default: hover")
    p.add_argument("--list-models", action="store_true", help="List the shipped models, what each is for, and exit.")
    p.add_argument(
        "--episodes", type=_int_in(1, MAX_EPISODES), metavar="N", help="Default: 10 (--node-only, --start landed: 1)"
    )
    p.add_argument("--task", choices=("hover", "waypoint", "circle"), help="What to fly. Default: the policy's task.")
    p.add_argument(
        "--duration",
        type=_seconds,
        default=None,
        metavar="S",
        help="Seconds per episode (of simulated time). Default: 5 (circle: two laps, 12.6 s; success is judged "
        "on the second; --start landed: a cap of 600 s on a flight that ends when landed and disarmed)",
    )
    p.add_argument(
        "--maneuver",
        type=sitl_options.maneuver_flag,
        default=None,
        metavar="step[:M]|figure8:V",
        help="Fly a maneuver from rest at home instead of the task's targets (core.maneuver): a step of M metres "
        "east (default 1; overshoot, rise and settling time), or PX4 mc_raptor's figure-eight at a peak speed of "
        "V m/s (tracking error over a lap after a 3 s ramp). A hover-layout policy or RAPTOR.",
    )
    p.add_argument("--seed", type=_int_in(0, 2**63 - 1), default=0, help="Seed of the start states. Default: 0")
    p.add_argument("--backend", choices=("onnxruntime", "numpy", "c"), default="numpy", help="Default: numpy")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--lockstep", dest="lockstep", action="store_true", default=True, help="(default)")
    mode.add_argument("--realtime", dest="lockstep", action="store_false", help="Run on the wall clock.")
    # handled before parsing (main_sim_only has its own flags); listed here for --help
    p.add_argument("--sim-only", action="store_true", help="Serve the simulator only (see above).")
    p.add_argument("--node-only", action="store_true", help="Run the node only, against --connect.")
    p.add_argument(
        "--connect", type=_address("--connect"), default=None, help="Simulator address for --node-only (tcp:HOST:PORT)."
    )
    p.add_argument(
        "--listen",
        type=_address("--listen", port_zero=True),
        default=None,
        help="Where the simulator listens (tcp:HOST:PORT). Default: a free loopback port.",
    )
    p.add_argument(
        "--min-success",
        type=_fraction,
        default=0.0,
        metavar="F",
        help="Exit 1 (after the summary) when the flown success rate is below F, e.g. 0.95. Default: 0",
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
        type=_address("--gcs", none=True),
        default="udp:127.0.0.1:14550",
        metavar="ADDR",
        help="Ground-station telemetry destination (QGroundControl/MAVProxy listen on UDP 14550); 'none': off. "
        "With --start landed the node also answers the ground station's commands there, as a PX4 vehicle "
        "(arm, take off, go to, missions, land). Default: udp:127.0.0.1:14550",
    )
    p.add_argument(
        "--key",
        type=Path,
        metavar="FILE",
        help="MAVLink 2 signing key (32 raw bytes or 64 hex digits) for the simulator link, both sides.",
    )
    sitl_options.add_arguments(p)
    sim = p.add_argument_group("simulator (passed on to the simulator process; see quad-sitl --sim-only --help)")
    add_passed_on_flags(sim)  # declared once, in the simulator's command line (simulator.cli)
    return p


class _Terminated(BaseException):
    """SIGTERM arrived: unwind (every finally runs, the simulator is stopped) and exit 143. A
    BaseException, like KeyboardInterrupt, so that no `except Exception` on the way swallows it."""


def _on_sigterm(signum, frame):
    raise _Terminated


def _bad_flag(message: str) -> int:
    print(f"quad-sitl: error: {message}", file=sys.stderr)
    return 2


def _warn(message: str) -> None:
    print(f"quad-sitl: warning: {message}", file=sys.stderr)


def _bad_file(message: str) -> int:
    print(f"quad-sitl: error: {message}", file=sys.stderr)
    return 1


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--sim-only" in argv:
        from quadpilot.simulator import main_sim_only

        return main_sim_only(argv)
    try:
        args = p.parse_args(argv)
    except UsageError as e:
        return _bad_flag(str(e))
    except SystemExit as e:  # --help
        return e.code if isinstance(e.code, int) else 0
    if args.list_models:
        from quadpilot.runtime.shipped import listing

        print("\n".join(listing()))
        return 0
    # every flag is checked here, before anything starts: nothing below refuses a flag
    rest = sim_args(args)
    if rest:  # the simulator's own flags (--mass-scale, --wind, --imu-noise, ...): checked here, passed on
        from quadpilot.core.vehicle_file import VehicleFileError
        from quadpilot.simulator import build_sim_parser, config_from_args

        if args.node_only and (others := [t for t in rest if not t.startswith("--vehicle=")]):
            return _bad_flag(f"{' '.join(others)}: simulator flags, but --node-only runs no simulator")
        try:
            config_from_args(build_sim_parser("quad-sitl").parse_args(rest))  # the same checks as the simulator's
        except UsageError as e:
            return _bad_flag(str(e))
        except VehicleFileError as e:  # --vehicle FILE that cannot be used
            return _bad_file(str(e))
    if args.node_only and not args.connect:
        return _bad_flag("--node-only needs --connect tcp:HOST:PORT")
    if args.connect and not args.node_only:
        return _bad_flag("--connect is for --node-only; without it quad-sitl starts its own simulator (--listen)")
    if (why := sitl_options.misused(args)) is not None:
        return _bad_flag(why)
    from quadpilot.console import quick  # QUADPILOT_DOCS_QUICK: one episode (console.docs_quick)

    args.episodes = quick(args.episodes or (1 if args.node_only or sitl_options.commanded(args) else 10), 1)
    if args.policy is None:  # the shipped model --model names (hover by default), from the package's own data
        from quadpilot.runtime.shipped import shipped_policy

        try:
            args.policy = shipped_policy(args.model)
        except ValueError as e:
            return _bad_flag(str(e))
    elif args.model is not None:
        return _bad_flag(f"give a policy file or --model, not both ({args.policy} and --model {args.model})")
    policy_path = args.policy
    named = str(policy_path).startswith(sitl_options.RAPTOR_NAME)  # a policy the runtime knows by name (runtime.raptor)
    for path, what in ((None if named else policy_path, sitl_options.POLICY_FILE), (args.key, "a signing key file")):
        if path is not None and (why := input_path_problem(path, what)) is not None:
            return _bad_flag(why)
    outputs = {"--json": args.json, "--plot": args.plot, "--video": args.video, "--tlog": args.tlog}
    outputs["--trace"] = args.trace
    for flag, out in outputs.items():
        if out is not None:
            try:
                check_output_path(out, flag)
            except ValueError as e:
                return _bad_flag(str(e))
    if args.plot is not None or args.video is not None:  # refuse before flying, not after
        from quadpilot.viz import VizUnavailable, check_plot_output, check_video_output

        try:
            if args.plot is not None:
                check_plot_output(args.plot)
            if args.video is not None:
                check_video_output(args.video)
        except (ValueError, VizUnavailable) as e:
            return _bad_flag(str(e))
    from quadpilot.runtime import ModelContractError, load_policy

    try:
        policy = load_policy(policy_path, args.backend)
    except ModelContractError as e:  # the file fails its contract
        return _bad_file(str(e))
    except ValueError as e:  # the backend cannot run here (e.g. --backend c without a C compiler)
        return _bad_flag(str(e))
    if args.vehicle is not None and hasattr(policy, "fly_on"):  # a contract policy flies the vehicle asked for
        from quadpilot.core.vehicle_file import resolve_vehicle

        try:
            policy.fly_on(resolve_vehicle(args.vehicle))
        except ValueError as e:
            return _bad_flag(f"--vehicle {args.vehicle}: {e}")
    elif args.vehicle is not None and args.node_only:  # only a contract policy's outputs depend on it there
        return _bad_flag(f"--vehicle with --node-only maps a contract policy's outputs; {policy_path} has its own")
    task = args.task or policy.info.task
    if args.maneuver is not None:
        if (why := sitl_options.maneuver_misused(args, task, policy, policy_path)) is not None:
            return _bad_flag(why)
        args.maneuver = dataclasses.replace(args.maneuver, dt=policy.info.control_period_s)
    if args.node_only and (task == "circle" or policy.info.layout.tracks):
        return _bad_flag(f"--node-only flies to a fixed --target; {policy_path} is a {policy.info.task} policy")
    if (task == "circle") != (policy.info.layout.tracks):
        return _bad_flag(
            f"{policy_path} observes the {policy.info.layout.name} layout "
            f"({policy.info.task} policy); --task {task} needs "
            + (
                "a circle (track layout) policy, e.g. models/circle/policy.onnx"
                if task == "circle"
                else "a hover-layout policy"
            )
        )
    key = None
    if args.key is not None:
        from quadpilot.link.transport import SigningError, read_key

        try:
            key = read_key(args.key)
        except SigningError as e:
            return _bad_file(str(e))
    old = signal.signal(signal.SIGTERM, _on_sigterm) if threading.current_thread() is threading.main_thread() else None
    try:
        with tempfile.TemporaryDirectory(prefix="quad-sitl-") as tmp:  # the policy's vehicle file, if it needs one
            if args.node_only:
                return node_only.fly(args, policy, policy_path, key)
            from quadpilot.simulator import build_sim_parser, config_from_args

            try:
                rest = [*rest, *policy_vehicle_args(args.vehicle, policy.info.vehicle, Path(tmp), warn=_warn)]
            except ValueError as e:  # the policy's vehicle cannot be written as a vehicle file
                return _bad_file(f"{policy_path}: {e}")
            try:  # the flags together with the policy's vehicle (e.g. a noise model it has not)
                config_from_args(build_sim_parser("quad-sitl").parse_args(rest))
            except UsageError as e:
                return _bad_flag(str(e))
            return fly_with_simulator(args, rest, policy, policy_path, task, key)
    except _Terminated:
        print("quad-sitl: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:  # before the first episode (during one, fly_with_simulator summarises what was flown)
        print("\nquad-sitl: interrupted", file=sys.stderr)
        return 130
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)
