"""Sensor models of the simulator: IMU, magnetometer, barometer. The IMU's noise (and the state
estimate's) is `quadpilot.core.sensor_noise`, the model the training environments use.
`Sensors` reads all of them for one step of one episode (`Reading`).

All vectors are in the project's frames (world ENU, body FLU, SI units); `quadpilot.link.wire`
turns them into HIL_SENSOR's FRD fields.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from quadpilot.core.frames import euler_to_rotmat, rotation_entries
from quadpilot.core.params import flu_layout
from quadpilot.core.rotor_aero import rotor_aero_wrench
from quadpilot.core.sensor_noise import ADIS16448, SensorNoise, SensorNoiseState
from quadpilot.core.state import PITCH, RATES, ROLL, VEL, YAW, Z

from .single_step import TRIG_AGREES

MAG_NED_GAUSS = (0.214, 0.012, 0.433)
"""gauss, Earth's field (north, east, down) at PX4's default SITL home (Zürich, 47.40° N 8.55° E):
approximately what the World Magnetic Model gives there (total ≈ 48 µT, inclination ≈ 64°,
declination ≈ 3° east), rounded. PX4 checks the measured field's direction and strength against its
own WMM tables (PX4-Autopilot src/lib/world_magnetic_model), so a much different value would raise
its magnetometer consistency warnings. The field is constant: it does not follow `Home`."""

# White-noise densities of an ADIS16448 IMU, the defaults of PX4's Gazebo IMU plugin, which turns a
# density into a per-sample standard deviation as density / √dt: `core.sensor_noise.ADIS16448`
# (with its bias model) is the one source; these names are kept for readers of this module.
GYRO_NOISE_DENSITY = ADIS16448.gyro_noise_density
"""rad/s/√Hz, gyroscope white noise (≈ 3.39e-4; 3.4e-3 rad/s per sample at 100 Hz)."""
ACCEL_NOISE_DENSITY = ADIS16448.accel_noise_density
"""m/s²/√Hz, accelerometer white noise (0.04 m/s² per sample at 100 Hz)."""

# International Standard Atmosphere, troposphere (ICAO Doc 7488 / ISO 2533), geopotential ≈
# geometric altitude at these heights.
ISA_P0_PA = 101_325.0  # Pa, sea-level pressure
ISA_T0_K = 288.15  # K, sea-level temperature
ISA_LAPSE_K_PER_M = 0.0065  # K/m, temperature lapse rate
ISA_EXPONENT = 5.25588  # g0·M/(R·L), dimensionless
ISA_MIN_ALT_M = -2_000.0
"""m, lowest altitude of the ISA tables (ISO 2533 starts them at −2 km geopotential)."""
ISA_TROPOPAUSE_M = 11_000.0
"""m, top of the troposphere layer, where the lapse-rate formula ends (ISO 2533)."""


def _isa_altitude(alt_msl_m: float) -> float:
    """The altitude clipped to the troposphere layer the formulas hold in. Beyond it the barometer
    reads the layer's edge, as a saturated sensor would: no multirotor of ours gets there except by
    a runaway climb or fall, and the unclipped formula is no atmosphere there (above ~44 km its base
    turns negative and the pressure complex)."""
    return min(max(float(alt_msl_m), ISA_MIN_ALT_M), ISA_TROPOPAUSE_M)


def isa_pressure_hpa(alt_msl_m: float) -> float:
    """Static pressure in hPa at an altitude above mean sea level (ISA troposphere; altitudes
    outside −2 km … 11 km read as the nearest edge)."""
    alt = _isa_altitude(alt_msl_m)
    return ISA_P0_PA * (1.0 - ISA_LAPSE_K_PER_M * alt / ISA_T0_K) ** ISA_EXPONENT / 100.0


def isa_temperature_c(alt_msl_m: float) -> float:
    """Air temperature in °C at an altitude above mean sea level (ISA troposphere, clipped as
    `isa_pressure_hpa`)."""
    return ISA_T0_K - ISA_LAPSE_K_PER_M * _isa_altitude(alt_msl_m) - 273.15


def rotation(state: np.ndarray) -> np.ndarray:
    """The body → world rotation (3, 3) of a 12-state: `core.frames.euler_to_rotmat` of its angles,
    as `core.frames.rotation_entries` on math's sin and cos (the same bits, with
    `single_step.TRIG_AGREES`; else that function itself), without NumPy's per-call overhead on one
    state: this runs every simulation step."""
    roll, pitch, yaw = float(state[ROLL]), float(state[PITCH]), float(state[YAW])
    if not (TRIG_AGREES and math.isfinite(roll) and math.isfinite(pitch) and math.isfinite(yaw)):
        return euler_to_rotmat(roll, pitch, yaw)
    return np.array(rotation_entries(math.sin, math.cos, roll, pitch, yaw))


def world_to_body(state: np.ndarray, v_world, rot: np.ndarray | None = None) -> np.ndarray:
    """A world ENU vector (3,) in the body FLU frame of a 12-state: Rᵀ·v (`rot`: its R, if known)."""
    r = rotation(state) if rot is None else rot
    return r.T @ np.asarray(v_world, np.float64)


_MAG_ENU = np.array((MAG_NED_GAUSS[1], MAG_NED_GAUSS[0], -MAG_NED_GAUSS[2]))  # NED → ENU, made once


def magnetometer_flu(state: np.ndarray, field_ned=MAG_NED_GAUSS, rot: np.ndarray | None = None) -> np.ndarray:
    """The Earth field (gauss) measured in the body FLU frame of a 12-state (`rot`: its R, if known)."""
    if field_ned is MAG_NED_GAUSS:
        v = _MAG_ENU
    else:
        n, e, d = field_ned
        v = (e, n, -d)  # NED → ENU
    return world_to_body(state, v, rot)


def specific_force_flu(
    state: np.ndarray, thrust_n: float, mass: float, drag: float, wind_enu, contact_enu=None, rot=None
) -> np.ndarray:
    """What an accelerometer measures, m/s² in body FLU: the non-gravitational force over mass.
    Rotor thrust acts along body +z; air drag, drag·(wind − v), acts in the world frame, and so does
    the ground's force over mass, `contact_enu` (m/s², None: not touching it). Hovering, or at rest
    on the ground, it is (0, 0, +g); in free fall, zero. `rot`: the state's R, if known."""
    f = np.array([0.0, 0.0, thrust_n / mass])
    if drag:
        f += world_to_body(state, drag * (np.asarray(wind_enu, np.float64) - state[VEL]) / mass, rot)
    if contact_enu is not None:
        f += world_to_body(state, contact_enu, rot)
    return f


