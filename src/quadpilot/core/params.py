"""Vehicle parameters: airframe presets and per-drone parameter batches.

A `VehicleParams` is one airframe, each number in the unit its field's docstring gives.
Every VehicleParams checks its numbers when it is made (a preset, a scaled or replaced copy, one read
from a checkpoint or from an ONNX file's metadata): each one number, finite, positive (motor_tau,
drag and omega_min may be 0); anything else is a ValueError naming the field, its value and what was
expected. `ParamBatch` holds the same quantities as arrays of shape (N,) so that one dynamics call
steps N drones that may each differ (domain randomisation needs no other code path).

The presets are the shipped vehicle files, `quadpilot/vehicles/<name>.toml`, each number there with its
unit and source: `core.vehicle_file` reads them (and users' files alike) once into its `PRESETS`
(`get_preset`, `SEED_VEHICLE`, `CRAZYFLIE`, `PX4_SIH_QUADX`).

Rotors: `VehicleParams.rotors` lists them in actuator output order (output 1 first), each a `Rotor`
with its position in the body FRD frame (x forward, y right, m; as a vehicle file and PX4 give it)
and its spin seen from above. `flu_layout` is the one place that turns that into the FLU frame the
dynamics work in. A vehicle saved before rotor lists existed (an old checkpoint, config.json or ONNX
metadata) carries only `arm`: it is PX4's quad-X (`quad_x`), output 1 front-right CCW, 2 rear-left
CCW, 3 front-left CW, 4 rear-right CW, the only layout there was.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields, replace

import numpy as np

GRAVITY = 9.81  # m/s^2, standard gravity rounded as in the course brief and the ENPM 667 project

NUM_MOTORS = 4
"""Rotors per vehicle. The dynamics step any number; the policy's action, the ONNX contract
(`modelfile.contract.NUM_MOTORS`) and the HIL_ACTUATOR_CONTROLS outputs this project fills carry four,
so a vehicle has exactly four."""

SPINS = {"ccw": +1, "cw": -1}
"""Spin seen from above → sign of the rotor's angular momentum about body up (+z in FLU). A rotor
spinning counter-clockwise seen from above is driven by a +z motor torque, so its reaction on the
body is −z: τ_z = −sign·k_m·F."""


class VehicleParamsError(ValueError):
    """A VehicleParams field that cannot be used; `field` names it (a vehicle file maps it onto
    its own key)."""

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        super().__init__(message)


@dataclass(frozen=True)
class Rotor:
    """One rotor, as a vehicle file's [[rotor]] table gives it."""

    x: float
    """m, forward of the centre of mass (body FRD)."""
    y: float
    """m, to the right of the centre of mass (body FRD)."""
    spin: str
    """"ccw" or "cw", seen from above."""

    def __post_init__(self) -> None:
        for k in ("x", "y"):
            v = getattr(self, k)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
                raise ValueError(f"rotor {k}: expected a number of metres, found {type(v).__name__}")
            try:
                v = float(v)
            except OverflowError:
                v = math.inf
            if not math.isfinite(v):
                raise ValueError(f"rotor {k} = {v!r}: expected a finite number of metres")
            object.__setattr__(self, k, v)
        if not isinstance(self.spin, str) or self.spin not in SPINS:
            found = repr(self.spin[:20]) if isinstance(self.spin, str) else type(self.spin).__name__
            raise ValueError(f'rotor spin: expected "ccw" or "cw" (seen from above), found {found}')


def quad_x(arm: float) -> tuple[Rotor, ...]:
    """PX4's quad-X (PX4-Autopilot `ROMFS/px4fmu_common/init.d/airframes/4001_quad_x`, "Quadrotor x":
    CA_ROTOR0..3_PX/PY and their KM signs) with rotors `arm` m from the centre of mass, in its output
    order: 1 front-right CCW, 2 rear-left CCW, 3 front-left CW, 4 rear-right CW (FRD: y is right)."""
    c = arm / math.sqrt(2.0)
    return (Rotor(c, c, "ccw"), Rotor(-c, -c, "ccw"), Rotor(c, -c, "cw"), Rotor(-c, c, "cw"))


def flu_layout(rotors) -> np.ndarray:
    """(M, 3) float64 rows (x, y, spin sign) of `rotors` in the body FLU frame the dynamics use:
    x forward, y LEFT (FRD's y negated), spin +1 counter-clockwise seen from above. The one place
    the rotor list changes frame."""
    return np.array([(r.x, -r.y, float(SPINS[r.spin])) for r in rotors], dtype=np.float64).reshape(-1, 3)


