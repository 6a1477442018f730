"""The observation layout: one named table, and the one function that builds observations.

The environments and the runtime both call `build_observation`, and the layout name travels in the
checkpoint and in the ONNX metadata; a runtime refuses a layout it does not know.

Why not the raw 12 states: absolute position would tie a policy to the place it was trained at
(hovering at (0, 0, 10) would be out of distribution for a policy trained at (0, 0, 2)), so
position enters as the error to the target, which is the position up to the known target. Raw yaw
jumps at ±π once yaw is uniform; the attitude enters as the rotation matrix, which is continuous
and gives roll and pitch without ambiguity. Position error, velocity and target velocity are
expressed in the body frame (Rᵀ·v): with yaw uniform, a world-frame error forces the network to
learn the rotation into the body frame itself (a product of inputs, slow for a small MLP);
measured on hover, the body-frame layout learned markedly faster.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dynamics import STATE_DIM
from .frames import euler_to_rotmat, world_to_body


@dataclass(frozen=True)
class ObsField:
    name: str
    size: int
    unit: str
    meaning: str


@dataclass(frozen=True)
class ObsLayout:
    name: str
    """Versioned identifier, stored in checkpoints and ONNX metadata."""
    fields: tuple[ObsField, ...]

    @property
    def dim(self) -> int:
        return sum(f.size for f in self.fields)

    def slices(self) -> dict[str, slice]:
        out, i = {}, 0
        for f in self.fields:
            out[f.name] = slice(i, i + f.size)
            i += f.size
        return out

    def to_json(self) -> dict:
        return {"name": self.name, "fields": [f.__dict__ for f in self.fields]}


_BASE = (
    ObsField("pos_error", 3, "m", "position minus target position, body FLU: Rᵀ·(p − p_target)"),
    ObsField("vel", 3, "m/s", "velocity, body FLU: Rᵀ·v"),
    ObsField("rot", 9, "1", "rotation matrix body FLU → world ENU, row-major (R11, R12, …, R33)"),
    ObsField("rates", 3, "rad/s", "body rates p, q, r, FLU"),
)
HOVER_LAYOUT = ObsLayout("quadpilot.obs.hover/1", _BASE)
TRACK_LAYOUT = ObsLayout(
    "quadpilot.obs.track/1",
    (*_BASE, ObsField("target_vel", 3, "m/s", "velocity of the moving target, body FLU: Rᵀ·v_target")),
)
LAYOUTS: dict[str, ObsLayout] = {layout.name: layout for layout in (HOVER_LAYOUT, TRACK_LAYOUT)}


def get_layout(name: str) -> ObsLayout:
    try:
        return LAYOUTS[name]
    except KeyError:
        raise ValueError(f"unknown observation layout {name!r}; this version knows {sorted(LAYOUTS)}") from None


def build_observation(
    state: np.ndarray,
    target_pos: np.ndarray,
    target_vel: np.ndarray | None = None,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Observations (N, 18) for the hover layout, or (N, 21) for the track layout when
    `target_vel` is given. state (N, 12); target_pos and target_vel (N, 3) or (3,).
    Written into `out` if given (its dtype wins), else float32."""
    n = state.shape[0]
    if state.ndim != 2 or state.shape[1] != STATE_DIM:
        raise ValueError(f"state must have shape (N, {STATE_DIM}), got {state.shape}")
    layout = HOVER_LAYOUT if target_vel is None else TRACK_LAYOUT
    if out is None:
        out = np.empty((n, layout.dim), dtype=np.float32)
    elif out.shape != (n, layout.dim):
        raise ValueError(f"out must have shape ({n}, {layout.dim}), got {out.shape}")
    rot = euler_to_rotmat(state[:, 6], state[:, 7], state[:, 8])
    out[:, 0:3] = world_to_body(rot, state[:, 0:3] - target_pos)
    out[:, 3:6] = world_to_body(rot, state[:, 3:6])
    out[:, 6:15] = rot.reshape(n, 9)
    out[:, 15:18] = state[:, 9:12]
    if target_vel is not None:
        out[:, 18:21] = world_to_body(rot, np.broadcast_to(target_vel, (n, 3)))
    return out
