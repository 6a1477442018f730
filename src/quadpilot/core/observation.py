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

The commanded heading (version 2 of both layouts): a vehicle must hold a heading, so the policy
must see its yaw relative to the one commanded. In the version-2 layouts the "rot" field is the
attitude relative to the heading frame, the world ENU frame turned about z by the commanded heading
ψ_cmd: Rz(−ψ_cmd)·R, which is the rotation matrix of (roll, pitch, yaw − ψ_cmd). Everything else is
in the body frame and does not change. With ψ_cmd = 0 the two versions are the same numbers, so a
version-1 policy (trained with no heading to hold) is flown with heading 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .frames import euler_to_rotmat, world_to_body
from .state import PITCH, POS, RATES, ROLL, STATE_DIM, VEL, YAW


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
    heading_frame: bool = False
    """"rot" is relative to the commanded heading (version 2), not to the world frame."""

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

    @property
    def tracks(self) -> bool:
        """The layout observes the moving target's velocity (the circle task)."""
        return any(f.name == "target_vel" for f in self.fields)


def _base(rot: str) -> tuple[ObsField, ...]:
    return (
        ObsField("pos_error", 3, "m", "position minus target position, body FLU: Rᵀ·(p − p_target)"),
        ObsField("vel", 3, "m/s", "velocity, body FLU: Rᵀ·v"),
        ObsField("rot", 9, "1", rot),
        ObsField("rates", 3, "rad/s", "body rates p, q, r, FLU"),
    )


_TARGET_VEL = ObsField("target_vel", 3, "m/s", "velocity of the moving target, body FLU: Rᵀ·v_target")
_WORLD_ROT = "rotation matrix body FLU → world ENU, row-major (R11, R12, …, R33)"
_HEADING_ROT = (
    "rotation matrix body FLU → heading frame (world ENU turned by the commanded heading ψ_cmd about z): "
    "Rz(−ψ_cmd)·R, row-major"
)
HOVER_LAYOUT_V1 = ObsLayout("quadpilot.obs.hover/1", _base(_WORLD_ROT))
TRACK_LAYOUT_V1 = ObsLayout("quadpilot.obs.track/1", (*_base(_WORLD_ROT), _TARGET_VEL))
HOVER_LAYOUT = ObsLayout("quadpilot.obs.hover/2", _base(_HEADING_ROT), heading_frame=True)
TRACK_LAYOUT = ObsLayout("quadpilot.obs.track/2", (*_base(_HEADING_ROT), _TARGET_VEL), heading_frame=True)
"""The layouts the environments build today; the version-1 layouts are still flown."""
LAYOUTS: dict[str, ObsLayout] = {
    layout.name: layout for layout in (HOVER_LAYOUT_V1, TRACK_LAYOUT_V1, HOVER_LAYOUT, TRACK_LAYOUT)
}


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
    heading=None,
) -> np.ndarray:
    """Observations (N, 18) for the hover layout, or (N, 21) for the track layout when
    `target_vel` is given. state (N, 12); target_pos and target_vel (N, 3) or (3,).
    heading: the commanded heading ψ_cmd in rad (ENU yaw, 0 = east), a scalar or (N,), for the
    version-2 layouts; None: 0, the world frame (version 1, or version 2 commanded to face east).
    Written into `out` if given (its dtype wins), else float32."""
    n = state.shape[0]
    if state.ndim != 2 or state.shape[1] != STATE_DIM:
        raise ValueError(f"state must have shape (N, {STATE_DIM}), got {state.shape}")
    layout = HOVER_LAYOUT if target_vel is None else TRACK_LAYOUT
    if out is None:
        out = np.empty((n, layout.dim), dtype=np.float32)
    elif out.shape != (n, layout.dim):
        raise ValueError(f"out must have shape ({n}, {layout.dim}), got {out.shape}")
    rot = euler_to_rotmat(state[:, ROLL], state[:, PITCH], state[:, YAW])
    out[:, 0:3] = world_to_body(rot, state[:, POS] - target_pos)
    out[:, 3:6] = world_to_body(rot, state[:, VEL])
    if heading is None:
        out[:, 6:15] = rot.reshape(n, 9)
    else:  # Rz(−ψ_cmd)·R: the first two rows turned by −ψ_cmd, the third unchanged
        c = np.cos(heading)
        s = np.sin(heading)
        c = np.broadcast_to(c, (n,))[:, None]
        s = np.broadcast_to(s, (n,))[:, None]
        out[:, 6:9] = c * rot[:, 0, :] + s * rot[:, 1, :]
        out[:, 9:12] = -s * rot[:, 0, :] + c * rot[:, 1, :]
        out[:, 12:15] = rot[:, 2, :]
    out[:, 15:18] = state[:, RATES]
    if target_vel is not None:
        out[:, 18:21] = world_to_body(rot, np.broadcast_to(target_vel, (n, 3)))
    return out
