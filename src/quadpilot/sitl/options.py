"""quad-sitl's flags beyond the parser's own: their types, the flags the node takes (`add_arguments`),
the checks of which flags go together (`misused`, `maneuver_misused`), and the simulator flags
quad-sitl passes on to its simulator process (`add_passed_on_flags`, `sim_args`,
`policy_vehicle_args`), declared once in the simulator's command line (`simulator.cli`)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

from quadpilot.autopilot.state_loss import StateLossConfig, parse_state_loss
from quadpilot.console import float_in
from quadpilot.core.params import VehicleParams
from quadpilot.core.vehicle_file import PRESETS, resolve_vehicle, same_vehicle, vehicle_to_toml
from quadpilot.link.spin import LOCKSTEP_SPIN_S, MAX_SPIN_US
from quadpilot.simulator.cli import passed_on_flags

POLICY_HELP = (
    "ONNX file from quad-export, or raptor:foundation (the RAPTOR policy PX4's mc_raptor flies, flown through its "
    "contract, runtime.raptor; or an RLtools .h5 checkpoint of its shape, or the policy.tar mc_raptor loads, from "
    "quad-export --format px4-raptor)."
)
POLICY_FILE = "an ONNX policy file from quad-export, an RLtools .h5 checkpoint or a policy.tar"
RAPTOR_NAME = "raptor:"
"""A policy argument starting so is a name the runtime knows (runtime.raptor), not a file."""
MAX_TARGET_M = 1000.0
"""m, largest |component| of --target: the safety monitor refuses a larger position error as no
state at all (`runtime.safety.ObservationLimits.pos_error`)."""
MAX_ALT_M = 2_147_483.0
"""m, largest |altitude| of --home: HIL_STATE_QUATERNION's int32 millimetres."""
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


def add_passed_on_flags(p) -> None:
    """Add the simulator's `passed_on_flags` to a parser (or group) as quad-sitl's copy: the same help
    and metavar but no default and no type, so that only the flags given are passed on, as given
    (quad-sitl checks them first with the simulator's own parser)."""
    for flag, kw in passed_on_flags().items():
        kw = dict(kw)
        if kw.get("action") != "store_true":
            for k in ("type", "choices"):
                kw.pop(k, None)
            kw["default"] = None
        p.add_argument(flag, **kw)


def passed_on_tokens(args) -> list[str]:
    """The passed-on flags given in `args` (a namespace of a parser with `add_passed_on_flags`), as
    simulator arguments: FLAG=VALUE in one token (a value like -0.9,0,0 is not taken for an option),
    a switch alone."""
    out = []
    for flag, kw in passed_on_flags().items():
        value = getattr(args, flag[2:].replace("-", "_"))
        if kw.get("action") == "store_true":
            if value:
                out.append(flag)
        elif value is not None:
            out.append(f"{flag}={value}")
    return out


def sim_args(args: argparse.Namespace) -> list[str]:
    """The simulator flags quad-sitl was given, as the simulator's arguments; with --maneuver against
    our own simulator, also the maneuver's start (`MANEUVER_START`) where not given."""
    rest = passed_on_tokens(args)
    if args.maneuver is not None and not args.node_only:  # our simulator: its start; another's is its own
        given = {t.split("=", 1)[0] for t in rest}
        rest += [f"{flag}={v}" for flag, v in MANEUVER_START.items() if flag not in given]
    return rest


def policy_vehicle_args(
    requested: str | None, policy_vehicle: VehicleParams, tmp: Path, warn: Callable[[str], None]
) -> list[str]:
    """The simulator's --vehicle for flying a policy: the policy's own vehicle unless `requested`
    (the user's --vehicle, already passed on and checked) names another; then `warn` gets one line
    when its parameters differ from the policy's. The policy's vehicle is its preset's name when it
    is that preset exactly, else a vehicle file written into `tmp`."""
    if requested is not None:
        flown = resolve_vehicle(requested)
        if not same_vehicle(flown, policy_vehicle):
            warn(
                f"--vehicle {requested} ({flown.name}, {flown.mass:g} kg) differs from the vehicle the policy "
                f"was trained on ({policy_vehicle.name}, {policy_vehicle.mass:g} kg)"
            )
        return []
    if PRESETS.get(policy_vehicle.name) == policy_vehicle:
        return [f"--vehicle={policy_vehicle.name}"]
    path = tmp / "policy_vehicle.toml"  # its name follows the one rule a model file's does (NAME_PATTERN)
    path.write_text(vehicle_to_toml(policy_vehicle), encoding="utf-8")
    return [f"--vehicle={path}"]
