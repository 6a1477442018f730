"""Vehicle files: an airframe as a TOML file, read into a `VehicleParams`.

The shipped presets are files of this package (`quadpilot/vehicles/<name>.toml`), and a user's file
works the same way. The schema takes the numbers as RotorPy's and PX4's parameter sets give them:

    name = "px4_sih_quadx"     # letters, digits, "_", "-", "." (it names the vehicle in messages and metadata)
    mass = 1.0                 # kg
    ixx = 0.025                # kg m^2, principal inertias (diagonal inertia tensor)
    iyy = 0.025
    izz = 0.030
    k_thrust = 5.0e-6          # N/(rad/s)^2, rotor thrust = k_thrust * omega^2
    k_torque = 1.0e-7          # N m/(rad/s)^2, rotor reaction torque = k_torque * omega^2
    omega_max = 1000.0         # rad/s at actuator command 1.0 (omega = command * omega_max)
    omega_min = 0.0            # rad/s, optional; only 0 (the model has no idle speed)
    motor_tau = 0.05           # s, first-order rotor lag, optional (0 = none)
    drag = 0.0                 # N s/m, optional: linear drag, see below
    [[rotor]]                  # one table per rotor, in actuator output order (output 1 first)
    x = 0.17                   # m, forward of the centre of mass (body FRD)
    y = 0.17                   # m, to the right
    spin = "ccw"               # seen from above

Mapping onto `VehicleParams`: k_f = k_thrust; k_m = k_torque / k_thrust (m, yaw torque per newton
of thrust); arm = the rotors' distance from the centre of mass. `core.dynamics` models a symmetric
quad-X, so the file must describe exactly that: four rotors at (±a/√2, ±a/√2) in PX4's quad-X
output order and spins (PX4 airframe "Quadrotor x": output 1 front-right CCW, 2 rear-left CCW,
3 front-left CW, 4 rear-right CW); any other layout is refused, naming the supported one.
Drag is linear and isotropic, F = drag · (v_wind − v) in N with v in m/s (world frame, the same in
every frame because it is isotropic): a scalar or three equal values [dx, dy, dz]. RotorPy's
`c_Dx, c_Dy, c_Dz` are quadratic parasitic-drag coefficients, a different law: do not paste them.

k_m and arm are derived, and rounded to 12 significant digits: a file written from the decimal
values of a `VehicleParams` (`vehicle_to_toml`) then reads back to the same floats, bit for bit.

A file that cannot be used raises `VehicleFileError` (a ValueError) with one line naming the file,
the key and the reason; an unknown preset name raises `UnknownVehicleError`.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

try:  # stdlib from Python 3.11; the `tomli` backport (same API) on 3.10
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

from .params import GRAVITY, VehicleParams

VEHICLES_DIR = Path(__file__).resolve().parent.parent / "vehicles"
"""The shipped vehicle files (package data, `quadpilot/vehicles/*.toml`)."""

MAX_FILE_BYTES = 64 * 1024
"""A vehicle file is a few hundred bytes; anything beyond this is not one (and is not read whole)."""

NAME_PATTERN = re.compile(r"[A-Za-z0-9_.-]{1,64}")

_REQUIRED = ("name", "mass", "ixx", "iyy", "izz", "k_thrust", "k_torque", "omega_max", "rotor")
_OPTIONAL = ("omega_min", "motor_tau", "drag")
_ROTOR_KEYS = ("x", "y", "spin")

# PX4's quad-X output order (ROMFS airframe "Quadrotor x", the order of `core.dynamics.MOTOR_LAYOUT`):
# signs of (x forward, y right) in body FRD, and spin seen from above.
QUAD_X = ((+1, +1, "ccw"), (-1, -1, "ccw"), (+1, -1, "cw"), (-1, +1, "cw"))
SUPPORTED_LAYOUTS = (
    "supported: quad-X only, 4 rotors at (±a/√2, ±a/√2) in PX4 output order "
    "1 front-right ccw, 2 rear-left ccw, 3 front-left cw, 4 rear-right cw (x forward, y right)"
)
_LAYOUT_RTOL = 1e-6  # relative: pasted positions of a symmetric frame agree to all their digits


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
        raise VehicleFileError(path, "name", f"expected 1-64 letters, digits, '_', '-' or '.', found {found}")

    def number(key: str, relation: str, default: float | None = None) -> float:
        if key not in doc:
            return default  # type: ignore[return-value]
        return _number(doc[key], path, key, relation)

    mass = number("mass", "> 0")
    ixx, iyy, izz = number("ixx", "> 0"), number("iyy", "> 0"), number("izz", "> 0")
    k_thrust, k_torque = number("k_thrust", "> 0"), number("k_torque", "> 0")
    omega_max = number("omega_max", "> 0")
    omega_min = number("omega_min", ">= 0", 0.0)
    if omega_min != 0.0:
        raise VehicleFileError(
            path, "omega_min", f"= {omega_min!r}: only 0 is supported (the model has no idle rotor speed)"
        )
    motor_tau = number("motor_tau", ">= 0", 0.0)
    drag = _drag(doc.get("drag", 0.0), path)
    arm = _quad_x_arm(doc["rotor"], path)
    try:
        return VehicleParams(
            name=name,
            mass=mass,
            arm=arm,
            ixx=ixx,
            iyy=iyy,
            izz=izz,
            k_f=k_thrust,
            k_m=_round12(k_torque / k_thrust),
            omega_max=omega_max,
            motor_tau=motor_tau,
            drag=drag,
        )
    except ValueError as e:  # a derived value out of range, e.g. k_torque / k_thrust overflowing
        raise VehicleFileError(path, None, str(e)) from None


def _number(v, path, key: str, relation: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise VehicleFileError(path, key, f"expected a number (float or integer), found {_type(v)}")
    try:
        f = float(v)
    except OverflowError:  # a TOML integer beyond the float range
        f = math.inf
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


def _quad_x_arm(rotors, path) -> float:
    """The arm length of a rotor list that is PX4's quad-X; VehicleFileError otherwise."""
    if not isinstance(rotors, list) or not all(isinstance(r, dict) for r in rotors):
        raise VehicleFileError(path, "rotor", f"expected [[rotor]] tables, found {_type(rotors)}")
    if len(rotors) != 4:
        raise VehicleFileError(path, "rotor", f"{len(rotors)} rotor table(s); {SUPPORTED_LAYOUTS}")
    pos = []
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
        pos.append((x, y, spin))
    a = abs(pos[0][0])
    for i, ((x, y, spin), (sx, sy, want)) in enumerate(zip(pos, QUAD_X, strict=True), start=1):
        symmetric = a > 0 and all(math.isclose(abs(c), a, rel_tol=_LAYOUT_RTOL) for c in (x, y))
        if not symmetric or math.copysign(1, x) != sx or math.copysign(1, y) != sy or spin != want:
            raise VehicleFileError(
                path, f"rotor[{i}]", f"(x {x:g}, y {y:g}, {spin}) is not this layout's; {SUPPORTED_LAYOUTS}"
            )
    arm = sum(math.hypot(x, y) for x, y, _ in pos) / 4.0
    return _round12(arm)


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
        raise ValueError(f"vehicle name {_short(v.name)!r}: a vehicle file needs 1-64 letters, digits, '_', '-', '.'")
    c = _pick(v.arm / math.sqrt(2.0), lambda x: _round12(math.hypot(x, x)) == v.arm)
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
        f"motor_tau = {v.motor_tau!r}  # s",
        f"drag = {v.drag!r}  # N s/m, linear, isotropic",
    ]
    for sx, sy, spin in QUAD_X:
        lines += ["", "[[rotor]]", f"x = {sx * c!r}  # m, forward (FRD)", f"y = {sy * c!r}  # m, right"]
        lines.append(f'spin = "{spin}"')
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
