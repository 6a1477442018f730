"""quad-train's flags as configurations, for every algorithm: the trainer's configuration (the
size and seed flags, PPO's preset, --set NAME=VALUE), the environment (--vehicle, --randomize,
--sensor-noise, --motor-tau) and, on --resume, what the flags ask that the checkpoint's run differs
in. The run loop (`loop`) calls these with the algorithm's Trainer class; the parser is `train.cli`'s.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from quadpilot.console import UsageError

# Configuration fields that have a command-line option (--total-steps ...); given explicitly, they
# override the preset. PPO has all of them; SAC the first six (the network options are PPO's).
SIZE_OPTIONS = {
    "total_steps": ("N", 1),
    "num_envs": ("K", 1),
    "seed": ("S", 0),
    "rollout_steps": ("T", 1),
    "minibatch_size": ("M", 1),
    "threads": ("N", 1),
    "obs_history": ("K", 1),
    "bptt_steps": ("L", 0),
}
PPO_NETWORK_OPTIONS = ("arch", "obs_history", "bptt_steps", "update")
"""Options of our PPO (its network, and how its update is computed): refused for the other algorithms."""
PPO_UPDATE_OPTIONS = ("epochs", "lr", "lr_schedule")
"""Options of PPO's update (ours and the SB3 baseline's): refused for SAC."""
RESUME_MAY_CHANGE = ("total_steps", "threads")
"""Options a resumed run may change; everything else must match the checkpoint."""


def upper_bounds() -> dict[str, int]:
    """The largest value of each SIZE_OPTIONS flag: the sizes a checkpoint may describe
    (`checks`), so that a run's own file is never refused, and 64 bits for the seed
    (torch.manual_seed)."""
    from .checks import MAX_BATCH, MAX_ENVS, MAX_OBS_HISTORY, MAX_THREADS

    sizes = {"num_envs": MAX_ENVS, "rollout_steps": MAX_BATCH, "minibatch_size": MAX_BATCH, "bptt_steps": MAX_BATCH}
    return {**sizes, "threads": MAX_THREADS, "obs_history": MAX_OBS_HISTORY, "seed": 2**63 - 1, "total_steps": 2**62}


# --- the trainer's configuration -------------------------------------------------------------


def parse_overrides(
    items: list[str] | None, cls: type, algo: str, flag: str = "--set", what: str | None = None
) -> dict[str, Any]:
    """`flag` NAME=VALUE items (--set: the trainer's) as fields of the configuration dataclass `cls`,
    typed by the field (int, float, bool, tuple of ints, str, or None for an optional field); `what`
    names a field in the message (default: a hyper-parameter of `algo`). Raises UsageError naming
    the problem."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    out: dict[str, Any] = {}
    for item in items or []:
        name, sep, text = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or name not in fields:
            known = ", ".join(sorted(fields))
            what = what or f"a {algo.upper()} hyper-parameter"
            raise UsageError(f"{flag} {item!r}: expected NAME=VALUE with NAME {what} ({known})")
        kind = str(fields[name].type)
        text = text.strip()
        try:
            if text.lower() == "none" and "None" in kind:
                value: Any = None
            elif kind.startswith("tuple"):
                value = tuple(int(v) for v in text.replace("x", ",").split(",") if v.strip())
            elif kind == "bool":
                if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                    raise ValueError(text)
                value = text.lower() in ("true", "1", "yes")
            elif kind == "int":
                value = int(text.replace("_", ""))
            elif kind.startswith("float"):
                value = float(text)
            else:
                value = text
        except ValueError:
            raise UsageError(f"{flag} {item!r}: {text!r} is not a valid {kind}") from None
        out[name] = value
    return out


def explicit_options(args, algo) -> dict[str, Any]:
    """The configuration fields the command line gives for trainer class `algo`: the size flags,
    --arch, --update, PPO's update settings, then --set (which wins)."""
    explicit = {k: getattr(args, k) for k in SIZE_OPTIONS if getattr(args, k) is not None}
    for k in ("arch", "update"):
        if getattr(args, k, None):
            explicit[k] = getattr(args, k)
    for k in PPO_UPDATE_OPTIONS:
        if getattr(args, k, None) is not None:
            explicit[k] = getattr(args, k)
    explicit.update(parse_overrides(getattr(args, "set", None), algo.Config, algo.algo))
    return explicit


def make_config(algo, explicit: dict, preset: str | None):
    """The configuration of a fresh run: PPO's preset (default fast) under the explicit options;
    SAC's defaults under them. UsageError naming a value the configuration refuses."""
    from .checks import check_sizes

    base = algo.preset_values(preset)
    try:
        cfg = algo.Config(**{**base, **explicit})
    except ValueError as e:
        raise UsageError(f"{algo.algo.upper()} configuration: {e}") from None
    try:  # the bounds of a checkpoint's, for the flags and the preset together
        check_sizes(cfg, "the configuration")
    except ValueError as e:
        raise UsageError(str(e)) from None
    return cfg


# --- the environment -------------------------------------------------------------------------


def resolve_vehicle_arg(args) -> None:
    """--vehicle NAME|FILE.toml: a shipped name stays a name (`core.vehicle_file.get_preset`, equal to its
    file), a file becomes its VehicleParams. UnknownVehicleError (exit 2) or VehicleFileError (exit 1)."""
    from quadpilot.core.vehicle_file import is_vehicle_path, resolve_vehicle

    if args.vehicle is None:
        return
    params = resolve_vehicle(args.vehicle)  # checks a name against the shipped files, reads a file
    if is_vehicle_path(args.vehicle):
        args.vehicle = params


def chosen_vehicle(args):
    """The VehicleParams --vehicle names (seed without it)."""
    from quadpilot.core.params import VehicleParams
    from quadpilot.core.vehicle_file import get_preset

    v = args.vehicle or "seed"
    return v if isinstance(v, VehicleParams) else get_preset(v)


def _sensor_preset(args) -> str:
    """The sensor-noise preset --sensor-noise names; without a PRESET, the vehicle's own, which a
    vehicle file has only if its name is a sensor-noise preset's."""
    from quadpilot.core.sensor_noise import SENSOR_NOISE_PRESETS

    if args.sensor_noise != "vehicle":
        return args.sensor_noise
    name = chosen_vehicle(args).name
    if name not in SENSOR_NOISE_PRESETS:
        raise UsageError(
            f"--sensor-noise: no sensor model for vehicle {name!r}; name one: --sensor-noise "
            f"{'|'.join(sorted(SENSOR_NOISE_PRESETS))}"
        )
    return name


def check_motor_tau(args) -> None:
    from quadpilot.core.params import checked_motor_tau

    if args.motor_tau is not None:
        try:
            checked_motor_tau(args.motor_tau)
        except ValueError:
            raise UsageError(f"--motor-tau must be a finite number of seconds ≥ 0, got {args.motor_tau}") from None


def check_heading_offset(args) -> None:
    off = getattr(args, "heading_offset", None)
    if off is not None and not (math.isfinite(off) and 0.0 <= off <= 180.0):
        raise UsageError(f"--heading-offset must be a number of degrees in [0, 180], got {off}")


DEFAULT_TIMING = "link"
"""quad-train's timing when no flag names one (`core.timing.PRESETS`)."""

TIMING_FLAGS = {"action_delay": "action_delay_ms", "obs_delay": "obs_delay_ms", "jitter": "jitter_ms"}
"""quad-train's per-range timing flags and the TimingConfig field each sets."""


def _ms_range(flag: str, text: str) -> tuple[float, float]:
    parts = text.split(":")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) not in (1, 2) or not all(math.isfinite(v) and v >= 0 for v in values) or values[0] > values[-1]:
        raise UsageError(f"{flag} {text!r}: expected milliseconds ≥ 0, one value or LOW:HIGH (e.g. 20 or 0:30)")
    return values[0], values[-1]