def air_force_flu(state: np.ndarray, rotor: np.ndarray, vehicle, wind_enu, rot=None) -> np.ndarray:
    """m/s², body FLU: RotorPy's parasitic drag, −|v_a|·diag(c_dx, c_dy, c_dz)·v_a, and rotor
    aerodynamics' force (`core.rotor_aero`, rotors at `rotor` ω/ω_max), over the mass, on the body
    airspeed v_a = Rᵀ(v − wind) (`core.dynamics`, module docstring): forces on the airframe, so the
    accelerometer measures them. `rot`: the state's R, if known."""
    air = world_to_body(state, state[VEL] - np.asarray(wind_enu, np.float64), rot)
    c = np.array([vehicle.c_dx, vehicle.c_dy, vehicle.c_dz])
    force = -float(np.linalg.norm(air)) * c * air
    if vehicle.k_d or vehicle.k_z or vehicle.k_h or vehicle.k_flap:
        lay = flu_layout(vehicle.rotors)
        col = lambda a: np.asarray(a, np.float64).reshape(-1, 1)  # noqa: E731
        aero, _ = rotor_aero_wrench(
            air[:, None],
            col(state[RATES]),
            col(np.asarray(rotor) * vehicle.omega_max),
            col(lay[:, 0]),
            col(lay[:, 1]),
            *(np.array([getattr(vehicle, k)]) for k in ("k_d", "k_z", "k_h", "k_flap")),
        )
        force = force + aero[:, 0]
    return force / vehicle.mass


class Reading(NamedTuple):
    """What the sensors measure at one step (body FLU, SI; the barometer in hPa at `alt_m` MSL)."""

    gyro: np.ndarray
    """(3,) rad/s, body rates (with IMU noise when it is on)."""
    accel: np.ndarray
    """(3,) m/s², specific force (with IMU noise when it is on)."""
    mag: np.ndarray
    """(3,) gauss."""
    pressure_hpa: float
    alt_m: float
    """m above mean sea level."""
    temperature_c: float
    estimate: np.ndarray | None
    """The state as an estimator would report it (12-state), with estimator noise only; else None."""


class Sensors:
    """The sensors of one episode: `core.sensor_noise`'s IMU and estimator processes when `spec` has
    them (drawn from `rng`, which the episode's start state came from), on the ideal readings of
    this module's models. `imu` and `estimator` say which parts are in force."""

    def __init__(
        self,
        spec: SensorNoise | None,
        dt: float,
        rng: np.random.Generator,
        home_alt_m: float,
        imu: bool,
        estimator: bool,
    ) -> None:
        self.imu, self.estimator, self.home_alt_m = imu, estimator, home_alt_m
        self.noise = None if spec is None else SensorNoiseState(spec, 1, dt, rng)
        self.variances: tuple[list[float], list[float]] | None = None
        if self.noise is not None:
            self.noise.reset()
            self.variances = estimate_variances(spec, dt) if spec.estimator is not None else None

    def read(self, state: np.ndarray, specific_force: np.ndarray, n: int, rot: np.ndarray | None = None) -> Reading:
        """Step `n`'s reading of the 12-state `state` whose ideal accelerometer reads `specific_force`
        (`rot`: the state's body → world rotation, if known: `rotation(state)`)."""
        gyro, accel, estimate = state[RATES].copy(), specific_force, None
        noise = self.noise
        if noise is not None:  # core.sensor_noise, as in training: advance one dt, then measure
            if n > 0:
                noise.step()
            if self.imu:
                gyro, accel = noise.gyro(gyro[None])[0], noise.accel(accel[None])[0]
            if self.estimator:
                estimate = noise.estimate(state[None])[0]
        alt = self.home_alt_m + float(state[Z])
        return Reading(
            gyro, accel, magnetometer_flu(state, rot=rot), isa_pressure_hpa(alt), alt, isa_temperature_c(alt), estimate
        )


def estimate_variances(spec: SensorNoise, dt: float) -> tuple[list[float], list[float]]:
    """Stationary variances of the estimate (pose x, y, z, roll, pitch, yaw; velocity and rates),
    NED order, for ODOMETRY's covariance diagonals."""
    est, imu = spec.estimator, spec.imu
    p = est.pos_white**2 + est.pos_drift**2
    v = est.vel_white**2 + est.vel_drift**2
    g = (imu.gyro_noise_density**2 / dt + imu.gyro_turn_on_bias**2) if imu else 0.0
    return [p, p, p, est.tilt_drift**2, est.tilt_drift**2, est.yaw_drift**2], [v, v, v, g, g, g]
