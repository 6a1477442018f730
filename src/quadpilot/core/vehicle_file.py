"""Vehicle files: an airframe as a TOML file, read into a `VehicleParams`.

The shipped presets are files of this package (`quadpilot/vehicles/<name>.toml`), and a user's file
works the same way. The schema takes the numbers as RotorPy's and PX4's parameter sets give them:

    name = "px4_sih_quadx"     # NAME_RULE: letters, digits, "_", ".", "+", "-", a letter or digit first (it names
                               # the vehicle in messages and metadata)
    mass = 1.0                 # kg
    ixx = 0.025                # kg m^2, principal inertias (diagonal inertia tensor)
    iyy = 0.025
    izz = 0.030
    k_thrust = 5.0e-6          # N/(rad/s)^2, rotor thrust = k_thrust * omega^2
    k_torque = 1.0e-7          # N m/(rad/s)^2, rotor reaction torque = k_torque * omega^2
    omega_max = 1000.0         # rad/s at actuator command 1.0 (omega = command * omega_max)
    omega_min = 0.0            # rad/s, optional: idle speed of an armed motor (see below)
    motor_tau = 0.05           # s, first-order rotor lag, optional (0 = none)
    drag = 0.0                 # N s/m, optional: linear drag, see below
    drag_quadratic = [0.005, 0.005, 0.01]  # N/(m/s)^2 along body x, y, z, optional: RotorPy's c_Dx, c_Dy, c_Dz
    k_d = 1.19e-4              # optional, RotorPy's rotor aerodynamics (names and units as RotorPy's):
    k_z = 2.32e-4              #   rotor drag and induced inflow, N/(rad/s * m/s),
    k_h = 3.39e-3              #   translational lift, N/(m/s)^2,
    k_flap = 0.0               #   blade flapping, N m/(rad/s * m/s)
    [[rotor]]                  # one table per rotor, in actuator output order (output 1 first)
    x = 0.17                   # m, forward of the centre of mass (body FRD)
    y = 0.17                   # m, to the right
    spin = "ccw"               # seen from above

Mapping onto `VehicleParams`: k_f = k_thrust; k_m = k_torque / k_thrust (m, yaw torque per newton
of thrust); the rotor tables become `VehicleParams.rotors` as they are (positions in FRD, in output
order; `core.params.flu_layout` is the one place they turn into the dynamics' FLU frame); arm = the
rotors' mean distance from the centre of mass. Any layout and any output order: four rotors
anywhere around the centre of mass, numbered as the vehicle's outputs are. PX4's quad-X numbers
them 1 front-right CCW, 2 rear-left CCW, 3 front-left CW, 4 rear-right CW; RotorPy's hummingbird
1 front-left CW, 2 front-right CCW, 3 rear-right CW, 4 rear-left CCW; a file says which. Refused,
naming `rotor`: a count other than four (the policy's action and the actuator outputs carry four),
a layout that cannot make roll, pitch and yaw torque independently (rotors on one line, spins that
cannot balance), or one whose hover needs a negative thrust (the centre of mass outside the rotors).

Rotor speed: omega = command * omega_max, clipped to [omega_min, omega_max] as RotorPy 3.0.0 clips it
(rotorpy/vehicles/multirotor.py, `Multirotor.step`, rotor_speed_min/rotor_speed_max). With
omega_min > 0 an armed motor idles at omega_min even at command 0; motors off (disarmed) stop the
rotors (`core.dynamics`, module docstring). omega_min must be below omega_max.

Drag, two laws, both optional and zero by default (`core.dynamics`):
- `drag`: linear and isotropic, F = drag · (v_wind − v) in N with v in m/s (world frame, the same in
  every frame because it is isotropic): a scalar or three equal values [dx, dy, dz]. PX4's SIH uses
  this law (SIH_KDV, N/(m/s), `D = -KDV*V`; default 1.0).
- `drag_quadratic = [c_Dx, c_Dy, c_Dz]`: RotorPy's parasitic drag, quadratic and per body axis,
  N/(m/s)^2: D = −|v_a|·diag(c_Dx, c_Dy, c_Dz)·v_a on the body airspeed v_a = Rᵀ(v − v_wind)
  (rotorpy/vehicles/multirotor.py, `compute_body_wrench`); RotorPy's airframe modules give the
  three numbers as they are (the coefficients are magnitudes, the same in FRD and FLU).
A file may give both; they add. RotorPy's rotor aerodynamics take its names and units: rotor drag
k_d and induced inflow k_z (N/(rad/s·m/s)), translational lift k_h (N/(m/s)^2), blade flapping
k_flap (N·m/(rad/s·m/s)) (`core.rotor_aero`); all optional, 0 by default.

k_m and arm are derived, and rounded to 12 significant digits: a file written from the decimal
values of a `VehicleParams` (`vehicle_to_toml`) then reads back to the same floats, bit for bit.

A file that cannot be used raises `VehicleFileError` (a ValueError) with one line naming the file,
the key and the reason; an unknown preset name raises `UnknownVehicleError`.
"""

