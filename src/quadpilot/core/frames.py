"""Rotations between the body frame (FLU) and the world frame (ENU), batched over a leading axis.

Euler angles are ZYX (yaw, then pitch, then roll): R = Rz(ψ)·Ry(θ)·Rx(φ) maps body vectors to
world vectors. Conversions to MAVLink's NED/FRD live in `quadpilot.link`, not here.
"""

from __future__ import annotations

import math

import numpy as np


def rotation_entries(sin, cos, roll, pitch, yaw) -> tuple[tuple, tuple, tuple]:
    """The body → world rotation R = Rz(ψ)·Ry(θ)·Rx(φ) as three rows of three entries, from roll,
    pitch and yaw as plain floats or arrays alike, with `sin` and `cos` to suit them (math's, NumPy's);
    the entries are then floats or arrays. The one statement of the matrix: `euler_to_rotmat`, the
    observations (`core.observation.observation_values`, `core.px4_raptor`), the simulator's sensors,
    the node's estimate and `link.frames.ned_frd_quaternion` compute it here; `euler_to_rotmat_rows`
    is the same operations in place."""
    sr, cr, sp, cp, sy, cy = sin(roll), cos(roll), sin(pitch), cos(pitch), sin(yaw), cos(yaw)
    return (
        (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
        (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
        (-sp, cp * sr, cp * cr),
    )


def to_body(rot, w) -> tuple:
    """Rᵀ·w, the world vector w (three numbers, or three arrays) in the body frame, for rotation
    entries `rot` (`rotation_entries`), each component summed as `world_to_body`'s einsum sums it:
    the products in order onto a zero, R_2i·w_2 + (R_1i·w_1 + (R_0i·w_0 + 0)), the zero turning a −0
    product into +0. So the same bits, a NaN's sign included (the einsum keeps the operands in this
    order; in the other, ((0 + R_0i·w_0) + …), the numbers are the same but a NaN may take the other
    sign)."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rot
    wx, wy, wz = w
    return (
        r20 * wz + (r10 * wy + (r00 * wx + 0.0)),
        r21 * wz + (r11 * wy + (r01 * wx + 0.0)),
        r22 * wz + (r12 * wy + (r02 * wx + 0.0)),
    )


def swap_frames_entries(rot) -> tuple[tuple, tuple, tuple]:
    """E·R·F for rotation entries `rot` (rows of three): body FLU → ENU to body FRD → NED, and back
    (E, world ENU ↔ NED, swaps x and y and negates z; F, body FLU ↔ FRD, negates y and z; both are
    their own inverse). Rows 0 and 1 swapped, row 2 negated, then columns 1 and 2 negated: every
    entry is one of R's, negated or not, so exactly R's bits."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rot
    return (r10, -r11, -r12), (r00, -r01, -r02), (-r20, r21, r22)


def euler_to_rotmat(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Body → world rotation matrices, shape (..., 3, 3), from ZYX Euler angles of shape (...)."""
    rows = rotation_entries(np.sin, np.cos, roll, pitch, yaw)
    r01 = rows[0][1]  # cy·sp·sr − sy·cr: the shape and type of all three angles'
    out = np.empty((*np.shape(r01), 3, 3), np.result_type(r01))  # filled in place: no stack
    for i, row in enumerate(rows):
        for j, entry in enumerate(row):
            out[..., i, j] = entry
    return out


def euler_to_rotmat_rows(sin, cos, out, tmp: np.ndarray):
    """`euler_to_rotmat` in place: sin and cos (3, N) of roll, pitch and yaw, out (3, 3, N) with
    out[j][i] = R_ji, tmp an (N,) scratch row; the same operations in the same order, so the same bits.
    sin, cos and out may also be their rows already taken apart (tuples of (N,) rows, and of such
    tuples): a caller that builds every step keeps them so, since taking a row of an array costs
    about a fifth of what a NumPy call on a small row costs."""
    sr, sp, sy = sin
    cr, cp, cy = cos
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = out
    mul = np.multiply
    mul(cy, cp, r00)
    mul(cy, sp, r01)  # cy·sp, then ·sr − sy·cr
    mul(r01, cr, r02)  # cy·sp·cr + sy·sr
    mul(r01, sr, r01)
    mul(sy, cr, tmp)
    np.subtract(r01, tmp, r01)
    mul(sy, sr, tmp)
    np.add(r02, tmp, r02)
    mul(sy, cp, r10)
    mul(sy, sp, r11)  # sy·sp, then ·sr + cy·cr
    mul(r11, cr, r12)  # sy·sp·cr − cy·sr
    mul(r11, sr, r11)
    mul(cy, cr, tmp)
    np.add(r11, tmp, r11)
    mul(cy, sr, tmp)
    np.subtract(r12, tmp, r12)
    np.negative(sp, r20)
    mul(cp, sr, r21)
    mul(cp, cr, r22)
    return out


def world_to_body_rows(rot: np.ndarray, v: np.ndarray, out: np.ndarray, *_scratch) -> np.ndarray:
    """`world_to_body` in place: rot (3, 3, N) as `euler_to_rotmat_rows` writes it, v (3, N) world
    vectors, out (3, N); the rows of v and out may lie apart (views of larger row blocks).

    `world_to_body` is np.einsum("nji,nj->ni"), which sums the three products of each component in
    order onto a zero: ((0 + R_0i·v_0) + R_1i·v_1) + R_2i·v_2, the zero turning a −0 product into
    +0. The same np.einsum over the rows computes the same sums (tests/core/test_inplace_equivalence.py
    compares the two bit for bit, −0 products included) in one call, and it reads and writes rows
    that lie apart without a buffer, where a ufunc given such a 2-D operand allocates one. (The
    scratch arguments of the earlier row-by-row form are accepted and not needed.)"""
    return np.einsum("jin,jn->in", rot, v, out=out)


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


def scalar_trig_agrees(samples: int = 256) -> bool:
    """math.sin, math.cos and math.floor give NumPy's bits on one-element float64 arrays at
    `samples` angles over ±4π and a few special ones. The scalar forms of one vehicle's step and
    observation (`simulator.single_step`, `runtime.observation_one`) compute only where this
    holds: `math` is the C library's, while `np.sin` may be NumPy's own SIMD code on some CPUs."""
    rng = np.random.default_rng(20240611)
    angles = np.concatenate([rng.uniform(-4 * math.pi, 4 * math.pi, samples), [0.0, -0.0, math.pi, -math.pi, 1e-300]])
    for v in angles.tolist():
        a = np.array([v])
        if (np.sin(a)[0], np.cos(a)[0], np.floor(a)[0]) != (math.sin(v), math.cos(v), float(math.floor(v))):
            return False
    return True