def allocation_matrix(vehicle: VehicleParams) -> np.ndarray:
    """(4, M) map from per-rotor thrusts (N, output order) to [total thrust (N), τx, τy, τz (N·m,
    body FLU)]: a rotor at (x, y) in FLU pushing F along +z makes r × F = (y·F, −x·F, 0), and its
    reaction torque is −spin·k_m·F about z (see `SPINS`). `core.dynamics` integrates exactly this
    (per drone scaled by its arm); the fallback controller inverts it."""
    lay = flu_layout(vehicle.rotors)
    return np.stack([np.ones(len(lay)), lay[:, 1], -lay[:, 0], -lay[:, 2] * vehicle.k_m])


_TRIM_RTOL = 1e-12  # an equal split counts as the trim when it balances to rounding


def _trim_thrusts(vehicle: VehicleParams) -> np.ndarray:
    """N per rotor that hold hover: total thrust = weight and zero torque. The equal split
    weight/M when that already balances (every symmetric frame), else the allocation solved."""
    a = allocation_matrix(vehicle)
    m = a.shape[1]
    equal = np.full(m, vehicle.weight / m)
    with np.errstate(over="ignore", invalid="ignore"):  # absurd positions give inf: refused by the caller
        wrench = a @ equal
        scale = vehicle.weight * max(vehicle.arm, vehicle.k_m)
        if np.all(np.abs(wrench[1:]) <= _TRIM_RTOL * scale):
            return equal
        want = np.array([vehicle.weight, 0.0, 0.0, 0.0])
        try:
            return np.linalg.lstsq(a, want, rcond=None)[0] if m != 4 else np.linalg.solve(a, want)
        except np.linalg.LinAlgError:  # singular to working precision: no trim
            return np.full(m, np.nan)