from __future__ import annotations

import math
import re
from dataclasses import fields
from pathlib import Path

try:  # stdlib from Python 3.11; the `tomli` backport (same API) on 3.10
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

from .params import GRAVITY, NUM_MOTORS, Rotor, VehicleParams, VehicleParamsError, checked_motor_tau

VEHICLES_DIR = Path(__file__).resolve().parent.parent / "vehicles"
"""The shipped vehicle files (package data, `quadpilot/vehicles/*.toml`)."""

MAX_FILE_BYTES = 64 * 1024
"""A vehicle file is a few hundred bytes; anything beyond this is not one (and is not read whole)."""

NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}")
"""A vehicle's name (`NAME_RULE`), the one rule wherever a name is read or written: a vehicle file,
a policy file's metadata (`modelfile`), the C the generator writes it into, the vehicle file the
simulator is given for a policy's vehicle. None of its characters needs quoting in TOML, JSON or C,
and it starts with a letter or digit, so it is never a hidden file's name, "." or "..", or an option."""
NAME_RULE = "1-64 letters, digits, '_', '.', '+' or '-', the first a letter or digit"

_REQUIRED = ("name", "mass", "ixx", "iyy", "izz", "k_thrust", "k_torque", "omega_max", "rotor")
_ROTOR_AERO = ("k_d", "k_z", "k_h", "k_flap")
_OPTIONAL = ("omega_min", "motor_tau", "drag", "drag_quadratic", *_ROTOR_AERO)
_ROTOR_KEYS = ("x", "y", "spin")

_FIELD_KEY = {
    "k_f": "k_thrust",
    "k_m": "k_torque",
    "arm": "rotor",
    "rotors": "rotor",
    "c_dx": "drag_quadratic",
    "c_dy": "drag_quadratic",
    "c_dz": "drag_quadratic",
}
"""VehicleParams field → the file key that gives it (the others are spelt alike)."""


class VehicleFileError(ValueError):
    """A vehicle file that cannot be used: one line naming the file, the key and the reason."""

    def __init__(self, path, key: str | None, reason: str) -> None:
        self.path, self.key, self.reason = str(path), key, reason
        where = f"{self.path}: {key}: " if key else f"{self.path}: "
        super().__init__(" ".join(f"{where}{reason}".split()))  # one line, whatever the reason held


class UnknownVehicleError(ValueError):
    """A vehicle name that is neither a shipped preset nor a path to a .toml file."""


def shipped_names() -> list[str]:
    """Names of the shipped vehicle files (`quadpilot/vehicles/<name>.toml`), sorted."""
    return sorted(p.stem for p in VEHICLES_DIR.glob("*.toml"))


def is_vehicle_path(spec: str) -> bool:
    """Whether a --vehicle value names a file (ends in .toml or holds a path separator) rather than
    a shipped preset."""
    return spec.endswith(".toml") or "/" in spec or "\\" in spec


def resolve_vehicle(spec: str) -> VehicleParams:
    """The vehicle a `--vehicle NAME|FILE.toml` value names: a shipped preset's file, or a user's
    file. UnknownVehicleError for an unknown name, VehicleFileError for a file that cannot be used."""
    if is_vehicle_path(spec):
        return load_vehicle_file(spec)
    names = shipped_names()
    if spec not in names:
        shown = spec if len(spec) <= 40 else spec[:40] + "..."
        raise UnknownVehicleError(
            f"unknown vehicle {shown!r}; expected a shipped vehicle ({', '.join(names)}) or a path to a .toml file"
        )
    return load_vehicle_file(VEHICLES_DIR / f"{spec}.toml")


