"""Telemetry a ground station relies on: the messages, built from the vehicle's state, and their rates.

Default intervals are PX4's for a ground-station link (src/modules/mavlink/mavlink_main.cpp,
MAVLINK_MODE_NORMAL): ATTITUDE 15 Hz, GLOBAL_POSITION_INT 5 Hz, HEARTBEAT, SYS_STATUS, GPS_RAW_INT,
LOCAL_POSITION_NED, EXTENDED_SYS_STATE and MISSION_CURRENT 1 Hz, HOME_POSITION 0.5 Hz;
ATTITUDE_QUATERNION off until asked for. SET_MESSAGE_INTERVAL changes any of them (MAVLink
MAV_CMD_SET_MESSAGE_INTERVAL: −1 off, 0 the default, else the interval in µs); AUTOPILOT_VERSION is
sent only when requested. Times are the caller's clock in seconds (simulated time here).

What MAVSDK reads from them (checked against its telemetry plugin): global position health only from
SYS_STATUS's GPS bit (0x20) present and healthy, home health from any HOME_POSITION, armable from the
pre-arm check bit, the landed state only from EXTENDED_SYS_STATE.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.core.state import PITCH, POS, RATES, ROLL, VEL, YAW
from quadpilot.link import wire
from quadpilot.link.frames import Home, enu_to_ned, flu_to_frd, local_to_geodetic, ned_frd_quaternion

M = mavlink2
HEARTBEAT, SYS_STATUS, GPS_RAW_INT = (
    M.MAVLINK_MSG_ID_HEARTBEAT,
    M.MAVLINK_MSG_ID_SYS_STATUS,
    M.MAVLINK_MSG_ID_GPS_RAW_INT,
)
ATTITUDE, ATTITUDE_QUATERNION = M.MAVLINK_MSG_ID_ATTITUDE, M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION
LOCAL_POSITION_NED, GLOBAL_POSITION_INT = M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
MISSION_CURRENT, AUTOPILOT_VERSION = M.MAVLINK_MSG_ID_MISSION_CURRENT, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION
HOME_POSITION, EXTENDED_SYS_STATE = M.MAVLINK_MSG_ID_HOME_POSITION, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE

DEFAULT_INTERVALS_S: dict[int, float | None] = {
    HEARTBEAT: 1.0,
    SYS_STATUS: 1.0,
    GPS_RAW_INT: 1.0,
    ATTITUDE: 1.0 / 15.0,
    ATTITUDE_QUATERNION: None,
    LOCAL_POSITION_NED: 1.0,
    GLOBAL_POSITION_INT: 0.2,
    MISSION_CURRENT: 1.0,
    HOME_POSITION: 2.0,
    EXTENDED_SYS_STATE: 1.0,
}
"""Streamed messages and their default intervals (s); None: not streamed unless asked for."""
REQUESTABLE = frozenset(DEFAULT_INTERVALS_S) | {AUTOPILOT_VERSION}
"""Message ids REQUEST_MESSAGE can produce."""

SENSORS = (
    M.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | M.MAV_SYS_STATUS_SENSOR_3D_MAG
    | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | M.MAV_SYS_STATUS_SENSOR_GPS
    | M.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | M.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | M.MAV_SYS_STATUS_AHRS
)
"""SYS_STATUS bits present, enabled and healthy: the simulator's sensors (including the GPS, 0x20),
the controllers the policy stands in for, and the estimator. The pre-arm check bit
(MAV_SYS_STATUS_PREARM_CHECK) is present and enabled, and healthy when the vehicle may arm or is armed
(MAVLink: "always healthy when armed"). The geofence bit is in health only (`wire.NO_FENCE_BREACHED`:
no fence present, none breached)."""
CAPABILITIES = (
    M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
)
"""AUTOPILOT_VERSION capabilities: what this vehicle speaks (no float missions, FTP or offboard)."""


def _ms(now: float) -> int:
    return int(now * 1000.0) & 0xFFFFFFFF


class Streams:
    """Intervals per message id and when each was last sent; `due(now)` → the ids to send now."""

    def __init__(self) -> None:
        self.intervals = dict(DEFAULT_INTERVALS_S)
        self.last: dict[int, float] = {}

    def set_interval(self, msg_id: int, interval_us: float) -> str | None:
        """SET_MESSAGE_INTERVAL; None if done, else why not."""
        if msg_id not in DEFAULT_INTERVALS_S:
            return f"message {msg_id} is not streamed"
        if not math.isfinite(interval_us) or (interval_us < 0 and interval_us != -1):
            return f"interval {interval_us} us: expected -1, 0 or a positive number"
        if interval_us == -1:
            self.intervals[msg_id] = None
        elif interval_us == 0:
            self.intervals[msg_id] = DEFAULT_INTERVALS_S[msg_id]
        else:
            self.intervals[msg_id] = interval_us * 1e-6
        return None

    def interval_us(self, msg_id: int) -> int:
        """MESSAGE_INTERVAL's value: −1 off, 0 not available, else µs."""
        if msg_id not in self.intervals:
            return 0
        s = self.intervals[msg_id]
        return -1 if s is None else round(s * 1e6)

    def due(self, now: float) -> list[int]:
        out = []
        for msg_id, every in self.intervals.items():
            if every is None:
                continue
            last = self.last.get(msg_id)
            if last is None or now - last >= every - 1e-9 or now < last:
                self.last[msg_id] = now
                out.append(msg_id)
        return out


