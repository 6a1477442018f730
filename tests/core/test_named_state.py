"""The 12-state is named in one place, `quadpilot.core.state`, and read through those names.

Two parts: the names agree with `STATE_NAMES`/`IDX` and with the table in `core.state`'s docstring
(the four slices cover 0..11 exactly once), and a scan of `src/quadpilot` with `ast` finds no
12-state indexed with a bare number outside `core/state.py`.

The scan cannot know an array's shape, so it goes by the name of what is subscripted: the last
identifier of the subscripted expression (`state`, `self.state`, `batch.state`, `flight.states`)
is one of STATE_VARS, the names this code base gives its 12-state arrays (found by reading every
numeric subscript in src/quadpilot). It flags a subscript whose index, or the last element of a
tuple index (the state axis is last: `states[:, 8]`, `flight.states[0, :, 8]`), is an integer
constant −12..11 or a slice whose constant bounds lie within −12..12 (`6:9`, `:3`, `9:`). The few
subscripts of such names that are not state indices are listed in ALLOWED with the reason.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np

from quadpilot.core import dynamics, state
from quadpilot.core.state import (
    ATT,
    IDX,
    PITCH,
    POS,
    POS_XY,
    RATES,
    ROLL,
    ROLL_PITCH,
    STATE_DIM,
    STATE_NAMES,
    VEL,
    YAW,
    R,
    X,
    Y,
    Z,
)

SRC = Path(state.__file__).resolve().parents[1]  # src/quadpilot
DEFINING_MODULE = "core/state.py"

# The names 12-state arrays go by in src/quadpilot: (N, 12) batches, (12,) single states, (T, N, 12)
# and (T, 12) histories, and the start states.
STATE_VARS = frozenset({"state", "states", "s", "new", "before", "starts"})
# Per file, a name that holds a 12-state there only (elsewhere it is an observation or a result).
STATE_VARS_IN = {"core/sensor_noise.py": frozenset({"out"})}  # SensorNoise.estimate's copy of the state

# (file, subscript as ast.unparse writes it) → why it is not a 12-state index.
ALLOWED = {
    ("simulator/plant.py", "s[0]"): "row 0 of dynamics.step's (1, 12) result",
    ("simulator/config.py", "s[0]"): "row 0 of sample_start_states' (1, 12) result",
    ("export/onnx_export.py", "starts[0]"): "time 0 of the (steps, sequences) episode-start flags",
    ("export/onnx_export.py", "state[0]"): "h of a recurrent policy's (h, c) state",
    ("export/onnx_export.py", "state[1]"): "c of a recurrent policy's (h, c) state",
    ("studies/learning_montage.py", "s[0]"): "the step count of a (step, path) snapshot",
    ("studies/learning_montage.py", "batch.state[0]"): "row 0 (the one drone) of an (N, 12) batch",
    ("studies/robustness.py", "states[0]"): "time 0 of a (T + 1, N, 12) history",
}


def _int(node: ast.expr) -> int | None:
    if isinstance(node, ast.Constant) and type(node.value) is int:
        return node.value
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        inner = _int(node.operand)
        return None if inner is None else -inner
    return None


def _bare_state_index(index: ast.expr) -> bool:
    if isinstance(index, ast.Tuple):
        if not index.elts:
            return False
        index = index.elts[-1]
    value = _int(index)
    if value is not None:
        return -STATE_DIM <= value < STATE_DIM
    if isinstance(index, ast.Slice):
        bounds = [b for b in (index.lower, index.upper) if b is not None]
        values = [_int(b) for b in bounds]
        return bool(bounds) and all(v is not None and -STATE_DIM <= v <= STATE_DIM for v in values)
    return False


def _last_name(node: ast.expr) -> str | None:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    return None


def bare_state_indices(source: str, rel: str) -> list[tuple[int, str]]:
    """(line, subscript) of every 12-state indexed with a bare number in `source` (file `rel`,
    relative to src/quadpilot), ALLOWED ones left out."""
    names = STATE_VARS | STATE_VARS_IN.get(rel, frozenset())
    hits = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Subscript) and _last_name(node.value) in names and _bare_state_index(node.slice):
            text = ast.unparse(node)
            if (rel, text) not in ALLOWED:
                hits.append((node.lineno, text))
    return sorted(hits)


def _sources() -> dict[str, str]:
    files = {p.relative_to(SRC).as_posix(): p.read_text(encoding="utf-8") for p in sorted(SRC.rglob("*.py"))}
    assert DEFINING_MODULE in files and len(files) > 50, f"scanned {len(files)} files under {SRC}"
    return files


# --- the names ------------------------------------------------------------------------------------


def test_scalar_names_match_state_names_and_idx():
    assert len(STATE_NAMES) == STATE_DIM == 12
    assert IDX == {name: i for i, name in enumerate(STATE_NAMES)}
    for i, name in enumerate(STATE_NAMES):
        assert getattr(state, name.upper()) == i == IDX[name], name


def test_slices_cover_the_state_once_in_order():
    covered = [i for sl in (POS, VEL, ATT, RATES) for i in range(STATE_DIM)[sl]]
    assert covered == list(range(STATE_DIM))
    assert [STATE_NAMES[i] for i in range(STATE_DIM)[POS]] == ["x", "y", "z"]
    assert [STATE_NAMES[i] for i in range(STATE_DIM)[VEL]] == ["vx", "vy", "vz"]
    assert [STATE_NAMES[i] for i in range(STATE_DIM)[ATT]] == ["roll", "pitch", "yaw"]
    assert [STATE_NAMES[i] for i in range(STATE_DIM)[RATES]] == ["p", "q", "r"]
    assert list(range(STATE_DIM)[POS_XY]) == [X, Y]
    assert list(range(STATE_DIM)[ROLL_PITCH]) == [ROLL, PITCH]
    for sl in (POS, VEL, ATT, RATES, POS_XY, ROLL_PITCH):  # plain slices: a view, as the literal gives
        assert type(sl) is slice and sl.step is None


def test_dynamics_reexports_the_same_objects():
    for name in ("STATE_DIM", "STATE_NAMES", "IDX", "POS", "VEL", "ATT", "RATES"):
        assert getattr(dynamics, name) is getattr(state, name), name


def test_docstring_table_matches_the_names():
    """Each row `index NAME SLICE quantity...` of core.state's table agrees with the constants."""
    rows = re.findall(r"^\s+(\d+)\s+([A-Z]+)\s+(POS|VEL|ATT|RATES)\s", state.__doc__, flags=re.MULTILINE)
    assert [int(i) for i, _, _ in rows] == list(range(STATE_DIM))
    for i, name, sl in rows:
        assert getattr(state, name) == int(i) and name.lower() == STATE_NAMES[int(i)]
        assert int(i) in range(STATE_DIM)[getattr(state, sl)], (name, sl)