def load_vehicle_file(path) -> VehicleParams:
    """Read and check the vehicle file at `path` (see the module docstring)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_FILE_BYTES + 1)
    except IsADirectoryError:
        raise VehicleFileError(path, None, "is a directory; expected a vehicle .toml file") from None
    except OSError as e:
        raise VehicleFileError(path, None, f"cannot read: {e.strerror or e}") from None
    if len(raw) > MAX_FILE_BYTES:
        raise VehicleFileError(path, None, f"too big: over {MAX_FILE_BYTES} bytes; a vehicle file is a few hundred")
    return parse_vehicle(raw, path)


def parse_vehicle(raw: bytes, path="<vehicle>") -> VehicleParams:
    """A `VehicleParams` from the bytes of a vehicle file; `path` names it in errors."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise VehicleFileError(path, None, f"not UTF-8 text (byte {e.start}); expected a UTF-8 TOML file") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise VehicleFileError(path, None, f"not valid TOML: {e}") from None
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        raise VehicleFileError(path, None, "not a vehicle file: arrays or tables nested too deeply") from None
    return _from_table(doc, path)


def _from_table(doc: dict, path) -> VehicleParams:
    unknown = sorted(set(doc) - set(_REQUIRED) - set(_OPTIONAL))
    if unknown:
        raise VehicleFileError(path, _short(unknown[0]), f"unknown key; expected {', '.join(_REQUIRED + _OPTIONAL)}")
    for key in _REQUIRED:
        if key not in doc:
            raise VehicleFileError(path, key, "missing; every vehicle file gives it")
    name = doc["name"]
    if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
        found = f"{_short(name)!r}" if isinstance(name, str) else _type(name)
        raise VehicleFileError(path, "name", f"expected {NAME_RULE}, found {found}")

    def number(key: str, relation: str, default: float | None = None) -> float:
        if key not in doc:
            return default  # type: ignore[return-value]
        return _number(doc[key], path, key, relation)

    mass = number("mass", "> 0")
    ixx, iyy, izz = number("ixx", "> 0"), number("iyy", "> 0"), number("izz", "> 0")
    k_thrust, k_torque = number("k_thrust", "> 0"), number("k_torque", "> 0")
    omega_max = number("omega_max", "> 0")
    omega_min = number("omega_min", ">= 0", 0.0)
    motor_tau = _motor_tau(doc.get("motor_tau", 0.0), path)
    drag = _drag(doc.get("drag", 0.0), path)
    c_dx, c_dy, c_dz = _drag_quadratic(doc.get("drag_quadratic", [0.0, 0.0, 0.0]), path)
    aero = {k: number(k, ">= 0", 0.0) for k in _ROTOR_AERO}
    rotors = _rotors(doc["rotor"], path)
    arm = _round12(sum(math.hypot(r.x, r.y) for r in rotors) / len(rotors))
    try:
        return VehicleParams(
            name=name,
            mass=mass,
            arm=arm if arm > 0 else None,  # all rotors at the centre: VehicleParams names it
            ixx=ixx,
            iyy=iyy,
            izz=izz,
            k_f=k_thrust,
            k_m=_round12(k_torque / k_thrust),
            omega_max=omega_max,
            motor_tau=motor_tau,
            drag=drag,
            omega_min=omega_min,
            rotors=rotors,
            c_dx=c_dx,
            c_dy=c_dy,
            c_dz=c_dz,
            **aero,
        )
    except VehicleParamsError as e:  # the layout, omega_min ≥ omega_max, a derived value out of range
        # VehicleParams says "vehicle 'name': field...: reason"; the file's message names the file's key
        reason = str(e).split(": ", 1)[1] if str(e).startswith("vehicle ") else str(e)
        if e.field == "k_m":  # derived: say from what
            reason = f"k_torque / k_thrust: {reason}"
        elif reason.startswith(e.field):
            reason = reason[len(e.field) :].lstrip(":")
        raise VehicleFileError(path, _FIELD_KEY.get(e.field, e.field), reason.strip()) from None