@dataclass(frozen=True)
class VehicleParams:
    """One airframe. Every field: unit, then where the number comes from."""

    name: str
    """Preset name, as given to `get_preset`."""
    mass: float
    """kg."""
    arm: float | None
    """m, mean distance from the centre of mass to the rotor axes: the layout's scale (domain
    randomisation and drawings scale it). With `rotors` given, None derives it from them; a number
    must agree with them. Without `rotors`, the vehicle is PX4's quad-X of this arm (`quad_x`)."""
    ixx: float
    """kg·m², roll inertia."""
    iyy: float
    """kg·m², pitch inertia."""
    izz: float
    """kg·m², yaw inertia."""
    k_f: float
    """N/(rad/s)², rotor thrust coefficient: F = k_f·ω²."""
    k_m: float
    """m, yaw reaction torque per newton of thrust: |τ_z| = k_m·F."""
    omega_max: float
    """rad/s, rotor speed at full command (command 1.0 in HIL_ACTUATOR_CONTROLS)."""
    motor_tau: float = 0.0
    """s, first-order motor time constant; 0 means the rotor reaches its command at once (seeds)."""
    drag: float = 0.0
    """N·s/m, linear translational drag coefficient (world frame); 0 disables it (seeds)."""
    gravity: float = GRAVITY
    """m/s²."""
    omega_min: float = 0.0
    """rad/s, lowest rotor speed of an armed motor: the commanded speed command·omega_max is
    clipped to [omega_min, omega_max], as RotorPy 3.0.0 clips it (rotorpy/vehicles/multirotor.py,
    `Multirotor.step`: `np.clip(cmd_rotor_speeds, self.rotor_speed_min, self.rotor_speed_max)`).
    Command 0 then idles at omega_min; only motors off (disarmed, `core.dynamics.step`'s `armed`)
    stops the rotors. 0 (the presets): command 0 stops them."""
    rotors: tuple[Rotor, ...] | None = None
    """The rotors in actuator output order (output 1 first), positions in body FRD (`Rotor`); any
    sequence of Rotors or of {x, y, spin} tables (JSON metadata) is taken. Stored as a list of
    Rotors, so that `dataclasses.asdict` gives what JSON reads back (a config.json or ONNX metadata
    compares equal to it); never change it in place. None: PX4's quad-X of `arm` (`quad_x`), the
    layout of every vehicle saved without a list."""
    c_dx: float = 0.0
    """N/(m/s)², quadratic parasitic drag along body x (forward), RotorPy's c_Dx: the body-frame
    drag force is D = −|v_a|·diag(c_dx, c_dy, c_dz)·v_a for the airspeed v_a = Rᵀ(v − wind)
    (rotorpy/vehicles/multirotor.py, `compute_body_wrench`). 0 (and c_dy, c_dz 0): none."""
    c_dy: float = 0.0
    """N/(m/s)², the same along body y (left)."""
    c_dz: float = 0.0
    """N/(m/s)², the same along body z (up)."""
    k_d: float = 0.0
    """N/(rad/s · m/s), RotorPy's rotor drag (H force) in the rotor plane: each rotor's hub feels
    −ω_i·k_d times its local airspeed's x and y (`core.rotor_aero`). 0: none."""
    k_z: float = 0.0
    """N/(rad/s · m/s), RotorPy's induced-inflow coefficient: the same along the rotor axis, −ω_i·k_z·v_z."""
    k_h: float = 0.0
    """N/(m/s)², RotorPy's translational lift: each rotor's thrust grows by k_h·(v_x² + v_y²) of its
    local airspeed."""
    k_flap: float = 0.0
    """N·m/(rad/s · m/s), RotorPy's blade-flapping moment: −k_flap·ω_i·(v_i × e_z) at each hub."""

    def __post_init__(self) -> None:
        """Every field is checked where a VehicleParams is made (a preset, a scaled copy, a vehicle read
        from a checkpoint or an ONNX file's metadata), so that no code downstream meets a negative mass
        or a NaN: ValueError naming the field, what it holds and what was expected. Numbers are stored
        as Python floats (a NumPy scalar or an int is converted)."""
        if not isinstance(self.name, str):
            raise VehicleParamsError("name", f"vehicle name: expected a string, found {type(self.name).__name__}")
        label = repr(self.name if len(self.name) <= 40 else self.name[:40] + "...")  # repr: one line
        for f in fields(self):
            if f.name in ("name", "rotors") or (f.name == "arm" and self.arm is None and self.rotors is not None):
                continue
            v = getattr(self, f.name)
            # bool is an int subclass, and numbers.Real admits NumPy's float and int scalars
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
                if isinstance(v, (list, tuple)):
                    found = f"a sequence of {len(v)}"
                elif isinstance(v, np.ndarray):
                    found = f"an array of shape {v.shape}"
                else:
                    found = type(v).__name__
                raise VehicleParamsError(f.name, f"vehicle {label}: {f.name}: expected one number, found {found}")
            try:
                v = float(v)
            except OverflowError:  # an integer beyond the float range
                v = math.inf
            if f.name == "motor_tau":
                try:
                    v = checked_motor_tau(v)
                except VehicleParamsError as e:
                    raise VehicleParamsError(f.name, f"vehicle {label}: {e}") from None
                object.__setattr__(self, f.name, v)
                continue
            bound, relation = _VEHICLE_LIMITS[f.name]
            if not (math.isfinite(v) and (v > bound if relation == "> 0" else v >= bound)):
                raise VehicleParamsError(
                    f.name, f"vehicle {label}: {f.name} = {v!r}: expected a finite number {relation}"
                )
            object.__setattr__(self, f.name, v)
        if not self.omega_min < self.omega_max:
            raise VehicleParamsError(
                "omega_min",
                f"vehicle {label}: omega_min = {self.omega_min!r}: expected below omega_max ({self.omega_max!r} rad/s)",
            )
        rotors = list(quad_x(self.arm)) if self.rotors is None else _rotor_list(self.rotors, label)
        mean = sum(math.hypot(r.x, r.y) for r in rotors) / len(rotors)
        if self.arm is None:
            if not mean > 0:
                raise VehicleParamsError(
                    "rotors",
                    f"vehicle {label}: rotors: every rotor sits at the centre of mass; expected them around it",
                )
            object.__setattr__(self, "arm", mean)
        elif not math.isclose(self.arm, mean, rel_tol=_ARM_RTOL):
            raise VehicleParamsError(
                "arm",
                f"vehicle {label}: arm = {self.arm!r}: expected the rotors' mean distance from the centre of mass, "
                f"{mean!r} m (give arm=None to derive it; `scaled(arm=...)` scales the rotors with it)",
            )
        object.__setattr__(self, "rotors", rotors)
        a = allocation_matrix(self)
        row_max = np.abs(a).max(axis=1, keepdims=True)  # rows in N, N·m: compare shapes, not units
        if np.linalg.matrix_rank(a / np.where(row_max > 0, row_max, 1.0)) < 4:
            raise VehicleParamsError(
                "rotors",
                f"vehicle {label}: rotors: this layout cannot make thrust, roll, pitch and yaw torque independently "
                "(rotors on one line, or spins that do not balance); expected a layout a multirotor can fly",
            )
        trim = _trim_thrusts(self)
        if not np.all(np.isfinite(trim)):
            raise VehicleParamsError(
                "rotors",
                f"vehicle {label}: rotors: positions this far apart (arm {self.arm:.3g} m) give no finite hover trim; "
                "expected metres, not kilometres",
            )
        if not np.all(trim > 0):
            outputs = ", ".join(str(int(i) + 1) for i in np.flatnonzero(trim <= 0))
            raise VehicleParamsError(
                "rotors",
                f"vehicle {label}: rotors: holding hover needs a negative thrust on output(s) {outputs} (the centre "
                "of mass lies outside what the rotors can balance); expected the rotors around the centre of mass",
            )

    def __hash__(self) -> int:  # the rotor list hashes as a tuple (a frozen vehicle is a value)
        return hash(
            tuple(
                (f.name, tuple(v) if f.name == "rotors" else v) for f in fields(self) for v in [getattr(self, f.name)]
            )
        )

    @property
    def n_rotors(self) -> int:
        return len(self.rotors)

    @property
    def weight(self) -> float:
        """N."""
        return self.mass * self.gravity

    @property
    def hover_thrust(self) -> float:
        """N per rotor at hover, the weight shared equally (the trim of a balanced layout;
        `hover_thrusts` for any)."""
        return self.weight / self.n_rotors

    @property
    def hover_thrusts(self) -> np.ndarray:
        """(M,) N per rotor that hold hover with zero torque: equal for every balanced layout
        (rotors centred on the centre of mass, spins balanced), the allocation solved otherwise."""
        return _trim_thrusts(self)

    @property
    def balanced(self) -> bool:
        """Every rotor holds the same share of the weight at hover (`hover_thrusts`)."""
        trim = self.hover_thrusts
        return bool(np.all(trim == trim[0]))

    @property
    def hover_omega(self) -> float:
        """rad/s per rotor at hover."""
        return math.sqrt(self.hover_thrust / self.k_f)

    @property
    def hover_command(self) -> float:
        """Normalised rotor speed ω/ω_max at hover, thrust shared equally: the policy's action
        map trims every rotor to it (`core.dynamics.action_to_command`)."""
        return self.hover_omega / self.omega_max

    @property
    def hover_commands(self) -> np.ndarray:
        """(M,) per-rotor ω/ω_max that hold hover with zero torque (`hover_thrusts`); every entry
        equals `hover_command` for a balanced layout."""
        if self.balanced:
            return np.full(self.n_rotors, self.hover_command)
        return np.sqrt(self.hover_thrusts / self.k_f) / self.omega_max

    @property
    def max_thrust(self) -> float:
        """N per rotor at full command."""
        return self.k_f * self.omega_max**2

    @property
    def thrust_to_weight(self) -> float:
        """Total maximum thrust over weight."""
        return self.n_rotors * self.max_thrust / self.weight

    def scaled(self, **scales: float) -> VehicleParams:
        """A copy with named fields multiplied, e.g. `scaled(mass=1.1, k_f=0.95)`; `arm` scales
        the rotor positions with it."""
        known = {f.name for f in fields(self)} - {"name", "rotors"}
        bad = set(scales) - known
        if bad:
            raise ValueError(f"cannot scale {sorted(bad)}; scalable fields are {sorted(known)}")
        new = {k: getattr(self, k) * v for k, v in scales.items()}
        if "arm" in scales:
            s = scales["arm"]
            new["rotors"] = tuple(Rotor(r.x * s, r.y * s, r.spin) for r in self.rotors)
            new["arm"] = None  # derived from the scaled rotors (equal to arm × s to rounding)
        return replace(self, **new)


