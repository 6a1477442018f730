"""The wire's frames and the local ↔ geodetic map: everything `wire` needs to turn the project's
frames into MAVLink's and back.

Inside the project: world ENU (z up), body FLU, SI units. On the wire, as the MAVLink common message
set and PX4's Simulator MAVLink API define them: local NED, body FRD, attitude as a unit quaternion
(w, x, y, z) rotating body FRD into NED, positions as WGS-84 latitude and longitude in 1e-7 degrees
and altitude in millimetres. (`core.frames` holds the project's own Euler angles and rotation
matrices; this module only converts between the two conventions.)

Position precision: 1e-7° of latitude is 1.11 cm, of longitude 1.11·cos(lat) cm, altitude 1 mm,
velocity 1 cm/s. Rounding to the nearest step bounds the position error a policy sees at
`Home.position_quantum_m` / 2 per horizontal axis and the velocity error at 0.5 cm/s per axis,
against a hover bar of 5 cm: no extra message is needed for precision. Local ↔ geodetic uses the
equirectangular approximation around the home point on a sphere of the WGS-84 mean radius (as
PX4's `map_projection` does for short distances; at 100 m from home it differs from the
azimuthal-equidistant projection by far less than the 1e-7° quantum).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from quadpilot.core.frames import rotation_entries, swap_frames_entries

EARTH_RADIUS_M = 6_371_008.8  # WGS-84 mean radius (IUGG), m
LAT_QUANTUM_DEG = 1e-7

# ENU ↔ NED swaps x and y and negates z; FLU ↔ FRD negates y and z. Both are their own inverse.
_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_FLU_FRD = np.diag([1.0, -1.0, -1.0])
_SWAP_XY = [1, 0, 2]  # ENU ↔ NED: swap the horizontal axes, flip the vertical one
_FLIP_Z = np.array([1.0, 1.0, -1.0])
_FLIP_YZ = np.array([1.0, -1.0, -1.0])  # FLU ↔ FRD


@dataclass(frozen=True)
class Home:
    """The geodetic origin of the local frame. Default: PX4 SITL's home (Zürich, Irchel park)."""

    lat_deg: float = 47.397742
    lon_deg: float = 8.545594
    alt_m: float = 488.0
    """m above mean sea level, of the local frame's z = 0."""

    # cached: every state message sent or read uses them (a frozen dataclass has no other state)
    @functools.cached_property
    def metres_per_deg_lat(self) -> float:
        return math.radians(1.0) * EARTH_RADIUS_M

    @functools.cached_property
    def metres_per_deg_lon(self) -> float:
        return math.radians(1.0) * EARTH_RADIUS_M * math.cos(math.radians(self.lat_deg))

    @property
    def position_quantum_m(self) -> tuple[float, float, float]:
        """Wire resolution of (east, north, up) in metres."""
        return (LAT_QUANTUM_DEG * self.metres_per_deg_lon, LAT_QUANTUM_DEG * self.metres_per_deg_lat, 1e-3)


def enu_to_ned(v: np.ndarray) -> np.ndarray:
    """(…, 3) ENU → NED (also NED → ENU)."""
    return np.asarray(v, np.float64)[..., _SWAP_XY] * _FLIP_Z


ned_to_enu = enu_to_ned


def flu_to_frd(v: np.ndarray) -> np.ndarray:
    """(…, 3) body FLU → FRD (also FRD → FLU)."""
    return np.asarray(v, np.float64) * _FLIP_YZ


frd_to_flu = flu_to_frd


def rotmat_enu_flu_to_ned_frd(r: np.ndarray) -> np.ndarray:
    """Body FLU → ENU rotation (3, 3) → the same attitude as body FRD → NED."""
    return _ENU_NED @ r @ _FLU_FRD


rotmat_ned_frd_to_enu_flu = rotmat_enu_flu_to_ned_frd  # the same sandwich: both factors are involutions


def rotmat_to_quaternion(r: np.ndarray) -> np.ndarray:
    """(3, 3) rotation → unit quaternion (w, x, y, z), w ≥ 0 (Shepperd's method, stable for all
    rotations)."""
    m = np.asarray(r, np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2.0
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2.0
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2.0
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def quaternion_to_rotmat(q) -> np.ndarray:
    """Quaternion (w, x, y, z), normalised here → (3, 3) rotation."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def local_to_geodetic(pos_enu: np.ndarray, home: Home) -> tuple[int, int, int]:
    """Local ENU position (m) → (lat degE7, lon degE7, alt mm), rounded to the wire's integers."""
    e, n, u = map(float, pos_enu)
    lat = home.lat_deg + n / home.metres_per_deg_lat
    lon = home.lon_deg + e / home.metres_per_deg_lon
    return round(lat * 1e7), round(lon * 1e7), round((home.alt_m + u) * 1000.0)


def geodetic_to_local(lat_e7: int, lon_e7: int, alt_mm: int, home: Home) -> np.ndarray:
    """(lat degE7, lon degE7, alt mm) → local ENU position (m)."""
    n = (lat_e7 * 1e-7 - home.lat_deg) * home.metres_per_deg_lat
    e = (lon_e7 * 1e-7 - home.lon_deg) * home.metres_per_deg_lon
    return np.array([e, n, alt_mm * 1e-3 - home.alt_m])


def ned_frd_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Body FRD → NED quaternion (w ≥ 0) of ENU/FLU ZYX Euler angles, in scalar arithmetic (this runs
    every simulation step). The same rotation as `rotmat_to_quaternion(rotmat_enu_flu_to_ned_frd(
    euler_to_rotmat(roll, pitch, yaw)))`, which the tests check it against."""
    rot = swap_frames_entries(rotation_entries(math.sin, math.cos, roll, pitch, yaw))  # M = E·R·F
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = rot
    tr = m00 + m11 + m22  # Shepperd's method, as rotmat_to_quaternion
    if tr > 0.0:
        t = math.sqrt(tr + 1.0) * 2.0
        q = (0.25 * t, (m21 - m12) / t, (m02 - m20) / t, (m10 - m01) / t)
    elif m00 > m11 and m00 > m22:
        t = math.sqrt(1.0 + m00 - m11 - m22) * 2.0
        q = ((m21 - m12) / t, 0.25 * t, (m01 + m10) / t, (m02 + m20) / t)
    elif m11 > m22:
        t = math.sqrt(1.0 + m11 - m00 - m22) * 2.0
        q = ((m02 - m20) / t, (m01 + m10) / t, 0.25 * t, (m12 + m21) / t)
    else:
        t = math.sqrt(1.0 + m22 - m00 - m11) * 2.0
        q = ((m10 - m01) / t, (m02 + m20) / t, (m12 + m21) / t, 0.25 * t)
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[0] < 0:
        n = -n
    return q[0] / n, q[1] / n, q[2] / n, q[3] / n
