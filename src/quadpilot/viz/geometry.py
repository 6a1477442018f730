"""Where the drawn quadrotor's parts are: pure NumPy, tested against known attitudes.

The rotor layout is `core.dynamics.MOTOR_LAYOUT` (PX4 quad-X, arms at ±45° in the body FLU frame)
and the rotation is `core.frames.euler_to_rotmat` (R = Rz(yaw)·Ry(pitch)·Rx(roll), body → world),
so the drawing and the model cannot disagree.
"""

from __future__ import annotations

import math

import numpy as np

from quadpilot.core.dynamics import ATT, MOTOR_LAYOUT, MOTOR_NAMES, POS, STATE_DIM
from quadpilot.core.frames import euler_to_rotmat
from quadpilot.core.params import SEED_VEHICLE, get_preset

# Rotor centres in the body frame for a unit arm: (x, y) = layout · 1/√2, z = 0, PX4 order.
_ROTORS_UNIT = np.array([[MOTOR_LAYOUT[m][0], MOTOR_LAYOUT[m][1], 0.0] for m in MOTOR_NAMES]) / math.sqrt(2.0)

EXAGGERATION = 3.0
"""How much `display_arm` lengthens the arms when the vehicle would be too small to see."""
VISIBLE_FRACTION = 0.04
"""Below this fraction of the view's width a true-size arm is exaggerated by `EXAGGERATION`."""


def body_points(state: np.ndarray, arm_length: float) -> np.ndarray:
    """Rotor centres in the world frame (m, ENU) of a vehicle with arms of `arm_length` m.

    state: (12,) or (N, 12) core state. Returns (4, 3) or (N, 4, 3), rotors in PX4 quad-X order
    (0 front-right, 1 rear-left, 2 front-left, 3 rear-right): p + R·b_i with
    b_i = arm·(±1/√2, ±1/√2, 0) in body FLU.
    """
    s = np.asarray(state, dtype=np.float64)
    if s.shape[-1:] != (STATE_DIM,) or s.ndim not in (1, 2):
        raise ValueError(f"body_points: state must have shape (12,) or (N, 12), got {s.shape}")
    att = s[..., ATT]
    rot = euler_to_rotmat(att[..., 0], att[..., 1], att[..., 2])  # (..., 3, 3)
    body = _ROTORS_UNIT * float(arm_length)  # (4, 3)
    return s[..., None, POS] + np.einsum("...ij,kj->...ki", rot, body)


def rotor_discs(state: np.ndarray, arm_length: float, radius: float, n: int = 16) -> np.ndarray:
    """(4, n, 3) world points of each rotor's disc outline: circles of `radius` m around the
    rotor centres, in the body x-y plane (so they tilt with the vehicle). state: (12,)."""
    s = np.asarray(state, dtype=np.float64)
    if s.shape != (STATE_DIM,):
        raise ValueError(f"rotor_discs: state must have shape (12,), got {s.shape}")
    rot = euler_to_rotmat(s[6], s[7], s[8])
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    circle = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1) * radius  # (n, 3) body
    body = _ROTORS_UNIT[:, None, :] * arm_length + circle[None]  # (4, n, 3)
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
