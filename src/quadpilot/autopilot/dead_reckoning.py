"""A state estimate from HIL_SENSOR alone, for the time the state stream is silent.

PX4 keeps flying through a lost position estimate because its estimator (EKF2) goes on propagating
attitude, velocity and height from the IMU and the barometer; the node gets the same raw data in
every step's HIL_SENSOR, so it does a small version of the same, started from the last valid state:

- attitude: the gyro integrated on SO(3) (Rodrigues' formula), corrected towards the accelerometer's
  "up" with a small proportional gain (Mahony, Hamel & Pflimlin, "Nonlinear complementary filters
  on the special orthogonal group", IEEE TAC 2008: ω + k·(a × v̂), v̂ = Rᵀe₃), and only while the
  accelerometer reads within `ACCEL_GATE` of 1 g. On a multirotor the specific force points along
  the thrust, so the correction pulls the estimate towards level: right in a hover, which is what
  this estimate is for, and slow enough (1/k ≈ 3 s) not to matter over the seconds it is used;
- height and vertical velocity: the accelerometer in the world frame, less gravity, integrated,
  and pulled towards the barometer's altitude (a second-order complementary filter, natural
  frequency `BARO_OMEGA`), the barometer's offset from the local frame taken when the estimate
  starts. A simulator whose HIL_SENSOR does not flag its barometer as updated (RotorPy 3.0.0 sends
  zeros and flags only the IMU) gets the accelerometer alone;
- horizontal position and velocity: the last state's, propagated with the accelerometer (the caller
  bounds how long it believes them: `autopilot.state_loss`).

Both IMU sensors have biases (a turn-on offset and a slow walk: 20 mg and 0.5 °/s for the ADIS16448
PX4's SITL simulates); levelled on a biased accelerometer, a vehicle that believes itself level drifts
sideways at the bias. So while valid states arrive the node learns the biases, as PX4's EKF2 does
while it has position and velocity aiding (`ImuCalibration`): the gyro against the attitude's change
between two states, the accelerometer against the velocity's change plus gravity, each averaged over
`CALIBRATION_TAU_S`. The estimate subtracts them.

The body rates are the gyro's, as always. An implausible sample (a value that is not finite, or
beyond what any IMU reports) is not used: the last good one is held, and counted. An implausible
estimate (`plausible` False: tilted beyond `MAX_TILT_RAD`, or the barometer and the estimate apart
by more than `MAX_BARO_INNOVATION_M`) is the caller's to act on: it stops believing it and lands.
"""

from __future__ import annotations

import math

import numpy as np

from quadpilot.core.frames import euler_to_rotmat, rotation_entries, rotmat_to_euler
from quadpilot.core.state import PITCH, POS, ROLL, VEL, YAW

ATTITUDE_GAIN = 0.3
"""rad/s per unit of (a × v̂): the accelerometer's pull on the attitude (a time constant of ≈ 3 s)."""
ACCEL_GATE = 0.1
"""The accelerometer corrects the attitude only while |a| is within this fraction of g."""
BARO_OMEGA = 1.5
"""rad/s: natural frequency of the barometer's pull on height and vertical velocity (damping 1)."""
MAX_GYRO = 70.0
"""rad/s: beyond this a gyro sample is a fault (as `runtime.safety.ObservationLimits.rates`)."""
MAX_ACCEL = 16.0 * 9.81
"""m/s²: a ±16 g accelerometer's full scale; beyond it a sample is a fault."""
MAX_TILT_RAD = math.radians(60.0)
"""An estimate tilted further than this is implausible for a vehicle that was hovering."""
MAX_BARO_INNOVATION_M = 3.0
"""m: the barometer and the estimate this far apart: one of them is wrong; the estimate is implausible."""
PRESSURE_ALT_UPDATED = 0x800
"""HIL_SENSOR fields_updated bit of pressure_alt (MAVLink HIL_SENSOR_UPDATED_PRESSURE_ALT)."""


CALIBRATION_TAU_S = 2.0
"""s over which the IMU biases are averaged while states arrive."""
CALIBRATION_MAX_DT_S = 0.05
"""s: two states further apart than this teach nothing (a gap, a dropout)."""