def checked_motor_tau(value) -> float:
    """The motor time constant `motor_tau` (s) as a float: a finite number ≥ 0, 0 meaning no lag;
    VehicleParamsError naming it otherwise. The one check of it: a VehicleParams, a vehicle file's
    `motor_tau`, the --motor-tau of quad-train and of the simulator, and a SimConfig call it."""
    try:
        v = float(value)
    except OverflowError:  # an integer beyond the float range
        v = math.inf
    if not (math.isfinite(v) and v >= 0):
        raise VehicleParamsError("motor_tau", f"motor_tau = {v!r}: expected a finite number >= 0")
    return v


_ARM_RTOL = 1e-9  # arm against the rotors' mean distance: equal to the digits a file or JSON carries


def _rotor_list(rotors, label: str) -> list[Rotor]:
    """`rotors` (Rotor objects, or tables {x, y, spin} as JSON metadata holds them) as
    a list of NUM_MOTORS Rotors; ValueError naming the rotor otherwise."""
    if isinstance(rotors, (str, bytes, dict)) or not isinstance(rotors, (list, tuple)):
        raise VehicleParamsError(
            "rotors", f"vehicle {label}: rotors: expected a list of rotors, found {type(rotors).__name__}"
        )
    if len(rotors) != NUM_MOTORS:
        raise VehicleParamsError(
            "rotors",
            f"vehicle {label}: rotors: {len(rotors)} rotor(s); expected {NUM_MOTORS} (the policy and the actuator "
            "outputs carry four)",
        )
    out = []
    for i, r in enumerate(rotors, start=1):
        try:
            if isinstance(r, Rotor):
                out.append(r)
            elif isinstance(r, dict) and set(r) == {"x", "y", "spin"}:
                out.append(Rotor(r["x"], r["y"], r["spin"]))
            else:
                keys = sorted(map(str, r))[:5] if isinstance(r, dict) else None
                found = f"a table with keys {keys}" if keys is not None else type(r).__name__
                raise ValueError(f"expected a table with x, y, spin, found {found}")
        except ValueError as e:
            raise VehicleParamsError("rotors", f"vehicle {label}: rotors[{i}]: {e}") from None
    return out


