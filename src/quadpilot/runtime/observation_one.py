"""`core.observation.build_observation` for the node's one vehicle, on plain floats (`observe`).

The node builds one observation per policy tick. `build_observation` on a batch of one spends most
of its time on NumPy's per-call overhead (some 80 ufunc calls and assignments on arrays of one
element), several times what its arithmetic costs on Python floats. So this runs the same
arithmetic, `core.observation.observation_values`, on the 12 floats of one state with `math`'s
trigonometry, in float64, rounded to float32 once at the end as the assignment into
`build_observation`'s float32 output rounds it. IEEE double arithmetic on Python floats and on
float64 arrays rounds alike; what could differ is the trigonometry (`math.sin` is the C library's,
`np.sin` may be NumPy's own SIMD code on some CPUs): `TRIG_AGREES` checks the two on sample angles
when the module is loaded (`core.frames.scalar_trig_agrees`, as for the simulator), and where they
differ, or an input is not finite (`math.sin` raises on ±Inf where `np.sin` gives NaN; a NaN's sign
and payload need not survive two compilers' arithmetic alike), `observe` hands the state to
`build_observation` itself. tests/runtime/test_observation_one.py compares the two bit for bit over
random states, targets, target velocities and headings.
"""

from __future__ import annotations

import math

import numpy as np

from quadpilot.core.frames import scalar_trig_agrees
from quadpilot.core.observation import build_observation, observation_values

TRIG_AGREES = scalar_trig_agrees()
"""Whether `observe` may compute in scalars (checked once, when this module is loaded)."""

_F32 = np.float32


def observe(state: list, target: list, target_vel: list | None = None, heading: float | None = None) -> np.ndarray:
    """`build_observation(np.array([state]), np.array(target), target_vel, heading=heading)[0]`: the
    float32 observation (18,), or (21,) with a target velocity, of one 12-state given as 12 floats
    (ENU/FLU, SI), a target position (3 floats), a target velocity (3 floats) or None, and a commanded
    heading (rad) or None; the same bits."""
    # one sum: NaN or ±Inf anywhere makes it non-finite (so does an overflow, which is merely slower)
    check = sum(state) + sum(target) + (0.0 if heading is None else heading)
    if target_vel is not None:
        check += sum(target_vel)
    if not (TRIG_AGREES and math.isfinite(check)):
        return _batched(state, target, target_vel, heading)
    return np.array(observation_values(math.sin, math.cos, state, target, target_vel, heading), _F32)


def _batched(state, target, target_vel, heading) -> np.ndarray:
    """`build_observation` itself, on a batch of one."""
    tv = None if target_vel is None else np.asarray(target_vel, np.float64)
    return build_observation(np.array([state], np.float64), np.asarray(target, np.float64), tv, heading=heading)[0]
