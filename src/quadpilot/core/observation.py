"""The observation layout: one named table, and the one function that computes observations.

`observation_values` is the layout's arithmetic, written once over any number type: `build_observation`
runs it on the columns of a batch, `runtime.observation_one` on the plain floats of the node's one
vehicle (NumPy's per-call overhead dominates on one drone), and `ObservationBuilder` is the same
operations in place, for the training batches that build every step without allocating
(tests/core/test_inplace_equivalence.py holds it to `build_observation` bit for bit). The layout name
travels in the checkpoint and in the ONNX metadata; a runtime refuses a layout it does not know.

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

from .frames import euler_to_rotmat_rows, rotation_entries, to_body, world_to_body_rows
from .state import ATT, POS, RATES, STATE_DIM, VEL


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
    Written into `out` if given (its dtype wins), else float32. `observation_values` on the columns."""
    n = state.shape[0]
    if state.ndim != 2 or state.shape[1] != STATE_DIM:
        raise ValueError(f"state must have shape (N, {STATE_DIM}), got {state.shape}")
    layout = HOVER_LAYOUT if target_vel is None else TRACK_LAYOUT
    if out is None:
        out = np.empty((n, layout.dim), dtype=np.float32)
    elif out.shape != (n, layout.dim):
        raise ValueError(f"out must have shape ({n}, {layout.dim}), got {out.shape}")
    tv = None if target_vel is None else np.asarray(target_vel).T
    values = observation_values(np.sin, np.cos, state.T, np.asarray(target_pos).T, tv, heading)
    for j, column in enumerate(values):  # each rounded into out as an assignment rounds
        out[:, j] = column
    return out


def observation_values(sin, cos, state, target, target_vel=None, heading=None) -> list:
    """The hover layout's 18 values, or the track layout's 21 with a target velocity, written once for
    any number type: `state` the 12 state values (x, y, z, vx, vy, vz, roll, pitch, yaw, p, q, r;
    ENU/FLU, SI), `target` and `target_vel` 3 values each (ENU), `heading` ψ_cmd (rad) or None (the
    world frame: version 1), each a plain float or a column of a batch (an array, broadcast), with
    `sin` and `cos` to suit (math's for floats, NumPy's for arrays). In the state's precision; the
    caller rounds to float32."""
    x, y, z, vx, vy, vz, roll, pitch, yaw, p, q, r = state
    tx, ty, tz = target
    rot = rotation_entries(sin, cos, roll, pitch, yaw)
    turned = rot[0] + rot[1] + rot[2] if heading is None else heading_turned(rot, cos(heading), sin(heading))
    out = [*to_body(rot, (x - tx, y - ty, z - tz)), *to_body(rot, (vx, vy, vz)), *turned, p, q, r]
    if target_vel is not None:
        out += to_body(rot, target_vel)
    return out