def chosen_timing(args):
    """The `core.timing.TimingConfig` of --timing, --action-delay, --obs-delay and --jitter (None: no
    flag given; a fresh run then takes DEFAULT_TIMING, a resumed one keeps its own)."""
    from quadpilot.core.timing import PRESETS

    name = getattr(args, "timing", None)
    ranges = {f: getattr(args, a, None) for a, f in TIMING_FLAGS.items()}
    if name is None and all(v is None for v in ranges.values()):
        return None
    if name is not None and name not in PRESETS:
        raise UsageError(f"--timing {name!r}: expected one of {', '.join(PRESETS)}")
    base = PRESETS[name or DEFAULT_TIMING]
    given = {
        f: _ms_range("--" + a.replace("_", "-"), ranges[f]) for a, f in TIMING_FLAGS.items() if ranges[f] is not None
    }
    if not given:
        return base
    try:
        return dataclasses.replace(base, name="custom", **given)
    except ValueError as e:
        raise UsageError(str(e)) from None


def chosen_reward(args):
    """The task's reward with --reward NAME=VALUE's fields set (None: no --reward given)."""
    items = getattr(args, "reward", None)
    if not items:
        return None
    from quadpilot.core.reward import RewardConfig

    from ..envs import make_config

    values = parse_overrides(items, RewardConfig, "", flag="--reward", what="a field of the reward")
    item = {i.partition("=")[0].strip().replace("-", "_"): i for i in items}  # each field's last item, as given
    for name, value in values.items():
        positive = name.endswith("_sigma") or name.startswith(("max_", "tilt_soft"))  # widths and limits
        if not math.isfinite(value) or value < 0 or (positive and value == 0):
            what = "a finite number > 0" if positive else "a finite number ≥ 0"
            raise UsageError(f"--reward {item[name]!r}: expected {what} after '='")
    return dataclasses.replace(make_config(args.task).reward, **values)