def _float(v, path, key: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise VehicleFileError(path, key, f"expected a number (float or integer), found {_type(v)}")
    try:
        return float(v)
    except OverflowError:  # a TOML integer beyond the float range
        return math.inf


def _motor_tau(v, path) -> float:
    try:
        return checked_motor_tau(_float(v, path, "motor_tau"))
    except VehicleParamsError:
        raise VehicleFileError(path, "motor_tau", f"= {_short(v)}: expected a finite number >= 0") from None


def _number(v, path, key: str, relation: str) -> float:
    f = _float(v, path, key)
    ok = f > 0 if relation == "> 0" else f >= 0
    if not (math.isfinite(f) and ok):
        raise VehicleFileError(path, key, f"= {_short(v)}: expected a finite number {relation}")
    return f


def _drag(v, path) -> float:
    if isinstance(v, list):
        if len(v) != 3:
            raise VehicleFileError(path, "drag", f"expected one number or three equal ones, found a list of {len(v)}")
        values = [_number(x, path, "drag", ">= 0") for x in v]
        if len(set(values)) != 1:
            raise VehicleFileError(
                path, "drag", f"= {v}: the model's drag is isotropic (one linear coefficient); expected equal values"
            )
        return values[0]
    return _number(v, path, "drag", ">= 0")


def _drag_quadratic(v, path) -> tuple[float, float, float]:
    key = "drag_quadratic"
    if not isinstance(v, list) or len(v) != 3:
        found = f"a list of {len(v)}" if isinstance(v, list) else _type(v)
        raise VehicleFileError(path, key, f"expected three numbers [c_Dx, c_Dy, c_Dz] in N/(m/s)^2, found {found}")
    cx, cy, cz = (_number(x, path, key, ">= 0") for x in v)
    return cx, cy, cz


def _rotors(rotors, path) -> tuple[Rotor, ...]:
    """The [[rotor]] tables as Rotors, in output order; VehicleFileError naming the rotor otherwise."""
    if not isinstance(rotors, list) or not all(isinstance(r, dict) for r in rotors):
        raise VehicleFileError(path, "rotor", f"expected [[rotor]] tables, found {_type(rotors)}")
    if len(rotors) != NUM_MOTORS:
        raise VehicleFileError(
            path,
            "rotor",
            f"{len(rotors)} rotor table(s); expected {NUM_MOTORS} (the policy's action and the actuator outputs "
            "carry four), in output order",
        )
    out = []
    for i, r in enumerate(rotors, start=1):
        where = f"rotor[{i}]"  # output number, 1-based
        unknown = sorted(set(r) - set(_ROTOR_KEYS))
        if unknown:
            raise VehicleFileError(path, f"{where}.{_short(unknown[0])}", "unknown key; expected x, y, spin")
        for key in _ROTOR_KEYS:
            if key not in r:
                raise VehicleFileError(path, f"{where}.{key}", "missing; every rotor gives x, y and spin")
        x, y = (_finite(r[k], path, f"{where}.{k}") for k in ("x", "y"))
        spin = r["spin"]
        if spin not in ("cw", "ccw"):
            found = repr(_short(spin)) if isinstance(spin, str) else _type(spin)
            raise VehicleFileError(path, f"{where}.spin", f'expected "cw" or "ccw" (seen from above), found {found}')
        out.append(Rotor(x, y, spin))
    return tuple(out)


def _finite(v, path, key: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise VehicleFileError(path, key, f"expected a number in metres, found {_type(v)}")
    try:
        f = float(v)
    except OverflowError:
        f = math.inf
    if not math.isfinite(f):
        raise VehicleFileError(path, key, f"= {_short(v)}: expected a finite number of metres")
    return f


def _round12(v: float) -> float:
    """`v` to 12 significant digits (see the module docstring: exact round trips of derived values)."""
    return float(f"{v:.12g}")


def _short(v) -> str:
    s = str(v)
    return s if len(s) <= 40 else s[:40] + "..."


def _type(v) -> str:
    return {dict: "a table", list: "an array", str: "a string", bool: "a boolean"}.get(type(v), type(v).__name__)


def vehicle_to_toml(v: VehicleParams) -> str:
    """A vehicle file for `v` that `parse_vehicle` reads back to `v` (numbers with ≤ 12 significant
    digits in arm and k_m, as every preset's, come back bit for bit). A gravity other than the
    standard one is not part of an airframe file: ValueError."""
    if v.gravity != GRAVITY:
        raise ValueError(f"vehicle {v.name!r}: gravity {v.gravity} is not {GRAVITY}; a vehicle file cannot hold it")
    if not NAME_PATTERN.fullmatch(v.name):
        raise ValueError(f"vehicle name {_short(v.name)!r}: a vehicle file needs {NAME_RULE}")
    k_torque = _pick(v.k_m * v.k_f, lambda t: _round12(t / v.k_f) == v.k_m)
    lines = [
        f'name = "{v.name}"',
        f"mass = {v.mass!r}  # kg",
        f"ixx = {v.ixx!r}  # kg m^2",
        f"iyy = {v.iyy!r}  # kg m^2",
        f"izz = {v.izz!r}  # kg m^2",
        f"k_thrust = {v.k_f!r}  # N/(rad/s)^2",
        f"k_torque = {k_torque!r}  # N m/(rad/s)^2 (k_m {v.k_m!r} m times k_thrust)",
        f"omega_max = {v.omega_max!r}  # rad/s at command 1.0",
        f"omega_min = {v.omega_min!r}  # rad/s, idle speed of an armed motor",
        f"motor_tau = {v.motor_tau!r}  # s",
        f"drag = {v.drag!r}  # N s/m, linear, isotropic",
    ]
    if v.c_dx or v.c_dy or v.c_dz:
        lines.append(f"drag_quadratic = [{v.c_dx!r}, {v.c_dy!r}, {v.c_dz!r}]  # N/(m/s)^2 along body x, y, z")
    units = {"k_d": "N/(rad/s m/s)", "k_z": "N/(rad/s m/s)", "k_h": "N/(m/s)^2", "k_flap": "N m/(rad/s m/s)"}
    if any(getattr(v, k) for k in _ROTOR_AERO):
        lines += [f"{k} = {getattr(v, k)!r}  # {units[k]}, RotorPy's" for k in _ROTOR_AERO]
    for i, r in enumerate(v.rotors, start=1):
        lines += ["", f"[[rotor]]  # output {i}", f"x = {r.x!r}  # m, forward (FRD)", f"y = {r.y!r}  # m, right"]
        lines.append(f'spin = "{r.spin}"')
    return "\n".join(lines) + "\n"


def _pick(guess: float, ok) -> float:
    """`guess` or the nearest of its float neighbours (within 8 ulps) for which `ok` holds."""
    for d in range(9):
        for c in {guess, *_steps(guess, d)}:
            if ok(c):
                return c
    return guess


def _steps(v: float, n: int) -> tuple[float, float]:
    up = down = v
    for _ in range(n):
        up, down = math.nextafter(up, math.inf), math.nextafter(down, -math.inf)
    return up, down


UNITS = {
    "mass": "kg",
    "arm": "m",
    "ixx": "kg·m²",
    "iyy": "kg·m²",
    "izz": "kg·m²",
    "k_f": "N/(rad/s)²",
    "k_m": "m",
    "omega_max": "rad/s",
    "motor_tau": "s",
    "drag": "N·s/m",
    "gravity": "m/s²",
    "omega_min": "rad/s",
    "c_dx": "N/(m/s)²",
    "c_dy": "N/(m/s)²",
    "c_dz": "N/(m/s)²",
    "k_d": "N/(rad/s · m/s)",
    "k_z": "N/(rad/s · m/s)",
    "k_h": "N/(m/s)²",
    "k_flap": "N·m/(rad/s · m/s)",
}
"""Each `VehicleParams` number's unit, as its field's docstring gives it (for messages)."""


def _rotor_rows(rotors) -> str:
    return " ".join(f"({r.x:.4g}, {r.y:.4g}, {r.spin})" for r in rotors)


def same_vehicle(a: VehicleParams, b: VehicleParams) -> bool:
    """Whether two vehicles are the same airframe: every field equal but the name (`differences`
    says what differs)."""
    return not differences(a, b)


def differences(a: VehicleParams, b: VehicleParams) -> list[str]:
    """What differs between two vehicles but their names, in field order, for a message:
    "mass 0.665 vs 0.03 kg" (a's value first), "rotors (x, y, spin) ... vs ..."."""
    out = []
    for f in fields(a):
        va, vb = getattr(a, f.name), getattr(b, f.name)
        if f.name == "name" or va == vb:
            continue
        if f.name == "rotors":
            out.append(f"rotors {_rotor_rows(va)} vs {_rotor_rows(vb)} (x, y in m, FRD)")
            continue
        ta, tb = f"{va:.6g}", f"{vb:.6g}"
        if ta == tb:  # apart only beyond six digits
            ta, tb = repr(va), repr(vb)
        out.append(f"{f.name} {ta} vs {tb} {UNITS[f.name]}")
    return out


def _shipped_presets() -> dict[str, VehicleParams]:
    names = sorted(shipped_names(), key=lambda n: n != "seed")  # the default first, then by name
    return {n: load_vehicle_file(VEHICLES_DIR / f"{n}.toml") for n in names}


PRESETS: dict[str, VehicleParams] = _shipped_presets()
"""The presets: the shipped vehicle files by name, read once. The files are the one definition of
each preset's numbers, each with its unit and source."""
SEED_VEHICLE, CRAZYFLIE, PX4_SIH_QUADX = PRESETS["seed"], PRESETS["crazyflie"], PRESETS["px4_sih_quadx"]


def get_preset(name: str) -> VehicleParams:
    """The preset called `name`; a clear error names the known ones."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown vehicle preset {name!r}; known presets: {sorted(PRESETS)}") from None
