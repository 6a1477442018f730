"""Rotations between the body frame (FLU) and the world frame (ENU), batched over a leading axis.

Euler angles are ZYX (yaw, then pitch, then roll): R = Rz(ψ)·Ry(θ)·Rx(φ) maps body vectors to
world vectors. Conversions to MAVLink's NED/FRD live in `quadpilot.link`, not here.
"""

from __future__ import annotations

import numpy as np


def euler_to_rotmat(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Body → world rotation matrices, shape (..., 3, 3), from ZYX Euler angles of shape (...)."""
    sr, cr = np.sin(roll), np.cos(roll)
    sp, cp = np.sin(pitch), np.cos(pitch)
    sy, cy = np.sin(yaw), np.cos(yaw)
    out = np.empty((*np.shape(sr), 3, 3), np.result_type(sr, sp, sy))  # filled in place: no stack
    out[..., 0, 0] = cy * cp
    out[..., 0, 1] = cy * sp * sr - sy * cr
    out[..., 0, 2] = cy * sp * cr + sy * sr
    out[..., 1, 0] = sy * cp
    out[..., 1, 1] = sy * sp * sr + cy * cr
    out[..., 1, 2] = sy * sp * cr - cy * sr
    out[..., 2, 0] = -sp
    out[..., 2, 1] = cp * sr
    out[..., 2, 2] = cp * cr
    return out


def rotmat_to_euler(rot: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZYX Euler angles (roll, pitch, yaw) of rotation matrices (..., 3, 3); pitch in [−π/2, π/2]."""
    roll = np.arctan2(rot[..., 2, 1], rot[..., 2, 2])
    pitch = -np.arcsin(np.clip(rot[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(rot[..., 1, 0], rot[..., 0, 0])
    return roll, pitch, yaw


def euler_to_quaternion(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z), shape (..., 4), of the same rotation as `euler_to_rotmat`."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.stack(
        (
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ),
        axis=-1,
    )


def quaternion_to_euler(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZYX Euler angles (roll, pitch, yaw) of unit quaternions (..., 4) in (w, x, y, z) order."""
    w, x, y, z = (q[..., i] for i in range(4))
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def world_to_body(rot: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rᵀ·v for rotation matrices (N, 3, 3) and world vectors (N, 3): the vectors in the body frame."""
    return np.einsum("nji,nj->ni", rot, v)


def body_to_world(rot: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R·v for rotation matrices (N, 3, 3) and body vectors (N, 3)."""
    return np.einsum("nij,nj->ni", rot, v)
