"""The MAVLink contract of quadpilot's software-in-the-loop: frames, units and the four messages.

Inside the project: world ENU (z up), body FLU, SI units, the 12-state vector of `core.dynamics`
(x, y, z, vx, vy, vz, roll, pitch, yaw, p, q, r). On the wire, as the MAVLink common message set
and PX4's Simulator MAVLink API define them: local NED, body FRD, positions as WGS-84 latitude and
longitude in 1e-7 degrees and altitude in millimetres, velocities in cm/s. This module (with
`link.frames`, the frame conversions and the local ↔ geodetic map it uses) is the only place the two
meet; everything is tested by round trips with known states.

Messages (https://mavlink.io/en/messages/common.html):
- HIL_STATE_QUATERNION (simulator → autopilot, every step): ground truth. attitude_quaternion
  (w, x, y, z) rotates body FRD into NED; rollspeed/pitchspeed/yawspeed rad/s FRD; lat/lon degE7;
  alt mm (MSL); vx/vy/vz cm/s NED; xacc/yacc/zacc mG.
- HIL_SENSOR (simulator → autopilot, every step, last: PX4 steps on it): IMU in FRD, m/s² and
  rad/s, magnetometer in gauss, barometer hPa.
- HIL_GPS (simulator → autopilot, at a low rate): lat/lon degE7, alt mm, vn/ve/vd cm/s.
- HIL_ACTUATOR_CONTROLS (autopilot → simulator, once per step): controls[0..3] motor commands in
  [0, 1] (normalised rotor speed ω/ω_max, PX4 quad-X order), mode bit 128 = armed
  (MAV_MODE_FLAG_SAFETY_ARMED), flags bit 1 = lockstep (HIL_ACTUATOR_CONTROLS_FLAGS_LOCKSTEP).

Motor order: our model numbers its rotors in PX4's quad-X order already (core.dynamics
MOTOR_LAYOUT: 0 front-right, 1 rear-left, 2 front-left, 3 rear-right), so `MOTOR_MAP` is the
identity; it is kept explicit so that a different airframe changes one line.

Position precision and the local ↔ geodetic map: see `link.frames`.

Integer fields are saturated to their MAVLink type's range in one place (`_saturating`, read from
pymavlink's own message definitions): a long enough fall or climb reaches altitudes whose
millimetres no int32 holds, and pymavlink refuses to pack them (struct.error), which would end the
process that builds the message. A value pinned at its type's limit is still a message.

What arrives is checked before it becomes a state (`BadState`, with a `reason` to count it by):
non-finite values, a quaternion that is zero or not of unit length (MAVLink's attitude quaternions
are unit quaternions; a sender normalises before it sends), and magnitudes no vehicle state can have.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.core.frames import euler_to_rotmat, rotmat_to_euler
from quadpilot.core.params import NUM_MOTORS
from quadpilot.core.state import PITCH, POS, RATES, ROLL, VEL, YAW, Z

# the frames (`link.frames`); the `X as X` ones are not used here, only re-exported: the rest of
# the project reads every conversion of the wire from this module
from .frames import EARTH_RADIUS_M as EARTH_RADIUS_M
from .frames import LAT_QUANTUM_DEG as LAT_QUANTUM_DEG
from .frames import (
    Home,
    enu_to_ned,
    flu_to_frd,
    frd_to_flu,
    local_to_geodetic,
    ned_frd_quaternion,
    quaternion_to_rotmat,
    rotmat_enu_flu_to_ned_frd,
    rotmat_ned_frd_to_enu_flu,
)
from .frames import geodetic_to_local as geodetic_to_local
from .frames import ned_to_enu as ned_to_enu
from .frames import rotmat_to_quaternion as rotmat_to_quaternion
from .saturation import fields_from_args as _fields_of
from .saturation import saturating as _saturating
from .saturation import saturating_args as _saturating_args

G_MG = 9.80665 / 1000.0  # m/s² per milli-g (MAVLink's mG uses standard gravity)
ARMED = 128  # MAV_MODE_FLAG_SAFETY_ARMED, in HIL_ACTUATOR_CONTROLS.mode
LOCKSTEP = 1  # HIL_ACTUATOR_CONTROLS_FLAGS_LOCKSTEP, in HIL_ACTUATOR_CONTROLS.flags
MOTOR_MAP = (0, 1, 2, 3)
"""controls[i] on the wire drives our model's rotor MOTOR_MAP[i] (identity: both are PX4 quad-X)."""
MAX_BODY_RATE = 70.0
"""rad/s, the largest body rate a state may carry: twice the full scale of a 2000 °/s MEMS gyro (the
usual range, e.g. the ADIS16448 and BMI088 of `core.sensor_noise`). The simulator's plant is held
below it and the node refuses a state beyond it."""
QUATERNION_NORM_TOLERANCE = 1e-2
"""A received attitude quaternion whose norm is further than this from 1 is not an attitude. float32
rounding of a normalised quaternion is ~1e-7; 1 % also admits a sender that renormalises only now
and then, and refuses garbage (and zero, which has no direction to normalise to)."""
MAX_ESTIMATE_SPEED = 327.67
"""m/s, the largest velocity component a state estimate may carry: what HIL_STATE_QUATERNION's int16
cm/s fields can express."""
MAX_ESTIMATE_DISTANCE = 2_147_483.647
"""m, the largest position component a state estimate may carry: what HIL_STATE_QUATERNION's int32
millimetre altitude can express."""