class ImuCalibration:
    """The gyro's and the accelerometer's biases (body FLU), learned from HIL_SENSOR against the states."""

    def __init__(self, gravity: float = 9.81) -> None:
        self.gravity = float(gravity)
        self._gyro_bias = [0.0, 0.0, 0.0]
        self._accel_bias = [0.0, 0.0, 0.0]
        self.samples = 0
        self._prev: tuple | None = None

    @property
    def gyro_bias(self) -> np.ndarray:
        return np.array(self._gyro_bias)

    @property
    def accel_bias(self) -> np.ndarray:
        return np.array(self._accel_bias)

    def update(self, state: list, time_usec: int, msg) -> None:
        """One step with both its state (12 floats, ENU/FLU) and its HIL_SENSOR."""
        rot = rotation_entries(math.sin, math.cos, state[ROLL], state[PITCH], state[YAW])
        vx, vy, vz = state[VEL]
        prev, self._prev = self._prev, (int(time_usec), rot, vx, vy, vz)
        if prev is None:
            return
        dt = (int(time_usec) - prev[0]) * 1e-6
        if not 0.0 < dt <= CALIBRATION_MAX_DT_S:
            return
        gyro = (float(msg.xgyro), -float(msg.ygyro), -float(msg.zgyro))
        acc = (float(msg.xacc), -float(msg.yacc), -float(msg.zacc))
        if not math.isfinite(sum(gyro) + sum(acc)):
            return
        p = prev[1]
        # D = P^T R, the rotation between the two states in the body frame; its skew part / dt is the rate
        d = [[p[0][i] * rot[0][j] + p[1][i] * rot[1][j] + p[2][i] * rot[2][j] for j in range(3)] for i in range(3)]
        h = 0.5 / dt
        rates = ((d[2][1] - d[1][2]) * h, (d[0][2] - d[2][0]) * h, (d[1][0] - d[0][1]) * h)
        fx, fy, fz = (vx - prev[2]) / dt, (vy - prev[3]) / dt, (vz - prev[4]) / dt + self.gravity
        # what an ideal accelerometer reads: R^T f, body frame
        specific = [rot[0][i] * fx + rot[1][i] * fy + rot[2][i] * fz for i in range(3)]
        k = min(1.0, dt / CALIBRATION_TAU_S)
        gb, ab = self._gyro_bias, self._accel_bias
        for i in range(3):
            gb[i] += k * (gyro[i] - rates[i] - gb[i])
            ab[i] += k * (acc[i] - specific[i] - ab[i])
        self.samples += 1


def _rodrigues(w: np.ndarray, dt: float) -> np.ndarray:
    """exp([w·dt]×): the rotation by the angle |w|·dt about w."""
    theta = math.sqrt(float(w @ w)) * dt
    if theta < 1e-12:
        return np.eye(3)
    k = w * (dt / theta)
    kx = np.array(((0.0, -k[2], k[1]), (k[2], 0.0, -k[0]), (-k[1], k[0], 0.0)))
    return np.eye(3) + math.sin(theta) * kx + (1.0 - math.cos(theta)) * (kx @ kx)


def imu_from_hil_sensor(msg) -> tuple[np.ndarray, np.ndarray]:
    """(gyro rad/s, specific force m/s²), body FLU, from a HIL_SENSOR (FRD: y and z times −1)."""
    gyro = np.array((msg.xgyro, -msg.ygyro, -msg.zgyro), np.float64)
    acc = np.array((msg.xacc, -msg.yacc, -msg.zacc), np.float64)
    return gyro, acc


def baro_from_hil_sensor(msg) -> float | None:
    """The barometer's altitude (m MSL), or None when the message does not flag it as updated."""
    if not int(getattr(msg, "fields_updated", 0)) & PRESSURE_ALT_UPDATED:
        return None
    alt = float(msg.pressure_alt)
    return alt if math.isfinite(alt) else None


