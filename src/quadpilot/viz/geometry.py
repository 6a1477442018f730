"""Where the drawn quadrotor's parts are: pure NumPy, tested against known attitudes.

The rotor layout is the vehicle's (`core.params.unit_layout`: rotor positions per metre of arm in
the body FLU frame, in output order), PX4's quad-X (`core.params.QUAD_X_UNIT`, arms at ±45°) when
none is given, and the rotation is `core.frames.euler_to_rotmat` (R = Rz(yaw)·Ry(pitch)·Rx(roll),
body → world), so the drawing and the model cannot disagree.
"""

from __future__ import annotations

import math

import numpy as np

from quadpilot.core.frames import euler_to_rotmat
from quadpilot.core.params import QUAD_X_UNIT
from quadpilot.core.state import ATT, PITCH, POS, ROLL, STATE_DIM, YAW
from quadpilot.core.vehicle_file import SEED_VEHICLE, get_preset


def _rotors_unit(layout) -> np.ndarray:
    """(M, 3) rotor centres in body FLU for a unit arm: (x, y) of the layout, z = 0."""
    lay = np.asarray(QUAD_X_UNIT if layout is None else layout, dtype=np.float64)
    if lay.ndim != 2 or lay.shape[1] != 3:
        raise ValueError(f"layout: expected (x/arm, y/arm, spin) rows, got shape {lay.shape}")
    return np.column_stack([lay[:, 0], lay[:, 1], np.zeros(len(lay))])


_ROTORS_UNIT = _rotors_unit(None)  # PX4 quad-X: (±1/√2, ±1/√2, 0)

EXAGGERATION = 3.0
"""How much `display_arm` lengthens the arms when the vehicle would be too small to see."""
VISIBLE_FRACTION = 0.04
"""Below this fraction of the view's width a true-size arm is exaggerated by `EXAGGERATION`."""


def body_points(state: np.ndarray, arm_length: float, layout=None) -> np.ndarray:
    """Rotor centres in the world frame (m, ENU) of a vehicle with arms of `arm_length` m.

    state: (12,) or (N, 12) core state; layout: the vehicle's `core.params.unit_layout` (None: PX4's
    quad-X). Returns (M, 3) or (N, M, 3), rotors in output order (quad-X: 0 front-right, 1
    rear-left, 2 front-left, 3 rear-right): p + R·b_i with b_i = arm·(x_i, y_i, 0) in body FLU.
    """
    s = np.asarray(state, dtype=np.float64)
    if s.shape[-1:] != (STATE_DIM,) or s.ndim not in (1, 2):
        raise ValueError(f"body_points: state must have shape (12,) or (N, 12), got {s.shape}")
    att = s[..., ATT]
    rot = euler_to_rotmat(att[..., 0], att[..., 1], att[..., 2])  # (..., 3, 3)
    body = (_ROTORS_UNIT if layout is None else _rotors_unit(layout)) * float(arm_length)  # (M, 3)
    return s[..., None, POS] + np.einsum("...ij,kj->...ki", rot, body)


def rotor_discs(state: np.ndarray, arm_length: float, radius: float, n: int = 16, layout=None) -> np.ndarray:
    """(M, n, 3) world points of each rotor's disc outline: circles of `radius` m around the
    rotor centres, in the body x-y plane (so they tilt with the vehicle). state: (12,); layout as
    in `body_points`."""
    s = np.asarray(state, dtype=np.float64)
    if s.shape != (STATE_DIM,):
        raise ValueError(f"rotor_discs: state must have shape (12,), got {s.shape}")
    rot = euler_to_rotmat(s[ROLL], s[PITCH], s[YAW])
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    circle = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1) * radius  # (n, 3) body
    unit = _ROTORS_UNIT if layout is None else _rotors_unit(layout)
    body = unit[:, None, :] * arm_length + circle[None]  # (M, n, 3)
    return s[POS] + body @ rot.T


def arm_length_of(arm_length: float | str | None) -> float:
    """The true arm length in m: a number as given, a preset name ("seed", "crazyflie") looked up
    in `core.params`, None the seed vehicle's (quad-sitl's default airframe)."""
    if arm_length is None:
        return SEED_VEHICLE.arm
    if isinstance(arm_length, str):
        return get_preset(arm_length).arm
    arm = float(arm_length)
    if not (math.isfinite(arm) and arm > 0):
        raise ValueError(f"arm_length must be a positive number of metres, got {arm_length!r}")
    return arm


def display_arm(arm_length: float, view_width: float) -> tuple[float, float]:
    """(drawn arm length, factor): the true arm, or the arm × `EXAGGERATION` when the true arm is
    shorter than `VISIBLE_FRACTION` of the view's width (a 0.1 m arm in a 4 m circle would be a
    few pixels in a 480×360 GIF)."""
    factor = EXAGGERATION if arm_length < VISIBLE_FRACTION * view_width else 1.0
    return arm_length * factor, factor
