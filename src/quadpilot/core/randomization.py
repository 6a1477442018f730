"""Domain randomisation: a randomised plant and random disturbances per drone and per episode.

One code path for training and evaluation: `ParamBatch` already holds every physical parameter per
drone, so randomising an episode means new entries for the drones being reset
(`ParamBatch.with_entries`). That returns a new batch object, and `core.dynamics` caches its derived
constants on the batch object, so the next step derives them afresh; the old batch is untouched.
Wind and pushes become the external force and moment that `core.dynamics.step` takes.

Wind acts as in the SITL simulator (`simulator.Plant`): through linear drag on the
air-relative velocity, F = drag·(wind − v). `core.dynamics` applies −drag·v (`ParamBatch.drag`);
the constant drag·wind is the external force here.

The policy sees none of this (its observation is unchanged) and its motor map keeps the nominal
hover command: it has to cope with a vehicle heavier or weaker than it believes, as a deployed
controller must (Tobin et al. 2017, "Domain randomization for transferring deep neural networks
from simulation to the real world"; Molchanov et al. 2019, "Sim-to-(multi)-real: transfer of
low-level robust control policies to multiple quadrotors", which randomised mass, inertia, thrust
and motor lag of quadrotors in much this way).

NumPy only; randomness comes in as an `np.random.Generator`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .params import GRAVITY, ParamBatch, VehicleParams
from .vehicle_file import SEED_VEHICLE

Range = tuple[float, float]

_SCALE_FIELDS = ("mass", "inertia", "k_f", "k_m")


@dataclass(frozen=True)
class RandomizationConfig:
    """Ranges of the per-episode randomisation, each drawn uniformly and independently per drone
    at every reset. A range (a, a) fixes a value (an evaluation grid cell). Defaults: the `default`
    preset for the seed vehicle."""

    name: str = "custom"
    """Preset this came from (`PRESETS`), or custom."""
    mass: Range = (0.8, 1.2)
    """× the nominal mass."""
    inertia: Range = (0.8, 1.2)
    """× the nominal ixx, iyy and izz, each axis drawn separately."""
    k_f: Range = (0.9, 1.1)
    """× the nominal rotor thrust coefficient k_f (all four rotors alike)."""
    k_m: Range = (0.9, 1.1)
    """× the nominal yaw torque coefficient k_m."""
    motor_tau: Range = (0.0, 0.03)
    """s, first-order motor time constant (absolute, replaces the preset's)."""
    wind_speed: Range = (0.0, 1.5)
    """m/s, constant horizontal wind for the episode; it acts through `drag`."""
    wind_direction_deg: float | None = None
    """deg, direction the wind blows towards, counter-clockwise from +x (east); None: uniform."""
    drag: Range | None = (0.1, 0.3)
    """N·s/m, linear drag coefficient, F = drag·(wind − v) (absolute, replaces the preset's);
    None: the preset's. quad-sitl uses 0.2 when there is wind (`simulator.DEFAULT_WIND_DRAG`)."""
    push_prob: float = 0.0
    """Probability that an episode has one push: a constant force and moment of random direction
    over a random interval."""
    push_force: Range = (0.0, 1.0)
    """N, magnitude of the push force (direction uniform on the sphere, world frame)."""
    push_torque: Range = (0.0, 0.0)
    """N·m, magnitude of the push moment (direction uniform on the sphere, body frame)."""
    push_duration: Range = (0.1, 0.3)
    """s, length of the push; it starts at a uniform time within the episode."""
    airframes: bool = False
    """Draw a whole airframe per episode (`AIRFRAMES`, `draw_airframes`) in place of the nominal
    vehicle: what its vehicle file would say. The motor map then uses that airframe's hover command,
    and the scales above (mass, inertia, k_f, k_m) make the true plant differ from its file, as a
    file that is wrong does; `motor_tau` is drawn as it is; `drag` is per kilogram of the drawn
    mass (1/s), and `push_force` per kilogram (m/s²) and `push_torque` per kg·m² of its roll inertia
    (rad/s²). The rotor layout stays the nominal's, scaled by the drawn arm."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name in ("name", "push_prob", "wind_direction_deg", "airframes") or (f.name == "drag" and v is None):
                continue
            if not (isinstance(v, (tuple, list)) and len(v) == 2 and all(math.isfinite(float(x)) for x in v)):
                raise ValueError(f"randomization {f.name} must be a (low, high) pair of finite numbers, got {v!r}")
            lo, hi = float(v[0]), float(v[1])
            if lo > hi:
                raise ValueError(f"randomization {f.name}: low {lo} > high {hi}")
            floor = 0.0 if f.name not in _SCALE_FIELDS else 1e-9
            if lo < floor:
                what = "scales must be > 0" if f.name in _SCALE_FIELDS else "values must be ≥ 0"
                raise ValueError(f"randomization {f.name}: {what}, got {v!r}")
            object.__setattr__(self, f.name, (lo, hi))
        if not 0.0 <= self.push_prob <= 1.0:
            raise ValueError(f"randomization push_prob must be in [0, 1], got {self.push_prob!r}")
        if self.wind_direction_deg is not None and not math.isfinite(self.wind_direction_deg):
            raise ValueError(
                f"randomization wind_direction_deg must be finite or None, got {self.wind_direction_deg!r}"
            )

    @property
    def has_wind(self) -> bool:
        return self.wind_speed[1] > 0.0

    @property
    def has_push(self) -> bool:
        return self.push_prob > 0.0 and (self.push_force[1] > 0.0 or self.push_torque[1] > 0.0)

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> RandomizationConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown randomization field(s) {sorted(unknown)}; known: {sorted(known)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

    @classmethod
    def fixed(
        cls,
        mass: float = 1.0,
        inertia: float = 1.0,
        k_f: float = 1.0,
        k_m: float = 1.0,
        motor_tau: float = 0.0,
        wind: float = 0.0,
        wind_direction_deg: float | None = 0.0,
        drag: float | None = None,
        name: str = "fixed",
    ) -> RandomizationConfig:
        """One perturbed plant, the same for every drone (an evaluation cell): scales of the
        nominal mass, inertia, k_f and k_m; motor_tau in s; wind in m/s towards
        `wind_direction_deg`; drag in N·s/m (None: the preset's). No pushes."""
        return cls(
            name=name,
            mass=(mass, mass),
            inertia=(inertia, inertia),
            k_f=(k_f, k_f),
            k_m=(k_m, k_m),
            motor_tau=(motor_tau, motor_tau),
            wind_speed=(wind, wind),
            wind_direction_deg=wind_direction_deg,
            drag=None if drag is None else (drag, drag),
            push_prob=0.0,
        )


# Presets for the seed vehicle; `preset(name, vehicle)` scales the absolute forces to another one.
PRESETS: dict[str, RandomizationConfig] = {
    # mass ±20 %, inertia ±20 %, k_f ±10 %, k_m ±10 %, motor lag 0–30 ms, wind up to 1.5 m/s
    # through 0.1–0.3 N·s/m of drag (0.3 N at most on the 0.665 kg vehicle, about 5 % of its weight)
    "default": RandomizationConfig(name="default"),
    # the vehicle's parameters only: no wind, the preset's drag
    "params": RandomizationConfig(name="params", wind_speed=(0.0, 0.0), drag=None),
    # default plus, in half the episodes, one push of up to 1.5 N and 0.01 N·m for 0.1–0.3 s
    "pushes": RandomizationConfig(name="pushes", push_prob=0.5, push_force=(0.0, 1.5), push_torque=(0.0, 0.01)),
    # a new airframe every episode (AIRFRAMES), its file wrong by mass ±30 %, inertia ±20 %, k_f ±20 %
    # and k_m ±10 % (the errors the airframe benchmark flies), motor lag 0–150 ms, wind up to 2 m/s
    # through 0.05–0.3 N·s/m per kg, and in a third of the episodes a push of up to 3 m/s² and 30 rad/s²
    "airframes": RandomizationConfig(
        name="airframes",
        airframes=True,
        mass=(0.7, 1.3),
        k_f=(0.8, 1.2),
        motor_tau=(0.0, 0.15),
        wind_speed=(0.0, 2.0),
        drag=(0.05, 0.3),
        push_prob=0.3,
        push_force=(0.0, 3.0),
        push_torque=(0.0, 30.0),
    ),
}


@dataclass(frozen=True)
class AirframeRanges:
    """The airframes `draw_airframes` draws from: quad-X vehicles from a 25 g micro to a 3 kg camera
    quad, each value uniform in its range (the mass log-uniform) and the rest scaled from it. The
    ranges hold the masses, inertia shapes, yaw inertias and yaw torques of the ten airframes of the
    benchmark (Crazyflie 2.1 to the 2.5 kg X500), though not every value of theirs (the arm, the
    thrust-to-weight and omega_max: see there and docs/raptor.md); none of them is drawn as such."""

    mass: Range = (0.025, 3.0)
    """kg, drawn log-uniformly."""
    arm: Range = (0.7, 1.5)
    """× 0.046 m·(mass / 0.03 kg)^(1/3), the arm of a frame whose size grows as its mass's cube
    root, through the Crazyflie 2.1's 46 mm at 30 g. The set's arms sit between 0.82 and 1.45 of it
    but for PX4 SIH's quad-X, 1.62; what the arm acts through, the angular acceleration per unit of
    differential action (arm·weight/(4√2·ixx)), is 16.7 rad/s² for it, above 1 % of the draws."""
    inertia: Range = (0.15, 0.5)
    """ixx = iyy = c·mass·arm²; the set's c lies between 0.18 (X500) and 0.43 (PX4 SIH quad-X)."""
    yaw_inertia: Range = (1.15, 2.1)
    """izz / ixx; the set's lie between 1.2 (PX4 SIH quad-X) and 2.0 (Crazyflie)."""
    thrust_to_weight: Range = (1.5, 4.0)
    """Full thrust over weight (the action's 2× hover ceiling makes more than 2 matter little)."""
    omega_max: Range = (800.0, 3000.0)
    """rad/s at full command; k_f follows from it and the thrust-to-weight ratio."""
    k_m: Range = (0.006, 0.04)
    """m, yaw torque per newton of thrust; the set's lie between 0.0083 and 0.034."""


AIRFRAMES = AirframeRanges()


def draw_airframes(
    rng: np.random.Generator, k: int, ranges: AirframeRanges = AIRFRAMES, gravity: float = GRAVITY
) -> dict:
    """k airframes as per-drone ParamBatch values (mass, arm, ixx, iyy, izz, k_f, k_m, omega_max;
    the motor lag and drag are the randomisation's). Draws in a fixed order from `rng`."""
    r = ranges
    u = lambda pair: rng.uniform(pair[0], pair[1], k)  # noqa: E731
    mass = np.exp(u((math.log(r.mass[0]), math.log(r.mass[1]))))
    arm = 0.046 * np.cbrt(mass / 0.03) * u(r.arm)
    ixx = u(r.inertia) * mass * arm**2
    izz = ixx * u(r.yaw_inertia)
    omega_max = u(r.omega_max)
    k_f = u(r.thrust_to_weight) * mass * gravity / (4.0 * omega_max**2)
    return {
        "mass": mass,
        "arm": arm,
        "ixx": ixx,
        "iyy": ixx.copy(),
        "izz": izz,
        "k_f": k_f,
        "k_m": u(r.k_m),
        "omega_max": omega_max,
    }


def preset(name: str, vehicle: VehicleParams = SEED_VEHICLE) -> RandomizationConfig:
    """The preset `name` for `vehicle`: relative ranges as they are, drag and push force scaled
    with the vehicle's mass and push moment with its roll inertia (relative to the seed vehicle),
    so that a Crazyflie gets the same accelerations and not a 1 N push (38 times its weight)."""
    try:
        cfg = PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown randomization preset {name!r}; known presets: {sorted(PRESETS)}") from None
    if cfg.airframes or (vehicle.mass == SEED_VEHICLE.mass and vehicle.ixx == SEED_VEHICLE.ixx):
        return cfg  # drawn airframes: their forces are per kilogram of each already
    m, j = vehicle.mass / SEED_VEHICLE.mass, vehicle.ixx / SEED_VEHICLE.ixx
    scale = lambda r, s: None if r is None else (r[0] * s, r[1] * s)  # noqa: E731
    return dataclasses.replace(
        cfg, drag=scale(cfg.drag, m), push_force=scale(cfg.push_force, m), push_torque=scale(cfg.push_torque, j)
    )


class Randomizer:
    """The randomised plants and disturbances of N drones.

    `resample(params, idx, rng, episode_steps)` draws new values for the drones `idx` (at their
    reset) and returns the new ParamBatch; `external(steps)` gives the (force, torque) to hand to
    `core.dynamics.step` at each drone's step count within its episode, None for a part that is
    zero by construction (so a plant without wind or pushes steps bit for bit like a plain one).
    """

    STATE = ("wind", "wind_force", "push_force", "push_torque", "push_start", "push_end", "u_hover")

    def __init__(self, cfg: RandomizationConfig, nominal: VehicleParams, n: int, dt: float, dtype=np.float32) -> None:
        if cfg.has_wind and cfg.drag is None and nominal.drag == 0.0:
            raise ValueError(
                "randomization: wind acts through linear drag, and neither the randomization (drag=None) nor the "
                f"vehicle {nominal.name!r} (drag 0) gives any; set a drag range"
            )
        self.cfg, self.nominal, self.n, self.dt = cfg, nominal, n, dt
        self.dtype = np.dtype(dtype)
        self.wind = np.zeros((n, 3))  # m/s, world ENU
        self.wind_force = np.zeros((n, 3), self.dtype)  # N, drag·wind
        self.push_force = np.zeros((n, 3), self.dtype)  # N, world ENU
        self.push_torque = np.zeros((n, 3), self.dtype)  # N·m, body FLU
        self.push_start = np.zeros(n, np.int64)  # step of the episode at which the push starts
        self.push_end = np.zeros(n, np.int64)  # first step without it (start == end: no push)
        # with `airframes`: each drone's hover command as its (drawn) vehicle file gives it; the
        # environment's motor map reads this array, so it is only ever written in place
        self.u_hover = np.full(n, nominal.hover_command, self.dtype)

    def resample(self, params: ParamBatch, idx: np.ndarray, rng: np.random.Generator, episode_steps: int) -> ParamBatch:
        """New plants and disturbances for the drones `idx` (int array); returns the new batch.
        Draws in a fixed order from `rng`, so the same seed gives the same plants."""
        c, nom = self.cfg, self.nominal
        idx = np.asarray(idx)
        k = idx.size
        u = lambda r, shape=k: rng.uniform(r[0], r[1], shape)  # noqa: E731
        if c.airframes:  # what each drone's vehicle file says; the scales below make it wrong
            file = draw_airframes(rng, k, gravity=nom.gravity)
            self.u_hover[idx] = np.sqrt(file["mass"] * nom.gravity / nom.n_rotors / file["k_f"]) / file["omega_max"]
        else:
            file = {f: np.full(k, getattr(nom, f)) for f in ("mass", "ixx", "iyy", "izz", "k_f", "k_m")}
        inertia = u(c.inertia, (k, 3))
        values = {
            **file,
            "mass": file["mass"] * u(c.mass),
            "ixx": file["ixx"] * inertia[:, 0],
            "iyy": file["iyy"] * inertia[:, 1],
            "izz": file["izz"] * inertia[:, 2],
            "k_f": file["k_f"] * u(c.k_f),
            "k_m": file["k_m"] * u(c.k_m),
            "motor_tau": u(c.motor_tau),
        }
        if c.drag is not None:
            values["drag"] = u(c.drag) * (file["mass"] if c.airframes else 1.0)
        drag = values.get("drag", np.full(k, nom.drag))
        if c.has_wind:
            speed = u(c.wind_speed)
            if c.wind_direction_deg is None:
                heading = rng.uniform(-math.pi, math.pi, k)
            else:
                heading = np.full(k, math.radians(c.wind_direction_deg))
            wind = np.stack([speed * np.cos(heading), speed * np.sin(heading), np.zeros(k)], axis=1)
            self.wind[idx] = wind
            self.wind_force[idx] = drag[:, None] * wind
        if c.has_push:
            on = rng.random(k) < c.push_prob
            length = np.maximum(1, np.round(u(c.push_duration) / self.dt)).astype(np.int64)
            start = rng.integers(0, episode_steps, k)
            self.push_start[idx] = start
            self.push_end[idx] = np.where(on, start + length, start)
            per_force = file["mass"] if c.airframes else 1.0
            per_torque = file["ixx"] if c.airframes else 1.0
            self.push_force[idx] = _directions(rng, k) * (u(c.push_force) * per_force)[:, None]
            self.push_torque[idx] = _directions(rng, k) * (u(c.push_torque) * per_torque)[:, None]
        return params.with_entries(idx, **values)

    def external(self, steps: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(force (N, 3) N world, torque (N, 3) N·m body) for each drone at step `steps` (N,) of
        its episode (0 for the first step after a reset)."""
        force = self.wind_force if self.cfg.has_wind else None
        torque = None
        if self.cfg.has_push:
            active = (steps >= self.push_start) & (steps < self.push_end)
            if active.any():
                on = active[:, None].astype(self.dtype)
                force = on * self.push_force if force is None else force + on * self.push_force
                torque = on * self.push_torque
        return force, torque

    def _keys(self) -> tuple[str, ...]:
        """What a checkpoint holds: the hover commands only for drawn airframes (they are the
        nominal's otherwise), so a plain randomised run's checkpoint is what it always was."""
        return self.STATE if self.cfg.airframes else tuple(k for k in self.STATE if k != "u_hover")

    def state_dict(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k).copy() for k in self._keys()}

    def load_state_dict(self, state: dict) -> None:
        for k in self._keys():
            want = getattr(self, k)
            got = np.asarray(state[k])
            if got.shape != want.shape:
                raise ValueError(f"randomizer state {k!r} has shape {got.shape}, expected {want.shape}")
            want[...] = got.astype(want.dtype)  # in place: the environment's motor map holds `u_hover`


def _directions(rng: np.random.Generator, k: int) -> np.ndarray:
    """(k, 3) unit vectors uniform on the sphere."""
    v = rng.normal(size=(k, 3))
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