class InertialEstimate:
    """The 12-state, propagated from a last valid state with the IMU and the barometer."""

    def __init__(
        self,
        state: list,
        time_usec: int,
        gravity: float = 9.81,
        baro_alt: float | None = None,
        calibration: ImuCalibration | None = None,
    ) -> None:
        s = np.asarray(state, np.float64)
        self.gyro_bias = np.zeros(3) if calibration is None else calibration.gyro_bias.copy()
        self.accel_bias = np.zeros(3) if calibration is None else calibration.accel_bias.copy()
        self.rot = euler_to_rotmat(s[ROLL], s[PITCH], s[YAW])
        self.pos = s[POS].copy()
        self.vel = s[VEL].copy()
        self.rates = np.zeros(3)
        self.gravity = float(gravity)
        self.time_usec = int(time_usec)
        self.baro_offset = None if baro_alt is None else baro_alt - float(self.pos[2])
        """m: the barometer's altitude less the local height at the start (None: no barometer yet)."""
        self._gyro = np.zeros(3)
        self._acc = np.array((0.0, 0.0, self.gravity))
        self.bad_samples = 0
        """IMU samples not used (non-finite or beyond full scale): the last good one was held."""
        self.baro_rejected = 0
        self.implausible: str | None = None
        """Why the estimate is no longer believed (None: it is)."""

    @property
    def plausible(self) -> bool:
        return self.implausible is None

    def update(self, msg) -> None:
        """Propagate to this HIL_SENSOR's time with its IMU, then correct with its barometer."""
        t = int(msg.time_usec)
        dt = (t - self.time_usec) * 1e-6
        if dt <= 0.0:
            return
        self.time_usec = t
        gyro, acc = imu_from_hil_sensor(msg)
        gyro, acc = gyro - self.gyro_bias, acc - self.accel_bias
        if (
            np.all(np.isfinite(gyro))
            and np.all(np.isfinite(acc))
            and np.abs(gyro).max() <= MAX_GYRO
            and np.abs(acc).max() <= MAX_ACCEL
        ):
            self._gyro, self._acc = gyro, acc
        else:
            self.bad_samples += 1
        gyro, acc = self._gyro, self._acc
        self.rates = gyro
        # attitude: gyro, plus the accelerometer's pull towards its "up" while it reads about 1 g
        w = gyro.copy()
        a_norm = math.sqrt(float(acc @ acc))
        if abs(a_norm - self.gravity) <= ACCEL_GATE * self.gravity:
            up_measured = acc / a_norm
            up_estimated = self.rot[2]  # Rᵀe₃: the world's up in the body frame
            w += ATTITUDE_GAIN * np.cross(up_measured, up_estimated)
        self.rot = self.rot @ _rodrigues(w, dt)
        u, _, vt = np.linalg.svd(self.rot)  # back onto SO(3): rounding drifts over thousands of steps
        self.rot = u @ vt
        # translation: the specific force in the world, less gravity
        a_world = self.rot @ acc
        a_world[2] -= self.gravity
        self.pos += self.vel * dt + 0.5 * a_world * dt * dt
        self.vel += a_world * dt
        baro = baro_from_hil_sensor(msg)
        if baro is not None:
            if self.baro_offset is None:
                self.baro_offset = baro - float(self.pos[2])
            innovation = baro - self.baro_offset - float(self.pos[2])
            if abs(innovation) > MAX_BARO_INNOVATION_M:
                self.baro_rejected += 1
                self.implausible = self.implausible or f"barometer {innovation:+.1f} m from the estimate"
            else:
                self.pos[2] += 2.0 * BARO_OMEGA * dt * innovation
                self.vel[2] += BARO_OMEGA * BARO_OMEGA * dt * innovation
        tilt = math.acos(max(-1.0, min(1.0, float(self.rot[2, 2]))))
        if tilt > MAX_TILT_RAD:
            self.implausible = self.implausible or f"estimated tilt {math.degrees(tilt):.0f} deg"

    def state(self) -> list:
        """The estimate as the 12-state the node flies on (ENU/FLU, SI), as floats."""
        roll, pitch, yaw = rotmat_to_euler(self.rot)
        return [*self.pos.tolist(), *self.vel.tolist(), float(roll), float(pitch), float(yaw), *self.rates.tolist()]