class BadState(ValueError):
    """A received state message whose values cannot be a vehicle's state; `reason` names the check
    (non_finite, quaternion_not_unit, out_of_range, frame), for counting drops by reason."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def _unit_quaternion(q, what: str) -> tuple[float, float, float, float]:
    """(w, x, y, z) normalised, or BadState: non-finite, zero, or not of unit length."""
    w, x, y, z = map(float, q)
    n2 = w * w + x * x + y * y + z * z
    if not math.isfinite(n2):  # also catches a NaN or ±Inf component, and an overflowing square
        raise BadState("non_finite", f"{what}: non-finite attitude quaternion {[w, x, y, z]}")
    n = math.sqrt(n2)
    if not abs(n - 1.0) <= QUATERNION_NORM_TOLERANCE:
        raise BadState(
            "quaternion_not_unit",
            f"{what}: attitude quaternion of norm {n:.6g}, expected 1 ± {QUATERNION_NORM_TOLERANCE:g}",
        )
    return w / n, x / n, y / n, z / n


def _check_rates(what: str, *rates: float) -> None:
    (a, b, c), lim = rates, MAX_BODY_RATE
    if -lim <= a <= lim and -lim <= b <= lim and -lim <= c <= lim:
        return  # every state (False for a NaN too: the loop below names what is wrong)
    for v in rates:
        if not -MAX_BODY_RATE <= v <= MAX_BODY_RATE:
            if not math.isfinite(v):
                raise BadState("non_finite", f"{what}: non-finite body rate {list(rates)}")
            raise BadState("out_of_range", f"{what}: body rate {v:.6g} rad/s, expected within ±{MAX_BODY_RATE:g}")


def _cm(v: float) -> int:
    """m/s → cm/s (the int16 field is saturated by `_saturating`)."""
    return round(v * 100.0)


@_saturating_args(mavlink2.MAVLink_hil_state_quaternion_message)
def hil_state_quaternion_args(state, home: Home, time_usec: int, accel_flu=None) -> list:
    """Arguments of `mav.hil_state_quaternion_send` (in order) for one 12-state (ENU/FLU, SI)."""
    x, y, z, vx, vy, vz, roll, pitch, yaw, p, q, r = map(float, state)
    lat, lon, alt = local_to_geodetic((x, y, z), home)
    if accel_flu is None:
        acc = (0.0, 0.0, 0.0)
    else:
        a0, a1, a2 = map(float, accel_flu)
        acc = (a0 / G_MG, -a1 / G_MG, -a2 / G_MG)
    return [
        int(time_usec),
        list(ned_frd_quaternion(roll, pitch, yaw)),  # attitude_quaternion
        p,  # rollspeed
        -q,  # pitchspeed
        -r,  # yawspeed
        lat,
        lon,
        alt,
        round(vy * 100.0),  # vx: NED north = ENU y, cm/s (`_cm` written out: this runs every simulation step)
        round(vx * 100.0),  # vy
        round(-vz * 100.0),  # vz
        0,  # ind_airspeed
        0,  # true_airspeed
        round(acc[0]),  # xacc
        round(acc[1]),  # yacc
        round(acc[2]),  # zacc
    ]


hil_state_quaternion_fields = _fields_of(
    mavlink2.MAVLink_hil_state_quaternion_message,
    hil_state_quaternion_args,
    "Keyword arguments of `mav.hil_state_quaternion_send` for one 12-state (ENU/FLU, SI).",
)


def state_from_hil_state_quaternion(msg, home: Home) -> np.ndarray:
    """A HIL_STATE_QUATERNION message (or any object with its fields) → 12-state ENU/FLU, SI.
    BadState if it cannot be a state: a non-finite value, a quaternion that is not a unit one, a
    latitude or longitude off the globe, a body rate beyond MAX_BODY_RATE (`state_values_from_hil_state_quaternion`
    as an array)."""
    return np.array(state_values_from_hil_state_quaternion(msg, home))


def state_values_from_hil_state_quaternion(msg, home: Home) -> list[float]:
    """`state_from_hil_state_quaternion` as 12 floats, the same values (the node's control loop works
    on floats).

    Scalar arithmetic (every step): the attitude is `rotmat_to_euler(rotmat_ned_frd_to_enu_flu(
    quaternion_to_rotmat(q)))` written out, which the tests check it against."""
    w, x, y, z = _unit_quaternion(msg.attitude_quaternion, "HIL_STATE_QUATERNION")
    _check_rates("HIL_STATE_QUATERNION", msg.rollspeed, msg.pitchspeed, msg.yawspeed)
    if not (-900_000_000 <= msg.lat <= 900_000_000 and -1_800_000_000 <= msg.lon <= 1_800_000_000):
        raise BadState("out_of_range", f"HIL_STATE_QUATERNION: lat/lon {msg.lat}/{msg.lon} degE7 is off the globe")
    # entries of R (FRD → NED) that the ENU/FLU Euler angles need, after E·R·F (see above)
    r00, r10 = 1 - 2 * (y * y + z * z), 2 * (x * y + w * z)
    r20, r21, r22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    n_m = (msg.lat * 1e-7 - home.lat_deg) * home.metres_per_deg_lat
    e_m = (msg.lon * 1e-7 - home.lon_deg) * home.metres_per_deg_lon
    return [
        e_m,
        n_m,
        msg.alt * 1e-3 - home.alt_m,
        msg.vy * 0.01,
        msg.vx * 0.01,
        -msg.vz * 0.01,
        math.atan2(r21, r22),
        math.asin(min(1.0, max(-1.0, r20))),
        math.atan2(r00, r10),
        msg.rollspeed,
        -msg.pitchspeed,
        -msg.yawspeed,
    ]


def _floats(v):
    """The values of `v` as Python floats: a float array's tolist() gives the floats float() gives its
    elements, without a call per element (this runs every simulation step)."""
    return v.tolist() if type(v) is np.ndarray and v.dtype.kind == "f" else map(float, v)


@_saturating_args(mavlink2.MAVLink_hil_sensor_message)
def hil_sensor_args(
    time_usec: int,
    gyro_flu,
    accel_flu,
    mag_flu,
    abs_pressure_hpa: float,
    pressure_alt_m: float,
    temperature_c: float = 15.0,
) -> list:
    """Arguments of `mav.hil_sensor_send` (in order); vectors in body FLU, converted to FRD here
    (y and z times −1, as `frames.flu_to_frd`)."""
    g0, g1, g2 = _floats(gyro_flu)
    a0, a1, a2 = _floats(accel_flu)
    m0, m1, m2 = _floats(mag_flu)
    return [
        int(time_usec),
        a0,  # xacc
        a1 * -1.0,  # yacc
        a2 * -1.0,  # zacc
        g0,  # xgyro
        g1 * -1.0,  # ygyro
        g2 * -1.0,  # zgyro
        m0,  # xmag
        m1 * -1.0,  # ymag
        m2 * -1.0,  # zmag
        float(abs_pressure_hpa),
        0.0,  # diff_pressure
        float(pressure_alt_m),
        float(temperature_c),
        0x1FFF,  # fields_updated: acc, gyro, mag, baro, temperature: all updated this step
        0,  # id
    ]


hil_sensor_fields = _fields_of(
    mavlink2.MAVLink_hil_sensor_message,
    hil_sensor_args,
    "Keyword arguments of `mav.hil_sensor_send`; vectors in body FLU, converted to FRD here.",
)


def gyro_from_hil_sensor(msg) -> np.ndarray:
    """Body rates (p, q, r) FLU in rad/s from a HIL_SENSOR message."""
    return frd_to_flu(np.array([msg.xgyro, msg.ygyro, msg.zgyro], np.float64))


def gyro_values_from_hil_sensor(msg) -> tuple[float, float, float]:
    """`gyro_from_hil_sensor` as three floats, the same bits (y and z times −1, as `frd_to_flu`)."""
    return float(msg.xgyro) * 1.0, float(msg.ygyro) * -1.0, float(msg.zgyro) * -1.0


@_saturating_args(mavlink2.MAVLink_hil_gps_message)
def hil_gps_args(state, home: Home, time_usec: int) -> list:
    """Arguments of `mav.hil_gps_send` (in order): 3-D fix, 10 satellites, eph/epv 0.3 m."""
    lat, lon, alt = local_to_geodetic(state[POS], home)
    vx, vy, vz = (float(v) for v in state[VEL])
    vn, ve, vd = vy, vx, vz * -1.0  # ENU → NED, as `frames.enu_to_ned`
    course = math.degrees(math.atan2(ve, vn)) % 360.0
    return [
        int(time_usec),
        3,  # fix_type
        lat,
        lon,
        alt,
        30,  # eph
        30,  # epv
        min(65534, round(math.hypot(vn, ve) * 100.0)),  # vel; UINT16_MAX means unknown
        _cm(vn),
        _cm(ve),
        _cm(vd),
        round(course * 100.0) % 36000,  # cog
        10,  # satellites_visible
        0,  # id
        0,  # yaw: 0 = not available
    ]


hil_gps_fields = _fields_of(
    mavlink2.MAVLink_hil_gps_message,
    hil_gps_args,
    "Keyword arguments of `mav.hil_gps_send` (3-D fix, 10 satellites, eph/epv 0.3 m).",
)


# --- a state estimate: ODOMETRY (simulator → autopilot, with --estimator-noise) ----------------
ODOMETRY_FRAME = 1  # MAV_FRAME_LOCAL_NED: position and attitude, origin at home
ODOMETRY_CHILD_FRAME = 12  # MAV_FRAME_BODY_FRD: velocity and rates, as PX4 publishes its own ODOMETRY
ODOMETRY_ESTIMATOR = 5  # MAV_ESTIMATOR_TYPE_GPS_INS: "estimator integrating GPS and inertial sensing"
_COV_DIAGONAL = (0, 6, 11, 15, 18, 20)  # of a 6×6 upper-right triangle stored row by row (21 floats)


def _covariance(variances) -> list[float]:
    """MAVLink's 21-float covariance with the given 6 variances on the diagonal; NaN first
    (unknown, as the message definition says) when None."""
    cov = [0.0] * 21
    if variances is None:
        cov[0] = math.nan
        return cov
    for i, v in zip(_COV_DIAGONAL, variances, strict=True):
        cov[i] = float(v)
    return cov


@_saturating(mavlink2.MAVLink_odometry_message)
def odometry_fields(state: np.ndarray, time_usec: int, pose_variance=None, velocity_variance=None) -> dict:
    """Keyword arguments of `mav.odometry_send` for a state *estimate* (12-state ENU/FLU, SI):
    position in local NED metres from home (floats: no 1 cm quantisation), attitude quaternion
    body FRD → NED, velocity and body rates in body FRD. The variances (6 each: x, y, z, roll,
    pitch, yaw and vx, vy, vz, rates) go on the covariance diagonals; None: unknown."""
    x, y, z, vx, vy, vz, roll, pitch, yaw, p, q, r = (float(v) for v in state)
    rot = euler_to_rotmat(roll, pitch, yaw)  # body FLU → ENU
    v_body = flu_to_frd(rot.T @ np.array([vx, vy, vz]))
    return {
        "time_usec": int(time_usec),
        "frame_id": ODOMETRY_FRAME,
        "child_frame_id": ODOMETRY_CHILD_FRAME,
        "x": y,  # NED north = ENU y
        "y": x,
        "z": -z,
        "q": list(ned_frd_quaternion(roll, pitch, yaw)),
        "vx": float(v_body[0]),
        "vy": float(v_body[1]),
        "vz": float(v_body[2]),
        "rollspeed": p,
        "pitchspeed": -q,
        "yawspeed": -r,
        "pose_covariance": _covariance(pose_variance),
        "velocity_covariance": _covariance(velocity_variance),
        "reset_counter": 0,
        "estimator_type": ODOMETRY_ESTIMATOR,
        "quality": 100,
    }


def state_from_odometry(msg) -> np.ndarray:
    """An ODOMETRY message in the frames `odometry_fields` writes (pose LOCAL_NED, twist BODY_FRD)
    → 12-state ENU/FLU, SI. Raises BadState (a ValueError) for other frames (reason "frame": guessing
    a frame would fly the vehicle on a wrong state) and for values that cannot be a state (as
    `state_from_hil_state_quaternion`; position and velocity within MAX_ESTIMATE_DISTANCE and
    MAX_ESTIMATE_SPEED)."""
    if msg.frame_id != ODOMETRY_FRAME or msg.child_frame_id != ODOMETRY_CHILD_FRAME:
        raise BadState(
            "frame",
            f"ODOMETRY frames {msg.frame_id}/{msg.child_frame_id}, expected {ODOMETRY_FRAME} (LOCAL_NED) / "
            f"{ODOMETRY_CHILD_FRAME} (BODY_FRD)",
        )
    q = _unit_quaternion(msg.q, "ODOMETRY")
    _check_rates("ODOMETRY", msg.rollspeed, msg.pitchspeed, msg.yawspeed)
    for values, bound, unit in (
        ((msg.x, msg.y, msg.z), MAX_ESTIMATE_DISTANCE, "m"),
        ((msg.vx, msg.vy, msg.vz), MAX_ESTIMATE_SPEED, "m/s"),
    ):
        for v in values:
            if not -bound <= v <= bound:
                if not math.isfinite(v):
                    raise BadState("non_finite", f"ODOMETRY: non-finite value in {list(values)}")
                raise BadState("out_of_range", f"ODOMETRY: {v:.6g} {unit}, expected within ±{bound:g}")
    rot = rotmat_ned_frd_to_enu_flu(quaternion_to_rotmat(q))  # body FLU → ENU
    roll, pitch, yaw = rotmat_to_euler(rot)
    v_world = rot @ frd_to_flu(np.array([msg.vx, msg.vy, msg.vz], np.float64))
    return np.array(
        [
            msg.y,
            msg.x,
            -msg.z,
            v_world[0],
            v_world[1],
            v_world[2],
            float(roll),
            float(pitch),
            float(yaw),
            msg.rollspeed,
            -msg.pitchspeed,
            -msg.yawspeed,
        ],
        np.float64,
    )


class NonFiniteCommand(ValueError):
    """A motor command that must never be transmitted (PX4 reads NaN as 'stop the motors')."""


@_saturating_args(mavlink2.MAVLink_hil_actuator_controls_message)
def actuator_controls_args(motors, time_usec: int, armed: bool, lockstep: bool) -> list:
    """Arguments of `mav.hil_actuator_controls_send` (in order) for 4 motor commands in [0, 1] (our
    rotor order). Raises NonFiniteCommand for NaN/Inf; clamps finite values to [0, 1]."""
    if type(motors) is np.ndarray and motors.dtype.kind == "f" and motors.shape == (NUM_MOTORS,):
        values = motors.tolist()  # float32 and float64 values are exact as Python floats
    else:
        values = np.asarray(motors, np.float64).reshape(-1).tolist()
    if len(values) != NUM_MOTORS:
        raise ValueError(f"expected {NUM_MOTORS} motor commands, got {len(values)}")
    controls = [0.0] * 16
    for wire, ours in enumerate(MOTOR_MAP):
        v = values[ours]
        if not math.isfinite(v):
            raise NonFiniteCommand(f"refusing to send non-finite motor commands {values}")
        controls[wire] = 1.0 if v > 1.0 else (0.0 if v < 0.0 else v)
    return [int(time_usec), controls, ARMED if armed else 0, LOCKSTEP if lockstep else 0]


actuator_controls_fields = _fields_of(
    mavlink2.MAVLink_hil_actuator_controls_message,
    actuator_controls_args,
    """Keyword arguments of `mav.hil_actuator_controls_send` for 4 motor commands in [0, 1] (our
    rotor order). Raises NonFiniteCommand for NaN/Inf; clamps finite values to [0, 1].""",
)


def motors_from_actuator_controls(msg) -> tuple[np.ndarray, bool, bool]:
    """(motor commands (4,) in our rotor order, armed, lockstep) from HIL_ACTUATOR_CONTROLS.
    Values are returned as sent; the caller decides what to do with non-finite or out-of-range ones."""
    values, armed, lockstep = motor_values_from_actuator_controls(msg)
    return np.array(values, np.float64), armed, lockstep


def motor_values_from_actuator_controls(msg) -> tuple[list[float], bool, bool]:
    """`motors_from_actuator_controls` with the commands as 4 floats (the simulator checks them every step)."""
    controls = msg.controls
    values = [0.0] * NUM_MOTORS
    for wire, ours in enumerate(MOTOR_MAP):
        values[ours] = float(controls[wire])
    return values, bool(msg.mode & ARMED), bool(msg.flags & LOCKSTEP)


# --- ground-station telemetry (autopilot → GCS on UDP 14550) -----------------------------------
UINT16_UNKNOWN = 65535


def attitude_ned_frd(state: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) rad of body FRD relative to NED, as MAVLink's ATTITUDE reports it, from
    the 12-state's ENU/FLU Euler angles."""
    r = rotmat_enu_flu_to_ned_frd(euler_to_rotmat(state[ROLL], state[PITCH], state[YAW]))
    roll, pitch, yaw = rotmat_to_euler(r)
    return float(roll), float(pitch), float(yaw)