# --- messages ----------------------------------------------------------------------------------


def home_position(mav, home: Home, now: float):
    """HOME_POSITION: home at the local origin, approach vector unset."""
    lat, lon, alt = local_to_geodetic((0.0, 0.0, 0.0), home)
    return mav.home_position_encode(lat, lon, alt, 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(now * 1e6))


def gps_raw_int(mav, state: np.ndarray, home: Home, now: float):
    """GPS_RAW_INT: a 3-D fix at the state's position (the simulator's GPS is exact to the wire's
    quantum), 10 satellites, 0.3 m accuracy as the simulator's HIL_GPS reports it."""
    lat, lon, alt = local_to_geodetic(state[POS], home)
    vn, ve, _ = (float(v) for v in enu_to_ned(state[VEL]))
    return mav.gps_raw_int_encode(
        int(now * 1e6),
        M.GPS_FIX_TYPE_3D_FIX,
        lat,
        lon,
        max(-(2**31), min(2**31 - 1, alt)),
        30,
        30,
        min(65534, round(math.hypot(vn, ve) * 100.0)),
        round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100.0) % 36000,
        10,
        0,
        300,
        300,
        100,
        0,
        0,
    )


def global_position_int(mav, state: np.ndarray, home: Home, now: float):
    return mav.global_position_int_encode(**wire.global_position_int_fields(state, home, _ms(now)))


def attitude(mav, state: np.ndarray, now: float):
    return mav.attitude_encode(**wire.attitude_fields(state, _ms(now)))


def attitude_quaternion(mav, state: np.ndarray, now: float):
    q = ned_frd_quaternion(float(state[ROLL]), float(state[PITCH]), float(state[YAW]))
    p, r_q, r = (float(v) for v in flu_to_frd(state[RATES]))
    return mav.attitude_quaternion_encode(_ms(now), *q, p, r_q, r, [0.0, 0.0, 0.0, 0.0])


def local_position_ned(mav, state: np.ndarray, now: float):
    return mav.local_position_ned_encode(**wire.local_position_ned_fields(state, _ms(now)))


def extended_sys_state(mav, landed_state: int):
    return mav.extended_sys_state_encode(M.MAV_VTOL_STATE_UNDEFINED, landed_state)


def sys_status(mav, armable: bool, errors: int = 0, received: int = 0):
    prearm = M.MAV_SYS_STATUS_PREARM_CHECK
    return mav.sys_status_encode(
        SENSORS | prearm,
        SENSORS | prearm,
        SENSORS | wire.NO_FENCE_BREACHED | (prearm if armable else 0),
        0,
        wire.UINT16_UNKNOWN,
        -1,
        -1,
        min(10000, round(10000 * errors / max(1, errors + received))),
        min(65535, errors),
        0,
        0,
        0,
        0,
    )


def autopilot_version(mav, flight_sw_version: int, uid: int):
    return mav.autopilot_version_encode(
        CAPABILITIES, flight_sw_version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, uid, [0] * 18
    )