def env_kwargs(args) -> dict:
    """`envs.make_config` keywords of a fresh run for --vehicle, --randomize, --sensor-noise,
    --motor-tau, --timing (and its ranges), --reward, --init-rotor, --heading-offset and --obs-version."""
    from quadpilot.core.timing import get_timing

    kw: dict = {"vehicle": args.vehicle} if args.vehicle else {}
    if getattr(args, "randomize", None):
        kw["randomization"] = args.randomize  # a preset name; make_config scales it to the vehicle
    if args.sensor_noise:
        kw["sensor_noise"] = _sensor_preset(args)
    if args.motor_tau is not None:
        check_motor_tau(args)
        kw["vehicle"] = dataclasses.replace(chosen_vehicle(args), motor_tau=args.motor_tau)
    kw["timing"] = chosen_timing(args) or get_timing(DEFAULT_TIMING)  # a fresh run: DEFAULT_TIMING unless told
    reward = chosen_reward(args)
    if reward is not None:
        kw["reward"] = reward
    if getattr(args, "init_rotor", None):
        kw["init_rotor"] = args.init_rotor
    if getattr(args, "obs_version", None):
        kw["obs_version"] = args.obs_version
        if args.obs_version == 1:
            kw["heading_offset_deg"] = 0.0  # as before the yaw rule, unless --heading-offset says otherwise
    if getattr(args, "heading_offset", None) is not None:
        check_heading_offset(args)
        kw["heading_offset_deg"] = args.heading_offset
    return kw


# --- what a resume may not change -------------------------------------------------------------


def clashes(args, explicit: dict, stored_cfg, extra: dict, env_config: dict) -> list[str]:
    """What the flags of a --resume ask that the checkpoint's run (configuration `stored_cfg`,
    `extra`, environment `env_config`) differs in; RESUME_MAY_CHANGE may differ."""
    from quadpilot.core.params import VehicleParams

    out = [
        f"--{k.replace('_', '-')} {v} (checkpoint: {getattr(stored_cfg, k)})"
        for k, v in explicit.items()
        if k not in RESUME_MAY_CHANGE and v != getattr(stored_cfg, k)
    ]
    if args.preset and args.preset != extra.get("preset"):
        out.append(f"--preset {args.preset} (checkpoint: {extra.get('preset')})")
    stored = env_config["vehicle"]
    if isinstance(args.vehicle, str) and args.vehicle != stored["name"]:  # a name: the same name
        out.append(f"--vehicle {args.vehicle} (checkpoint: {stored['name']})")
    elif args.vehicle and not isinstance(args.vehicle, str):  # a file: the same parameters
        want = args.vehicle if args.motor_tau is None else dataclasses.replace(args.vehicle, motor_tau=args.motor_tau)
        if want != VehicleParams(**stored):
            out.append(f"--vehicle {want.name} from a file whose parameters differ (checkpoint: {stored['name']})")
    if getattr(args, "randomize", None):
        name = (env_config.get("randomization") or {}).get("name")
        if name != args.randomize:
            out.append(f"--randomize {args.randomize} (checkpoint: {name or 'off'})")
    if args.sensor_noise:
        want = _sensor_preset(args)
        name = (env_config.get("sensor_noise") or {}).get("name")
        if name != want:
            out.append(f"--sensor-noise {want} (checkpoint: {name or 'off'})")
    reward = chosen_reward(args)
    if reward is not None:
        have = env_config.get("reward", {})
        moved = [f"{k}={v:g}" for k, v in dataclasses.asdict(reward).items() if have.get(k) != v]
        if moved:
            out.append(f"--reward {' '.join(moved)} (checkpoint: another reward)")
    timing = chosen_timing(args)
    if timing is not None:
        have = env_config.get("timing") or {}
        ranges = {k: tuple(have.get(k, (0.0, 0.0))) for k in TIMING_FLAGS.values()}
        if any(getattr(timing, k) != v for k, v in ranges.items()):
            out.append(f"--timing {timing.name} (checkpoint: {have.get('name', 'none')})")
    if args.motor_tau is not None and args.motor_tau != stored.get("motor_tau"):
        out.append(f"--motor-tau {args.motor_tau} (checkpoint: {stored.get('motor_tau')})")
    if getattr(args, "init_rotor", None) and args.init_rotor != env_config.get("init_rotor", "hover"):
        out.append(f"--init-rotor {args.init_rotor} (checkpoint: {env_config.get('init_rotor', 'hover')})")
    version = env_config.get("obs_version", 1)  # saved before the yaw rule: version 1
    if getattr(args, "obs_version", None) and args.obs_version != version:
        out.append(f"--obs-version {args.obs_version} (checkpoint: {version})")
    offset = env_config.get("heading_offset_deg", 0.0)
    if getattr(args, "heading_offset", None) is not None and args.heading_offset != offset:
        out.append(f"--heading-offset {args.heading_offset:g} (checkpoint: {offset:g})")
    return out
