"""`core.observation.build_observation` for the node's one vehicle, in scalar arithmetic (`observe`).

The node builds one observation per policy tick. `build_observation` on a batch of one spends most
of its time on NumPy's per-call overhead (some 40 ufunc calls and assignments on arrays of one
element, two einsums), several times what its arithmetic costs on Python floats. This is that
arithmetic, written out once more for one state, operation for operation in the order
`build_observation` does it (`core.frames.euler_to_rotmat`, then `world_to_body`'s einsum, which
sums each component's three products in order onto a zero: ((0 + R_0i·v_0) + R_1i·v_1) + R_2i·v_2,
as `core.frames.world_to_body_rows` documents), in float64, rounded to float32 once at the end as
the assignment into `build_observation`'s float32 output rounds it. IEEE double arithmetic on Python
floats and on float64 arrays rounds alike; what could differ is the trigonometry (`math.sin` is the
C library's, `np.sin` may be NumPy's own SIMD code on some CPUs): `TRIG_AGREES` checks the two on
sample angles when the module is loaded (`core.frames.scalar_trig_agrees`, as for the simulator), and
where they differ, or an input is not finite (`math.sin` raises on ±Inf where `np.sin` gives NaN; a
NaN's sign and payload need not survive two compilers' arithmetic alike), `observe` hands the state
to `build_observation` itself. tests/runtime/test_observation_one.py compares the two bit for bit
over random states, targets, target velocities and headings.
"""

from __future__ import annotations

import math

import numpy as np

from quadpilot.core.frames import scalar_trig_agrees
from quadpilot.core.observation import build_observation

TRIG_AGREES = scalar_trig_agrees()
"""Whether `observe` may compute in scalars (checked once, when this module is loaded)."""

_F32 = np.float32


def observe(state: list, target: list, target_vel: list | None = None, heading: float | None = None) -> np.ndarray:
    """`build_observation(np.array([state]), np.array(target), target_vel, heading=heading)[0]`: the
    float32 observation (18,), or (21,) with a target velocity, of one 12-state given as 12 floats
    (ENU/FLU, SI), a target position (3 floats), a target velocity (3 floats) or None, and a commanded
    heading (rad) or None; the same bits."""
    x, y, z, vx, vy, vz, roll, pitch, yaw, p, q, r = state
    tx, ty, tz = target
    # one sum: NaN or ±Inf anywhere makes it non-finite (so does an overflow, which is merely slower)
    check = sum(state) + tx + ty + tz + (0.0 if heading is None else heading)
    if target_vel is not None:
        check += sum(target_vel)
    if not (TRIG_AGREES and math.isfinite(check)):
        return _batched(state, target, target_vel, heading)
    sr, cr = math.sin(roll), math.cos(roll)
    sp, cp = math.sin(pitch), math.cos(pitch)
    sy, cy = math.sin(yaw), math.cos(yaw)
    # core.frames.euler_to_rotmat, entry for entry
    r00 = cy * cp
    r01 = cy * sp * sr - sy * cr
    r02 = cy * sp * cr + sy * sr
    r10 = sy * cp
    r11 = sy * sp * sr + cy * cr
    r12 = sy * sp * cr - cy * sr
    r20 = -sp
    r21 = cp * sr
    r22 = cp * cr
    # core.frames.world_to_body (Rᵀ·v, the einsum's order and its zero start) of the position error
    ex, ey, ez = x - tx, y - ty, z - tz
    out = [
        0.0 + r00 * ex + r10 * ey + r20 * ez,
        0.0 + r01 * ex + r11 * ey + r21 * ez,
        0.0 + r02 * ex + r12 * ey + r22 * ez,
        0.0 + r00 * vx + r10 * vy + r20 * vz,
        0.0 + r01 * vx + r11 * vy + r21 * vz,
        0.0 + r02 * vx + r12 * vy + r22 * vz,
    ]
    if heading is None:
        out += (r00, r01, r02, r10, r11, r12, r20, r21, r22)
    else:  # Rz(−ψ_cmd)·R: rows c·R0 + s·R1 and (−s)·R0 + c·R1, then R2
        c, s = math.cos(heading), math.sin(heading)
        ns = -s
        out += (
            c * r00 + s * r10,
            c * r01 + s * r11,
            c * r02 + s * r12,
            ns * r00 + c * r10,
            ns * r01 + c * r11,
            ns * r02 + c * r12,
            r20,
            r21,
            r22,
        )
    out += (p, q, r)
    if target_vel is not None:
        wx, wy, wz = target_vel
        out += (
            0.0 + r00 * wx + r10 * wy + r20 * wz,
            0.0 + r01 * wx + r11 * wy + r21 * wz,
            0.0 + r02 * wx + r12 * wy + r22 * wz,
        )
    return np.array(out, _F32)


def _batched(state, target, target_vel, heading) -> np.ndarray:
    """`build_observation` itself, on a batch of one."""
    tv = None if target_vel is None else np.asarray(target_vel, np.float64)
    return build_observation(np.array([state], np.float64), np.asarray(target, np.float64), tv, heading=heading)[0]