def test_names_index_like_the_literals():
    a = np.arange(2 * 3 * STATE_DIM, dtype=np.float32).reshape(2, 3, STATE_DIM)
    assert np.array_equal(a[..., POS], a[..., 0:3]) and np.shares_memory(a[..., POS], a)
    assert np.array_equal(a[:, :, YAW], a[:, :, 8]) and a[..., R].dtype == np.float32
    assert np.array_equal(a[..., ROLL : R + 1], a[..., 6:12]) and np.array_equal(a[..., Z], a[..., 2])


# --- the scan -------------------------------------------------------------------------------------


def test_no_bare_state_index_in_src():
    found = {rel: bare_state_indices(src, rel) for rel, src in _sources().items() if rel != DEFINING_MODULE}
    found = {rel: hits for rel, hits in found.items() if hits}
    assert not found, f"12-state indexed with bare numbers (use quadpilot.core.state's names): {found}"


def test_allow_list_is_current():
    """Every ALLOWED entry still names a subscript in its file: a stale entry would hide a new one."""
    sources = _sources()
    for rel, text in ALLOWED:
        present = {ast.unparse(n) for n in ast.walk(ast.parse(sources[rel])) if isinstance(n, ast.Subscript)}
        assert text in present, f"ALLOWED entry {text!r} no longer in {rel}"


BARE = [
    "state[:, 6:9]",
    "state[..., 8]",
    "self.state[2]",
    "batch.state[:, 0:3]",
    "flight.states[0, :, 11]",
    "states[-1, 8]",
    "s[3:6]",
    "s[:3]",
    "s[9:]",
    "new[-1]",
]
NAMED = ["state[:, ATT]", "states[..., YAW]", "s[POS]", "s[ROLL : R + 1]", "state.shape[0]", "obs[:, 6:9]"]


def test_scan_catches_bare_indices_and_passes_names():
    for expr in BARE:
        assert bare_state_indices(f"x = {expr}\n", "anywhere.py"), expr
    for expr in NAMED:
        assert not bare_state_indices(f"x = {expr}\n", "anywhere.py"), expr


def test_scan_catches_a_bare_index_written_into_a_real_module():
    """The regression the scan is for: `state[:, 6:9]` written again into core/reward.py (in memory)."""
    rel = "core/reward.py"
    src = _sources()[rel]
    assert bare_state_indices(src, rel) == []
    broken = src + "\n\ndef _tilt_again(state):\n    return state[:, 6:9]\n"
    assert bare_state_indices(broken, rel) == [(len(src.splitlines()) + 4, "state[:, 6:9]")]
