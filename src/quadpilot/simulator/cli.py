"""`quad-sitl --sim-only` (and `python -m quadpilot.simulator`): the simulator alone, from the
command line. Flags map one to one onto `SimConfig` fields; a bad flag is one line on stderr and exit
code 2, a simulator that cannot run (e.g. its port taken) one line and exit code 1.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

from quadpilot.atomic_files import atomic_write
from quadpilot.console import Parser, UsageError, check_output_path, float_in
from quadpilot.console import positive_float as _positive
from quadpilot.core.mission import TASKS
from quadpilot.core.params import checked_motor_tau
from quadpilot.core.vehicle_file import (
    PRESETS,
    UnknownVehicleError,
    VehicleFileError,
    is_vehicle_path,
    resolve_vehicle,
)
from quadpilot.link.spin import MAX_SPIN_US
from quadpilot.link.transport import SigningError, SimulatorError, parse_address, read_key

from .config import DEFAULT_WIND_DRAG, START_MODES, SimConfig
from .faults import KINDS, FaultSpecError, parse_faults
from .process import Simulator
from .records import SimStats


def vehicle_label(cfg: SimConfig) -> str:
    """The vehicle a config flies, for messages: the preset name, or the file's vehicle and path."""
    if cfg.airframe is not None:
        return f"{cfg.airframe.name} ({cfg.airframe.mass:g} kg) from {cfg.airframe_source}"
    return cfg.vehicle