_VEHICLE_LIMITS = {
    # field: (bound, relation). Masses, lengths, inertias, coefficients and speeds are physical
    # magnitudes; a zero drag coefficient or idle speed means "none" (see the field docs); the motor
    # time constant has its own check, `checked_motor_tau`.
    "mass": (0.0, "> 0"),
    "arm": (0.0, "> 0"),
    "ixx": (0.0, "> 0"),
    "iyy": (0.0, "> 0"),
    "izz": (0.0, "> 0"),
    "k_f": (0.0, "> 0"),
    "k_m": (0.0, "> 0"),
    "omega_max": (0.0, "> 0"),
    "drag": (0.0, ">= 0"),
    "gravity": (0.0, "> 0"),
    "omega_min": (0.0, ">= 0"),
    "c_dx": (0.0, ">= 0"),
    "c_dy": (0.0, ">= 0"),
    "c_dz": (0.0, ">= 0"),
    "k_d": (0.0, ">= 0"),
    "k_z": (0.0, ">= 0"),
    "k_h": (0.0, ">= 0"),
    "k_flap": (0.0, ">= 0"),
}

_BATCH_FIELDS = (
    "mass",
    "ixx",
    "iyy",
    "izz",
    "k_f",
    "k_m",
    "arm",
    "omega_max",
    "motor_tau",
    "drag",
    "omega_min",
    "c_dx",
    "c_dy",
    "c_dz",
    "k_d",
    "k_z",
    "k_h",
    "k_flap",
)


def unit_layout(vehicle: VehicleParams) -> tuple[tuple[float, float, float], ...]:
    """The vehicle's rotors as (x/arm, y/arm, spin sign) rows in body FLU (`flu_layout` over its
    arm): the shape of the layout, which a `ParamBatch` scales per drone by its `arm`."""
    lay = flu_layout(vehicle.rotors)
    return tuple((float(x / vehicle.arm), float(y / vehicle.arm), float(s)) for x, y, s in lay)


_CHECKED_LAYOUTS: set = set()  # layouts already checked (a randomised batch is remade at every reset)


def _checked_layout(layout) -> tuple[tuple[float, float, float], ...]:
    lay = np.asarray(layout, dtype=np.float64)
    if lay.ndim != 2 or lay.shape[1] != 3 or lay.shape[0] < 1 or not np.isfinite(lay).all():
        raise ValueError(f"layout: expected (x/arm, y/arm, spin) rows for each rotor, got shape {lay.shape}")
    if not np.all(np.abs(lay[:, 2]) == 1.0):
        raise ValueError(f"layout: spin signs must be +1 or -1, got {lay[:, 2].tolist()}")
    out = tuple(tuple(float(v) for v in row) for row in lay)
    if len(_CHECKED_LAYOUTS) < 256:
        _CHECKED_LAYOUTS.add(out)
    return out