def heading_turned(rot, c, s) -> tuple:
    """The nine entries, row-major, of Rz(−ψ)·R for rotation entries `rot` (`frames.rotation_entries`)
    and c = cos ψ, s = sin ψ: rows c·R0 + s·R1 and (−s)·R0 + c·R1, then R2 (floats or arrays)."""
    (r00, r01, r02), (r10, r11, r12), row2 = rot
    ns = -s
    return (
        c * r00 + s * r10,
        c * r01 + s * r11,
        c * r02 + s * r12,
        ns * r00 + c * r10,
        ns * r01 + c * r11,
        ns * r02 + c * r12,
        *row2,
    )


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

    Why the detour through `fields`: an observation is a row of 18 (or 21) float32, and NumPy
    writes a column of an (N, 18) array element by element, about 1 ns each, where a contiguous
    ufunc takes a fifth of that. So each field is computed into a row of `fields` (a row per call:
    see below), and the rows are moved into `out` in one transposing copy, which reads the 18 rows
    side by side. Those rows lie `_stride(k)` elements apart, k rounded up to 64 bytes and kept off
    a multiple of 2 KiB: rows a multiple of 4 KiB apart (k = 1024, 2048, 4096 float32) all fall in
    one set of the CPU's cache, which made that copy several times slower at N = 4096, and rows at
    an odd 4-byte offset make it slower too. So `fields` is not one contiguous block: a ufunc writes
    into it a row at a time (np.einsum and np.copyto take its blocks of rows without a buffer)."""

    FIELDS = 21  # the track layout's

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
            "fields": np.zeros(self.FIELDS * _stride(self.n), np.float32),
        }
        if self.dtype != np.float32:  # fields computed in the state dtype, then cast in one copy
            self._store["wide"] = flat(self.FIELDS)
        self._works: dict[int, _ObsWork] = {}
        self.last: _ObsWork | None = None

    def build(
        self,
        s: np.ndarray,
        target_pos: np.ndarray,
        out,
        target_vel: np.ndarray | None = None,
        heading: np.ndarray | None = None,
        target_rows: np.ndarray | None = None,
    ):
        """`build_observation(states, target_pos, target_vel, out, heading)` for the k ≤ n states
        whose rows are s (12, k) (contiguous rows); target_pos and target_vel (k, 3), heading (k,)
        in the state dtype or None. out: float32 (k, 18) or (k, 21), or a sequence of such arrays
        that take the k observations in turn (rows 0..k1 − 1 into the first, and so on).
        target_rows: the target positions as rows (3, k) (a contiguous block), for a caller that
        keeps them so (the batches), instead of target_pos (then None): the same subtraction as one
        call over contiguous operands, where a column of a (k, 3) array is read at a stride."""
        k = s.shape[1] if s.ndim == 2 else -1
        dim = (HOVER_LAYOUT if target_vel is None else TRACK_LAYOUT).dim
        if s.shape != (STATE_DIM, k) or not 0 < k <= self.n:
            raise ValueError(f"state rows must have shape ({STATE_DIM}, k), 0 < k ≤ {self.n}, got {s.shape}")
        parts = (out,) if isinstance(out, np.ndarray) else tuple(out)
        rows = 0
        for p in parts:  # (a loop: a generator's frames cost more than the checks)
            if p.shape[1:] != (dim,) or p.dtype != np.float32:
                rows = -1
                break
            rows += p.shape[0]
        if rows != k:
            raise ValueError(f"out must be float32 of {k} rows of {dim}, got {[(p.dtype, p.shape) for p in parts]}")
        w = self._works.get(k)
        if w is None:  # a batch builds a few sizes (all, all + the drones reset): keep their views
            if len(self._works) >= 256:
                self._works.clear()
            w = self._works[k] = _ObsWork(self._store, k)
        self.last = w
        if w.state is not s:  # the views of the state read below, made once per state array
            w.state, w.state_views = s, (s[ATT], s[POS], s[VEL], s[RATES])
        att, pos, vel, rates = w.state_views
        rot, v, wide = w.rot, w.vec, w.wide
        np.sin(att, w.sin)
        np.cos(att, w.cos)
        # with the rows as views made once (rot_rows[j][i] = R_ji), see `euler_to_rotmat_rows`
        euler_to_rotmat_rows(w.sin_rows, w.cos_rows, w.rot_rows, w.tmp0)
        if target_rows is not None:  # state[:, POS] − target_pos, elementwise: the same bits in any layout
            np.subtract(pos, target_rows, v)
        else:
            target_pos = np.asarray(target_pos)
            for i, row in enumerate(POS_ROWS):
                np.subtract(s[row], target_pos[:, i], v[i])
        world_to_body_rows(rot, v, wide[0:3])
        world_to_body_rows(rot, vel, wide[3:6])
        # the fields that are plain copies in `build_observation` (an assignment) are copied: copyto
        # moves the same bits, at a third of np.positive's cost
        if heading is None:
            np.copyto(wide[6:15], rot.reshape(9, k))  # (rot is contiguous: a view)
        else:  # Rz(−ψ_cmd)·R: rows c·R0 + s·R1 and (−s)·R0 + c·R1, then R2
            c, sn, neg = w.heading_rows
            (r0, r1, _), (b, t), f = w.rot_rows, w.scratch_rows, w.field_rows
            np.cos(heading, c)
            np.sin(heading, sn)
            np.negative(sn, neg)
            for i in range(3):
                np.multiply(c, r0[i], b[i])
                np.multiply(sn, r1[i], t[i])
            for i, row in f[6:9]:
                np.add(b[i], t[i], row)
            for i in range(3):
                np.multiply(neg, r0[i], b[i])
                np.multiply(c, r1[i], t[i])
            for i, row in f[9:12]:
                np.add(b[i], t[i], row)
            np.copyto(wide[12:15], rot[2])
        np.copyto(wide[15:18], rates)
        if target_vel is not None:
            world_to_body_rows(rot, np.asarray(target_vel).T, wide[18:21])
        fields = w.fields
        if wide is not fields:  # float64 state: the observation is float32, cast as an assignment casts
            np.copyto(fields[:dim], wide[:dim], casting="same_kind")
        start = 0
        for part in parts:  # the bits of each field moved into the observations' columns
            stop = start + part.shape[0]
            np.copyto(part, fields[:dim, start:stop].T)
            start = stop
        return out


POS_ROWS = tuple(range(POS.start, POS.stop))


def _stride(k: int) -> int:
    """The distance between the rows of `fields` for k states: k rounded up to 16 float32 (64 bytes),
    and 16 more if that is a multiple of 512 (2 KiB), see `ObservationBuilder`."""
    stride = -(-k // 16) * 16
    return stride + 16 if stride % 512 == 0 else stride


class _ObsWork:
    """An ObservationBuilder's arrays for k states: (r, k) contiguous views of its flat storage."""

    def __init__(self, store: dict, k: int) -> None:
        def rows(name: str, r: int) -> np.ndarray:
            return store[name][: r * k].reshape(r, k)

        self.sin, self.cos, self.vec, self.block, self.tmp = (rows(a, 3) for a in ("sin", "cos", "vec", "block", "tmp"))
        self.rot = rows("rot", 9).reshape(3, 3, k)
        fields = ObservationBuilder.FIELDS
        # (21, k) float32 rows `_stride(k)` apart: not one block, written a row at a time
        self.fields = store["fields"][: fields * _stride(k)].reshape(fields, -1)[:, :k]
        # the rows the fields are computed in: `fields` itself, or contiguous rows of the state dtype
        self.wide = rows("wide", fields) if "wide" in store else self.fields
        # (i, row) of each field, i its place in its 3-vector
        self.field_rows = tuple((i % 3, row) for i, row in enumerate(self.wide))
        self.tmp0 = self.tmp[0]
        # rows taken apart once: taking a row of an array costs about a fifth of a small NumPy call
        self.rot_rows = tuple(tuple(r) for r in self.rot)  # rot_rows[j][i] = R_ji
        self.sin_rows, self.cos_rows = tuple(self.sin), tuple(self.cos)
        self.scratch_rows = (tuple(self.block), tuple(self.tmp))
        self.heading_rows = tuple(rows("heading", 3))
        self.state, self.state_views = None, ()  # the state rows last built from, and views of them
        self._trig: tuple = (0, ())

    def trig(self, n: int) -> tuple:
        """The rows of sin, cos and the thrust axis (R02, R12, R22) of the first n states of the last
        build, three tuples of three rows, what `dynamics.Stepper.step` takes as `trig` (made once)."""
        if self._trig[0] != n:
            self._trig = (n, (tuple(self.sin[:, :n]), tuple(self.cos[:, :n]), tuple(self.rot[:, 2, :n])))
        return self._trig[1]
