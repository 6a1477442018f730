"""Vehicle parameters: airframe presets and per-drone parameter batches.

A preset (`VehicleParams`) is one airframe, scalars with their unit and source on the same line.
Every VehicleParams checks its numbers when it is made (a preset, a scaled or replaced copy, one read
from a checkpoint or from an ONNX file's metadata): each one number, finite, positive (motor_tau
and drag may be 0); anything else is a ValueError naming the field, its value and what was expected.
`ParamBatch` holds the same quantities as arrays of shape (N,) so that one dynamics call steps N
drones that may each differ (domain randomisation needs no other code path).

The presets are also shipped as vehicle files, `quadpilot/vehicles/<name>.toml` (`core.vehicle_file`
reads them and users' files alike); tests/core/test_vehicle_files.py holds the two equal, field by
field, so a change here needs the same change there.

Motor numbering is PX4's quad-X order (see `MOTOR_LAYOUT` in `dynamics`): 0 front-right (CCW),
1 rear-left (CCW), 2 front-left (CW), 3 rear-right (CW).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields, replace

import numpy as np

GRAVITY = 9.81  # m/s^2, standard gravity rounded as in seed 000/001


@dataclass(frozen=True)
class VehicleParams:
    """One airframe. Every field: unit, then where the number comes from."""

    name: str
    """Preset name, as given to `get_preset`."""
    mass: float
    """kg."""
    arm: float
    """m, distance from the centre of mass to each rotor axis."""
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

    def __post_init__(self) -> None:
        """Every field is checked where a VehicleParams is made (a preset, a scaled copy, a vehicle read
        from a checkpoint or an ONNX file's metadata), so that no code downstream meets a negative mass
        or a NaN: ValueError naming the field, what it holds and what was expected. Numbers are stored
        as Python floats (a NumPy scalar or an int is converted)."""
        if not isinstance(self.name, str):
            raise ValueError(f"vehicle name: expected a string, found {type(self.name).__name__}")
        label = repr(self.name if len(self.name) <= 40 else self.name[:40] + "...")  # repr: one line
        for f in fields(self):
            if f.name == "name":
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
                raise ValueError(f"vehicle {label}: {f.name}: expected one number, found {found}")
            try:
                v = float(v)
            except OverflowError:  # an integer beyond the float range
                v = math.inf
            bound, relation = _VEHICLE_LIMITS[f.name]
            if not (math.isfinite(v) and (v > bound if relation == "> 0" else v >= bound)):
                raise ValueError(f"vehicle {label}: {f.name} = {v!r}: expected a finite number {relation}")
            object.__setattr__(self, f.name, v)

    @property
    def weight(self) -> float:
        """N."""
        return self.mass * self.gravity

    @property
    def hover_thrust(self) -> float:
        """N per rotor at hover."""
        return self.weight / 4.0

    @property
    def hover_omega(self) -> float:
        """rad/s per rotor at hover."""
        return math.sqrt(self.hover_thrust / self.k_f)

    @property
    def hover_command(self) -> float:
        """Normalised rotor speed ω/ω_max at hover."""
        return self.hover_omega / self.omega_max

    @property
    def max_thrust(self) -> float:
        """N per rotor at full command."""
        return self.k_f * self.omega_max**2

    @property
    def thrust_to_weight(self) -> float:
        """Total maximum thrust over weight."""
        return 4.0 * self.max_thrust / self.weight

    def scaled(self, **scales: float) -> VehicleParams:
        """A copy with named fields multiplied, e.g. `scaled(mass=1.1, k_f=0.95)`."""
        known = {f.name for f in fields(self)} - {"name"}
        bad = set(scales) - known
        if bad:
            raise ValueError(f"cannot scale {sorted(bad)}; scalable fields are {sorted(known)}")
        return replace(self, **{k: getattr(self, k) * v for k, v in scales.items()})


_VEHICLE_LIMITS = {
    # field: (bound, relation). Masses, lengths, inertias, coefficients and speeds are physical
    # magnitudes; a zero time constant or drag coefficient means "none" (see the field docs).
    "mass": (0.0, "> 0"),
    "arm": (0.0, "> 0"),
    "ixx": (0.0, "> 0"),
    "iyy": (0.0, "> 0"),
    "izz": (0.0, "> 0"),
    "k_f": (0.0, "> 0"),
    "k_m": (0.0, "> 0"),
    "omega_max": (0.0, "> 0"),
    "motor_tau": (0.0, ">= 0"),
    "drag": (0.0, ">= 0"),
    "gravity": (0.0, "> 0"),
}


# The seed vehicle (seed 001 after Pi et al. 2020): mass, arm and inertia as published.
# The seeds give no rotor data, so the rotor is a 5-inch (0.127 m) propeller, the largest that
# fits an X frame with 0.105 m arms (adjacent rotor axes 0.148 m apart). Static thrust
# coefficient C_T ≈ 0.11 and power coefficient C_P ≈ 0.045 are typical of 5-inch propellers in the
# UIUC Propeller Data Site; with T = C_T·ρ·n²·D⁴ and n = ω/2π:
#   k_f = C_T·ρ·D⁴/(4π²) = 0.11·1.225·0.127⁴/39.48 ≈ 8.9e-7 N/(rad/s)²,
#   k_m = C_P/(2π·C_T)·D ≈ 0.0083 m (yaw torque per newton of thrust).
# omega_max = 2000 rad/s (≈19 100 rpm, a ~1900 KV motor on 3S under load) gives thrust-to-weight
# 2.2, the usual margin for a camera-class quadrotor; hover then sits at ω/ω_max ≈ 0.68.
SEED_VEHICLE = VehicleParams(
    name="seed",
    mass=0.665,  # kg, seed 001 parameter table
    arm=0.105,  # m, seed 001 parameter table
    ixx=0.0023,  # kg·m², seed 001 parameter table
    iyy=0.0025,  # kg·m², seed 001 parameter table
    izz=0.0037,  # kg·m², seed 001 parameter table
    k_f=8.9e-7,  # N/(rad/s)², 5-inch prop, C_T 0.11 (UIUC propeller data), derivation above
    k_m=0.0083,  # m, C_P/(2π·C_T)·D with C_P 0.045, derivation above
    omega_max=2000.0,  # rad/s, thrust-to-weight 2.2, derivation above
)

# Crazyflie 2.x: Förster, "System Identification of the Crazyflie 2.0 Nano Quadrocopter",
# ETH Zurich 2015, as used by gym-pybullet-drones' cf2x.urdf (Panerati et al. 2021).
CRAZYFLIE = VehicleParams(
    name="crazyflie",
    mass=0.027,  # kg, cf2x.urdf (Förster 2015: 0.027 kg without markers)
    arm=0.046,  # m, half the 92 mm motor-to-motor diagonal (Bitcraze CF2.1 datasheet)
    ixx=1.4e-5,  # kg·m², cf2x.urdf (Förster 2015: 1.395e-5)
    iyy=1.4e-5,  # kg·m², cf2x.urdf (Förster 2015: 1.436e-5)
    izz=2.17e-5,  # kg·m², cf2x.urdf (Förster 2015: 2.173e-5)
    k_f=2.88e-8,  # N/(rad/s)², cf2x.urdf kf = 3.16e-10 N/rpm² × (60/2π)²
    k_m=0.0251,  # m, cf2x.urdf km/kf = 7.94e-12/3.16e-10
    omega_max=2274.0,  # rad/s, cf2x.urdf thrust2weight 2.25 → ω_max = ω_hover·√2.25
)

PRESETS: dict[str, VehicleParams] = {p.name: p for p in (SEED_VEHICLE, CRAZYFLIE)}


def get_preset(name: str) -> VehicleParams:
    """The preset called `name`; a clear error names the known ones."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown vehicle preset {name!r}; known presets: {sorted(PRESETS)}") from None


_BATCH_FIELDS = ("mass", "ixx", "iyy", "izz", "k_f", "k_m", "arm", "omega_max", "motor_tau", "drag")


@dataclass(frozen=True)
class ParamBatch:
    """Physical parameters of N drones, each field an array of shape (N,).

    Build with `ParamBatch.from_preset(preset, n)`; randomise per drone with `with_entries`
    (`core.randomization`). The arrays are read-only copies: `core.dynamics` caches constants
    derived from them on the batch object, so a batch must never change in place; a changed batch
    is a new object, with an empty cache.
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

    def __post_init__(self) -> None:
        for k in _BATCH_FIELDS:
            a = np.array(getattr(self, k), copy=True)
            a.flags.writeable = False  # see the class docstring: the derived-constant cache
            object.__setattr__(self, k, a)

    @classmethod
    def from_preset(cls, preset: VehicleParams, n: int, dtype=np.float64) -> ParamBatch:
        if n < 1:
            raise ValueError(f"need at least one drone, got n={n}")
        values = {k: np.full(n, getattr(preset, k), dtype=dtype) for k in _BATCH_FIELDS}
        return cls(**values, gravity=preset.gravity)

    @property
    def n(self) -> int:
        return int(self.mass.shape[0])

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