QUAD_X_UNIT = unit_layout(VehicleParams("quad_x", 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.01, 1.0))
"""`unit_layout` of PX4's quad-X (`quad_x`): rotors at (±1/√2, ±1/√2) in FLU."""


@dataclass(frozen=True)
class ParamBatch:
    """Physical parameters of N drones, each field an array of shape (N,), and one rotor layout.

    Build with `ParamBatch.from_preset(preset, n)`; randomise per drone with `with_entries`
    (`core.randomization`). The arrays are read-only copies: `core.dynamics` caches constants
    derived from them on the batch object, so a batch must never change in place; a changed batch
    is a new object, with an empty cache.

    The rotor layout is shared by the batch and scaled per drone: rotor i of drone j sits at
    arm[j]·(layout[i][0], layout[i][1]) in body FLU (`unit_layout`), so a per-drone `arm` stretches
    or shrinks the whole frame as the one `arm` of a quad-X did.
    """

    mass: np.ndarray
    ixx: np.ndarray
    iyy: np.ndarray
    izz: np.ndarray
    k_f: np.ndarray
    k_m: np.ndarray
    arm: np.ndarray
    omega_max: np.ndarray
    motor_tau: np.ndarray
    drag: np.ndarray
    gravity: float = GRAVITY
    omega_min: np.ndarray | None = None
    """rad/s per drone; None: zeros (no idle speed)."""
    layout: tuple[tuple[float, float, float], ...] = QUAD_X_UNIT
    """Rotors in output order: (x/arm, y/arm, spin sign) in body FLU, spin +1 counter-clockwise
    seen from above (`unit_layout`). Default: PX4's quad-X."""
    c_dx: np.ndarray | None = None
    """N/(m/s)² per drone, quadratic body drag (`VehicleParams.c_dx`); None: zeros, as c_dy, c_dz."""
    c_dy: np.ndarray | None = None
    c_dz: np.ndarray | None = None
    k_d: np.ndarray | None = None
    """Per drone, RotorPy's rotor aerodynamics (`VehicleParams.k_d` ...); None: zeros, as k_z, k_h, k_flap."""
    k_z: np.ndarray | None = None
    k_h: np.ndarray | None = None
    k_flap: np.ndarray | None = None

    def __post_init__(self) -> None:
        for k in ("omega_min", "c_dx", "c_dy", "c_dz", "k_d", "k_z", "k_h", "k_flap"):
            if getattr(self, k) is None:
                object.__setattr__(self, k, np.zeros_like(np.asarray(self.mass)))
        for k in _BATCH_FIELDS:
            a = np.array(getattr(self, k), copy=True)
            a.flags.writeable = False  # see the class docstring: the derived-constant cache
            object.__setattr__(self, k, a)
        if self.layout is not QUAD_X_UNIT and not (isinstance(self.layout, tuple) and self.layout in _CHECKED_LAYOUTS):
            object.__setattr__(self, "layout", _checked_layout(self.layout))

    @classmethod
    def from_preset(cls, preset: VehicleParams, n: int, dtype=np.float64) -> ParamBatch:
        if n < 1:
            raise ValueError(f"need at least one drone, got n={n}")
        values = {k: np.full(n, getattr(preset, k), dtype=dtype) for k in _BATCH_FIELDS}
        return cls(**values, gravity=preset.gravity, layout=unit_layout(preset))

    @property
    def n(self) -> int:
        return int(self.mass.shape[0])

    @property
    def n_rotors(self) -> int:
        return len(self.layout)

    def subset(self, idx) -> ParamBatch:
        """Parameters of the drones selected by `idx` (index array or boolean mask)."""
        return replace(self, **{k: getattr(self, k)[idx] for k in _BATCH_FIELDS})

    def astype(self, dtype) -> ParamBatch:
        return replace(self, **{k: getattr(self, k).astype(dtype) for k in _BATCH_FIELDS})

    def with_entries(self, idx, **values) -> ParamBatch:
        """A new batch whose drones `idx` (index array or boolean mask) get `values` for the named
        fields (scalars or arrays matching `idx`, cast to each field's dtype); this one is left as
        it is. Being a new object, it carries none of the constants `core.dynamics` derived and
        cached for this one."""
        bad = set(values) - set(_BATCH_FIELDS)
        if bad:
            raise ValueError(f"no per-drone field(s) {sorted(bad)}; fields are {list(_BATCH_FIELDS)}")
        new = {}
        for k, v in values.items():
            a = getattr(self, k).copy()
            a[idx] = v
            new[k] = a
        return replace(self, **new)