@_saturating(mavlink2.MAVLink_attitude_message)
def attitude_fields(state: np.ndarray, time_boot_ms: int) -> dict:
    """Keyword arguments of `mav.attitude_send` (ATTITUDE: NED/FRD angles and FRD rates, rad)."""
    roll, pitch, yaw = attitude_ned_frd(state)
    rates = flu_to_frd(state[RATES])
    return {
        "time_boot_ms": int(time_boot_ms) & 0xFFFFFFFF,
        "roll": roll,
        "pitch": pitch,
        "yaw": yaw,
        "rollspeed": float(rates[0]),
        "pitchspeed": float(rates[1]),
        "yawspeed": float(rates[2]),
    }


NO_FENCE_BREACHED = mavlink2.MAV_SYS_STATUS_GEOFENCE
"""SYS_STATUS's geofence bit, set in health only: no fence is present or enabled, so none is breached.
A health bit of 0 is an error (MAVLink), and MAVProxy's fence module says "fence breach" on the
first SYS_STATUS without it, fence or none; ArduPilot sets it by default for the same reason
(GCS_Common.cpp: "GEOFENCE always defaults to healthy")."""


@_saturating(mavlink2.MAVLink_sys_status_message)
def sys_status_fields(sensors: int, errors: int, received: int) -> dict:
    """Keyword arguments of `mav.sys_status_send` for a ground station: `sensors` (a
    MAV_SYS_STATUS_SENSOR bit mask) present, enabled and healthy, and no fence breached
    (`NO_FENCE_BREACHED`); no battery information (-1); drop_rate_comm in c% and errors_comm from the
    count of messages dropped (`errors`) against those used (`received`)."""
    return {
        "onboard_control_sensors_present": sensors,
        "onboard_control_sensors_enabled": sensors,
        "onboard_control_sensors_health": sensors | NO_FENCE_BREACHED,
        "load": 0,
        "voltage_battery": UINT16_UNKNOWN,
        "current_battery": -1,
        "battery_remaining": -1,
        "drop_rate_comm": round(10000 * errors / max(1, errors + received)),
        "errors_comm": errors,
        "errors_count1": 0,
        "errors_count2": 0,
        "errors_count3": 0,
        "errors_count4": 0,
    }


