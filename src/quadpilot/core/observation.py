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

from .frames import euler_to_rotmat, euler_to_rotmat_rows, world_to_body, world_to_body_rows
from .state import ATT, PITCH, POS, RATES, ROLL, STATE_DIM, VEL, YAW


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


class ObservationBuilder:
    """`build_observation` in place, for a batch that builds N observations every step: it reads the
    states as rows (12, k), and every intermediate lives in storage allocated here once (for up to
    `n` states), so a build allocates no array.

    Bit for bit `build_observation`: the same operations in the same order (`frames.euler_to_rotmat_rows`,
    `frames.world_to_body_rows`), each writing into a buffer (a ufunc computes the same bits wherever
    it writes); tests/core/test_inplace_equivalence.py checks the two against each other. After a
    build of k states, `last` holds its arrays: `sin`, `cos` (3, k) of roll, pitch and yaw, `rot`
    (3, 3, k) the rotation matrices (rot[j, i] = R_ji) and `vec` (3, k) the position error rows,
    for a caller that needs them too (until the next build).

    The rows of a build of k states are (r, k) arrays laid on flat storage, so each is contiguous:
    NumPy runs a ufunc over contiguous operands of one shape as one loop, where a broadcast or a
    strided 2-D operand makes it allocate a buffer of 8192 elements and loop per row. So every
    operation here is over such blocks or over single rows.

    Why the detour through `fields` and `units`: an observation is a row of 18 (or 21) float32, and
    NumPy writes a column of an (N, 18) array element by element, about 1 ns each, where a
    contiguous ufunc takes a fifth of that. So each field is computed into a row of `fields`, two
    rows at a time are interleaved into one row of 8-byte units (field 2g's four bytes, then
    2g + 1's: two copies at a stride of 8 bytes), and the units are moved into `out` in one copy:
    half the elements of moving the floats."""

    GROUPS = 11  # pairs of fields: 21 fields (the track layout) and one row to spare

    def __init__(self, n: int, dtype) -> None:
        self.n, self.dtype = int(n), np.dtype(dtype)
        flat = lambda rows, dt=self.dtype: np.zeros(rows * self.n, dt)  # noqa: E731
        self._store = {
            "sin": flat(3),
            "cos": flat(3),
            "rot": flat(9),
            "vec": flat(3),
            "block": flat(3),
            "tmp": flat(3),
            "heading": flat(3),
            "fields": flat(2 * self.GROUPS, np.float32),
            "units": flat(self.GROUPS, np.uint64),
        }
        if self.dtype != np.float32:  # fields computed in the state dtype, then cast in one copy
            self._store["wide"] = flat(2 * self.GROUPS)
        self._works: dict[int, _ObsWork] = {}
        self.last: _ObsWork | None = None

    def build(
        self,
        s: np.ndarray,
        target_pos: np.ndarray,
        out,
        target_vel: np.ndarray | None = None,
        heading: np.ndarray | None = None,
    ):
        """`build_observation(states, target_pos, target_vel, out, heading)` for the k ≤ n states
        whose rows are s (12, k) (contiguous rows); target_pos and target_vel (k, 3), heading (k,)
        in the state dtype or None. out: float32 (k, 18) or (k, 21), or a sequence of such arrays
        that take the k observations in turn (rows 0..k1 − 1 into the first, and so on)."""
        k = s.shape[1] if s.ndim == 2 else -1
        dim = (HOVER_LAYOUT if target_vel is None else TRACK_LAYOUT).dim
        if s.shape != (STATE_DIM, k) or not 0 < k <= self.n:
            raise ValueError(f"state rows must have shape ({STATE_DIM}, k), 0 < k ≤ {self.n}, got {s.shape}")
        parts = (out,) if isinstance(out, np.ndarray) else tuple(out)
        if sum(p.shape[0] for p in parts) != k or any(p.shape[1:] != (dim,) or p.dtype != np.float32 for p in parts):
            raise ValueError(f"out must be float32 of {k} rows of {dim}, got {[(p.dtype, p.shape) for p in parts]}")
        w = self._works.get(k)
        if w is None:  # a batch builds a few sizes (all, all + the drones reset): keep their views
            if len(self._works) >= 256:
                self._works.clear()
            w = self._works[k] = _ObsWork(self._store, k)
        self.last = w
        rot, v, tmp, blk, f = w.rot, w.vec, w.tmp, w.block, w.wide
        np.sin(s[ATT], w.sin)
        np.cos(s[ATT], w.cos)
        euler_to_rotmat_rows(w.sin, w.cos, rot, w.tmp0)
        target_pos = np.asarray(target_pos)
        for i, row in enumerate(POS_ROWS):  # state[:, POS] − target_pos
            np.subtract(s[row], target_pos[:, i], v[i])
        world_to_body_rows(rot, v, f[0:3], blk, tmp)
        world_to_body_rows(rot, s[VEL], f[3:6], blk, tmp)
        r0, r1, r2 = w.rot_rows
        if heading is None:
            np.positive(rot, f[6:15].reshape(3, 3, k))
        else:  # Rz(−ψ_cmd)·R: rows c·R0 + s·R1 and (−s)·R0 + c·R1, then R2
            c, sn, neg = w.heading_rows
            np.cos(heading, c)
            np.sin(heading, sn)
            np.negative(sn, neg)
            for i in range(3):
                np.multiply(c, r0[i], blk[i])
                np.multiply(sn, r1[i], tmp[i])
            np.add(blk, tmp, f[6:9])
            for i in range(3):
                np.multiply(neg, r0[i], blk[i])
                np.multiply(c, r1[i], tmp[i])
            np.add(blk, tmp, f[9:12])
            np.positive(r2, f[12:15])
        np.positive(s[RATES], f[15:18])
        if target_vel is not None:
            world_to_body_rows(rot, np.asarray(target_vel).T, f[18:21], blk, tmp)
        if f is not w.fields:  # float64 state: the observation is float32, cast as an assignment casts
            np.copyto(w.fields[:dim], f[:dim], casting="same_kind")
        _merge_and_move(w, dim, parts)
        return out


