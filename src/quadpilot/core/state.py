"""The 12-state's layout: the one place that names its entries (NumPy indexing only).

Every array whose last axis is a vehicle state, (12,), (N, 12), (T, N, 12), ..., is laid out as:

    index  name   slice   quantity                                   unit   frame
    0      X      POS     position x (east)                          m      world ENU
    1      Y      POS     position y (north)                         m      world ENU
    2      Z      POS     position z (up; the ground plane is z = 0) m      world ENU
    3      VX     VEL     velocity x                                 m/s    world ENU
    4      VY     VEL     velocity y                                 m/s    world ENU
    5      VZ     VEL     velocity z                                 m/s    world ENU
    6      ROLL   ATT     roll φ, about body x                       rad    ZYX Euler, body FLU → world ENU
    7      PITCH  ATT     pitch θ, about body y (positive nose down) rad    ZYX Euler, body FLU → world ENU
    8      YAW    ATT     yaw ψ, about world z, from east            rad    ZYX Euler, body FLU → world ENU
    9      P      RATES   body rate about x (forward)                rad/s  body FLU
    10     Q      RATES   body rate about y (left)                   rad/s  body FLU
    11     R      RATES   body rate about z (up)                     rad/s  body FLU

The rotation Rz(yaw)·Ry(pitch)·Rx(roll) takes body FLU into world ENU (`core.frames.euler_to_rotmat`);
`core.dynamics` documents the equations. POS_XY (0:2) is the horizontal position, ROLL_PITCH (6:8)
the tilt pair.

Index with these names, on the last axis: `state[..., YAW]`, `states[:, POS]`, `s[VEL]`. They are
plain ints and slices, so indexing with them costs what indexing with the literal costs and gives
the same array (a view for a slice); nothing here runs per step. `tests/core/test_named_state.py`
checks the layout and scans `src/quadpilot` for state arrays indexed with bare numbers anywhere
else.
"""

from __future__ import annotations

STATE_DIM = 12
STATE_NAMES = ("x", "y", "z", "vx", "vy", "vz", "roll", "pitch", "yaw", "p", "q", "r")
IDX = {name: i for i, name in enumerate(STATE_NAMES)}

# scalar indices, in STATE_NAMES order
X, Y, Z = 0, 1, 2
VX, VY, VZ = 3, 4, 5
ROLL, PITCH, YAW = 6, 7, 8
P, Q, R = 9, 10, 11

# the four 3-vectors, and two pairs
POS = slice(X, Z + 1)
VEL = slice(VX, VZ + 1)
ATT = slice(ROLL, YAW + 1)
RATES = slice(P, R + 1)
POS_XY = slice(X, Y + 1)  # horizontal position
ROLL_PITCH = slice(ROLL, PITCH + 1)  # tilt