@_saturating(mavlink2.MAVLink_local_position_ned_message)
def local_position_ned_fields(state: np.ndarray, time_boot_ms: int) -> dict:
    """Keyword arguments of `mav.local_position_ned_send` (m and m/s, local NED at home)."""
    p, v = enu_to_ned(state[POS]), enu_to_ned(state[VEL])
    return {
        "time_boot_ms": int(time_boot_ms) & 0xFFFFFFFF,
        "x": float(p[0]),
        "y": float(p[1]),
        "z": float(p[2]),
        "vx": float(v[0]),
        "vy": float(v[1]),
        "vz": float(v[2]),
    }


@_saturating(mavlink2.MAVLink_global_position_int_message)
def global_position_int_fields(state: np.ndarray, home: Home, time_boot_ms: int) -> dict:
    """Keyword arguments of `mav.global_position_int_send`: lat/lon degE7, alt mm MSL,
    relative_alt mm above home, vx/vy/vz cm/s NED, hdg cdeg (yaw from north, 0..35999)."""
    lat, lon, alt = local_to_geodetic(state[POS], home)
    v = enu_to_ned(state[VEL])
    yaw = attitude_ned_frd(state)[2]
    return {
        "time_boot_ms": int(time_boot_ms) & 0xFFFFFFFF,
        "lat": lat,
        "lon": lon,
        "alt": alt,
        "relative_alt": round(float(state[Z]) * 1000.0),
        "vx": _cm(v[0]),
        "vy": _cm(v[1]),
        "vz": _cm(v[2]),
        "hdg": round(math.degrees(yaw) * 100.0) % 36000,
    }