POS_ROWS = tuple(range(POS.start, POS.stop))


class _ObsWork:
    """An ObservationBuilder's arrays for k states: (r, k) contiguous views of its flat storage."""

    def __init__(self, store: dict, k: int) -> None:
        def rows(name: str, r: int) -> np.ndarray:
            return store[name][: r * k].reshape(r, k)

        self.sin, self.cos, self.vec, self.block, self.tmp = (rows(a, 3) for a in ("sin", "cos", "vec", "block", "tmp"))
        self.rot = rows("rot", 9).reshape(3, 3, k)
        self.fields = rows("fields", 2 * ObservationBuilder.GROUPS)  # (22, k) float32
        self.wide = rows("wide", 2 * ObservationBuilder.GROUPS) if "wide" in store else self.fields
        self.tmp0 = self.tmp[0]
        self.rot_rows = tuple(self.rot)
        self.heading_rows = tuple(rows("heading", 3))
        bits = self.fields.view(np.uint32)
        self.first, self.second = bits[0::2], bits[1::2]  # fields 2g and 2g + 1, (G, k)
        self.units = rows("units", ObservationBuilder.GROUPS)  # (G, k) 8-byte units
        halves = self.units.view(np.uint32).reshape(ObservationBuilder.GROUPS, k, 2)
        self.low, self.high = halves[..., 0], halves[..., 1]  # the first and last 4 bytes of each unit


def _merge_and_move(w: _ObsWork, dim: int, parts: tuple) -> None:
    """Each pair of field rows (2g, 2g + 1) merged into one row of 8-byte units (field 2g's bytes
    first, as in an observation row), moved into the observation rows of `parts`: bit copies, the
    same bytes as writing the float32 one by one."""
    pairs = dim // 2
    units = w.units[:pairs]
    np.copyto(w.low[:pairs], w.first[:pairs])
    np.copyto(w.high[:pairs], w.second[:pairs])
    start = 0
    for out in parts:
        stop = start + out.shape[0]
        if out.flags.c_contiguous:
            np.copyto(out[:, : 2 * pairs].view(np.uint64), units[:, start:stop].T)
            if dim % 2:
                np.copyto(out[:, dim - 1], w.fields[dim - 1, start:stop])
        else:  # pragma: no cover - the batches' observations are C-contiguous
            np.copyto(out, w.fields[:dim, start:stop].T)
        start = stop