def _wind(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(
            f"expected three comma-separated numbers (m/s east,north,up), e.g. 2,0,0; got {text!r}"
        )
    return values  # type: ignore[return-value]


def _impulse(text: str) -> tuple[float, float]:
    from .config import MAX_IMPULSE_MPS

    dv, _, at = text.partition("@")
    try:
        values = (float(dv), float(at))
    except ValueError:
        values = (math.nan, math.nan)
    dv_ok = math.isfinite(values[0]) and abs(values[0]) <= MAX_IMPULSE_MPS
    if not (dv_ok and math.isfinite(values[1]) and values[1] >= 0):
        raise argparse.ArgumentTypeError(
            f"expected DV@T: a velocity jump east in m/s (within ±{MAX_IMPULSE_MPS:g}) at T s (≥ 0), e.g. 1@2; "
            f"got {text!r}"
        )
    return values


def _non_negative(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"expected a finite number ≥ 0, got {text!r}")
    return v


def _motor_tau(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    try:
        return checked_motor_tau(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a finite number ≥ 0, got {text!r}") from None


def _int_at_least(lo: int):
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"must be ≥ {lo}, got {v}")
        return v

    return parse


def _listen(text: str) -> str:
    try:
        parse_address(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def _faults(text: str):
    try:
        return parse_faults(text)
    except FaultSpecError as e:
        raise argparse.ArgumentTypeError(str(e).removeprefix("--sensor-fault ")) from None


def _flag(table: dict, flag: str, **kw) -> None:
    table[flag] = kw


def passed_on_flags() -> dict[str, dict]:
    """The simulator's flags that quad-sitl also takes and passes on to the simulator process,
    declared here once: flag → `add_argument` keywords (the plant, the start, the rate, the faults)."""
    d = SimConfig()
    table: dict[str, dict] = {}
    _flag(
        table,
        "--vehicle",
        default=d.vehicle,
        metavar="NAME|FILE.toml",
        help="airframe: a shipped vehicle or a vehicle file (core.vehicle_file); default: the policy's own under "
        f"quad-sitl, {d.vehicle} for the simulator alone",
    )
    _flag(
        table,
        "--start",
        choices=START_MODES,
        default=d.start,
        metavar="air|landed",
        help="air: in flight, rotors at hover speed (default); landed: at rest on the ground at home, rotors at rest",
    )
    _flag(table, "--mass-scale", type=_positive, metavar="X", default=d.mass_scale, help="multiplies the mass")
    _flag(
        table, "--inertia-scale", type=_positive, metavar="X", default=d.inertia_scale, help="multiplies the inertias"
    )
    _flag(
        table,
        "--motor-scale",
        type=_positive,
        metavar="X",
        default=d.motor_scale,
        help="multiplies the thrust coefficient k_f",
    )
    _flag(table, "--motor-tau", type=_motor_tau, default=None, metavar="S", help="motor time constant, s")
    _flag(table, "--wind", type=_wind, default=d.wind, metavar="E,N,U", help="constant wind, m/s world ENU")
    _flag(table, "--gust", type=_non_negative, default=d.gust, metavar="M/S", help="gust std per axis, m/s")
    _flag(
        table,
        "--impulse",
        type=_impulse,
        default=None,
        metavar="DV@T",
        help="a hit at T s into each episode: the velocity jumps by DV m/s east (e.g. 1@2)",
    )
    _flag(
        table, "--init-pos-radius", type=_non_negative, default=d.init_pos_radius, metavar="M", help="start ball radius"
    )
    _flag(table, "--init-vel", type=_non_negative, default=d.init_vel, metavar="M/S", help="start velocity range ±")
    _flag(table, "--init-tilt", type=_non_negative, default=d.init_tilt_deg, metavar="DEG", help="start roll/pitch ±")
    _flag(
        table,
        "--drag",
        type=float,
        default=None,
        metavar="D",
        help=f"N·s/m linear drag (default: the vehicle's, or {DEFAULT_WIND_DRAG} with wind if it has no drag law)",
    )
    _flag(
        table,
        "--imu-noise",
        action="store_true",
        help="IMU noise (core.sensor_noise, the vehicle's IMU): white noise, turn-on bias and bias random walk",
    )
    _flag(
        table,
        "--estimator-noise",
        action="store_true",
        help="send ODOMETRY, the state as an EKF would output it (cm-level errors, core.sensor_noise); the "
        "node flies on it, and is judged on the exact HIL_STATE_QUATERNION",
    )
    _flag(
        table,
        "--rate",
        type=_positive,
        default=1.0 / d.dt,
        metavar="HZ",
        help=f"simulation steps per second (default {1 / d.dt:g})",
    )
    _flag(
        table,
        "--sensor-fault",
        type=_faults,
        default=(),
        metavar="KIND@T",
        help="inject sensor faults at a simulated time of every episode, e.g. gyro-spike@2s, pos-freeze@2s+0.5s, "
        "baro-step@1s:5, nan@3s:gyro (kinds: " + ", ".join(KINDS) + "; see simulator.faults)",
    )
    return table


def build_sim_parser(prog: str = "quad-sitl --sim-only") -> argparse.ArgumentParser:
    d = SimConfig()
    p = Parser(prog=prog, description="Run only the simulator: core dynamics served over MAVLink like a PX4 simulator.")
    p.add_argument("--sim-only", action="store_true", help=argparse.SUPPRESS)
    p.add_argument(
        "--listen", type=_listen, default=d.listen, help=f"tcp:HOST:PORT or udp:HOST:PORT (default {d.listen})"
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--lockstep", dest="lockstep", action="store_true", default=True, help="one step per actuator message (default)"
    )
    mode.add_argument("--realtime", dest="lockstep", action="store_false", help="one step per dt of wall-clock time")
    for flag, kw in passed_on_flags().items():  # quad-sitl's copy: `sitl.options.add_passed_on_flags`
        p.add_argument(flag, **kw)
    p.add_argument("--task", choices=TASKS, default=d.task, help="where episodes start (core.mission; default hover)")
    p.add_argument("--gust-tau", type=_positive, default=d.gust_tau_s, metavar="S", help="gust correlation time, s")
    p.add_argument("--init-rate", type=_non_negative, default=d.init_rate, metavar="RAD/S", help="start body rates ±")
    p.add_argument("--seed", type=_int_at_least(0), default=d.seed, help="seed of the start states and the noise")
    p.add_argument("--episodes", type=_int_at_least(1), default=None, help="serve this many connections, then exit")
    p.add_argument("--gps-every", type=_int_at_least(1), default=d.gps_every, help="steps between HIL_GPS messages")
    p.add_argument(
        "--esc-timeout",
        type=_positive,
        default=d.esc_timeout_s,
        help="s, motors cut after this long without a valid command",
    )
    p.add_argument(
        "--lockstep-timeout",
        type=_positive,
        default=d.lockstep_timeout_s,
        help="s, an episode ends after this silence",
    )
    p.add_argument("--max-steps", type=_int_at_least(1), default=d.max_steps, help="step bound of one episode")
    p.add_argument(
        "--spin-us",
        type=float_in(0.0, MAX_SPIN_US),
        default=d.spin_s * 1e6,
        metavar="US",
        help=f"µs to poll for the peer's answer before sleeping, in lockstep (default {d.spin_s * 1e6:g}; 0: off)",
    )
    p.add_argument("--json", metavar="OUT", default=None, help="write the stats and episode records as JSON on exit")
    p.add_argument(
        "--key",
        metavar="FILE",
        default=None,
        help="MAVLink 2 signing key (32 raw bytes or 64 hex digits): sign, and accept only signed messages",
    )
    return p


def config_from_args(args: argparse.Namespace) -> SimConfig:
    """The SimConfig the flags describe. UsageError for a bad flag (an unknown vehicle name among
    them); VehicleFileError (a ValueError) for a --vehicle file that cannot be used."""
    try:
        airframe = resolve_vehicle(args.vehicle)
    except UnknownVehicleError as e:
        raise UsageError(f"--vehicle: {e}") from None
    file_kw: dict = {}
    vehicle = args.vehicle
    if is_vehicle_path(args.vehicle):
        vehicle = airframe.name if airframe.name in PRESETS else "seed"  # whose sensor models apply
        file_kw = {"airframe": airframe, "airframe_source": args.vehicle}
    try:
        return SimConfig(
            **file_kw,
            listen=args.listen,
            task=args.task,
            start=args.start,
            vehicle=vehicle,
            mass_scale=args.mass_scale,
            inertia_scale=args.inertia_scale,
            motor_scale=args.motor_scale,
            motor_tau=args.motor_tau,
            wind=args.wind,
            gust=args.gust,
            gust_tau_s=args.gust_tau,
            impulse=args.impulse,
            init_pos_radius=args.init_pos_radius,
            init_vel=args.init_vel,
            init_tilt_deg=args.init_tilt,
            init_rate=args.init_rate,
            drag=args.drag,
            imu_noise=args.imu_noise,
            estimator_noise=args.estimator_noise,
            dt=1.0 / args.rate,
            seed=args.seed,
            episodes=args.episodes,
            gps_every=args.gps_every,
            lockstep=args.lockstep,
            esc_timeout_s=args.esc_timeout,
            lockstep_timeout_s=args.lockstep_timeout,
            max_steps=args.max_steps,
            spin_s=args.spin_us / 1e6,
            signing_key=read_key(args.key) if args.key else None,
            sensor_faults=args.sensor_fault,
        )
    except (ValueError, SigningError) as e:
        raise UsageError(str(e)) from None


def _write_stats(path: str, stats: SimStats, prog: str = "quad-sitl") -> bool:
    """--json on the way out; False (and one line) if it could not be written."""
    import json

    try:
        text = json.dumps(dataclasses.asdict(stats), indent=1)
        atomic_write(path, lambda f: f.write(text.encode()))
    except OSError as e:
        print(f"{prog}: error: --json {path}: {e.strerror or e}", file=sys.stderr)
        return False
    return True


def main_sim_only(argv: list[str] | None = None, prog: str = "quad-sitl") -> int:
    """`quad-sitl --sim-only [...]`: serve episodes, one line per episode on stdout. Returns the
    exit code: 0 done, 1 the simulator could not run (e.g. port taken), 2 bad flags, 130 Ctrl-C."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_sim_parser(f"{prog} --sim-only").parse_args(argv)
        cfg = config_from_args(args)
        if args.json is not None:  # before serving: not lost at the end
            try:
                check_output_path(Path(args.json), "--json")
            except ValueError as e:
                raise UsageError(str(e)) from None
    except SystemExit as e:  # --help
        return e.code if isinstance(e.code, int) else 0
    except UsageError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 2
    except VehicleFileError as e:  # a --vehicle file that cannot be used
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 1
    sim = Simulator(cfg, on_episode=lambda r: print(r.summary(), flush=True))
    try:
        address = sim.bind()
        mode = "lockstep" if cfg.lockstep else "realtime"
        what = f"{mode}, {cfg.start} start, vehicle {vehicle_label(cfg)}, seed {cfg.seed}"
        print(f"{prog}: simulator listening on {address} ({what})", flush=True)
        stats = sim.serve()
    except SimulatorError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"\n{prog}: interrupted", file=sys.stderr)
        return 130
    finally:
        sim.close()
        written = not args.json or _write_stats(args.json, sim.stats, prog)
    dropped = sum(stats.dropped.values())
    print(f"{prog}: served {stats.episodes} episodes, {stats.steps} steps, dropped {dropped} packets", flush=True)
    return 0 if written else 1
