"""The files of a training run other than checkpoints: metrics.csv, JSON files, the run
directory's lock (curves.png, drawn from metrics.csv, is `train.runs.plotting`'s). Every file of a run
(checkpoints, replay chunks and snapshots too) is written whole or not at all by
`atomic_files.atomic_write`.

metrics.csv has a fixed header (`COLUMNS` for PPO; an algorithm names its own, `sac.COLUMNS`) and
one row per iteration (a PPO update), appended, flushed and fsync'd as soon as the iteration ends, so
a kill loses at most the row being written. A resumed run first cuts the file back to the
checkpoint's iteration count (`truncate_metrics`), so every iteration number appears once.

A run holds its directory's lock file (`LOCK`, flock(2), `lock_run_dir`) while it writes there, so
that a second run in the same directory is refused instead of interleaving its files with the
first's. The kernel drops the lock when the process ends however it ends (kill -9 included), so a
`--resume` after a crash never finds a stale lock.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path

import numpy as np

from quadpilot.atomic_files import atomic_write

COLUMNS = (
    "global_step",
    "update",
    "time_s",
    "policy_loss",
    "value_loss",
    "entropy",
    "approx_kl",
    "clip_fraction",
    "explained_variance",
    "grad_norm",
    "lr",
    "steps_per_s",
    "rollout_s",
    "env_s",
    "inference_s",
    "update_s",
    "ep_return",
    "ep_length",
    "success_rate",
    "episodes",
    "nonfinite_skipped",
    "curriculum_stage",
    "target_radius",
    "eval_success_rate",
    "eval_error_m",
)
HEADER = ",".join(COLUMNS)
LOCK = ".lock"
"""The run directory's lock file: empty but for the pid of the run holding it."""


# --- metrics.csv ----------------------------------------------------------------------------


def _cell(v) -> str:
    if v is None:
        return ""  # e.g. curriculum columns of a task without a curriculum
    if isinstance(v, (bool, np.bool_)):
        return str(int(v))
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return repr(float(v))  # shortest exact round trip; nan/inf as "nan"/"inf"


class MetricsLog:
    """Append-only metrics.csv writer with a fixed header (`columns`, by default COLUMNS; SAC
    passes its own); keys not in the columns are ignored and missing ones left blank."""

    def __init__(self, path: str | os.PathLike, columns: tuple[str, ...] = COLUMNS) -> None:
        self.path = Path(path)
        self.columns = tuple(columns)
        fresh = not self.path.exists() or self.path.stat().st_size == 0
        self._f = open(self.path, "a", encoding="utf-8", newline="")  # closed in close()
        if fresh:
            self._write_line(",".join(self.columns))

    def _write_line(self, line: str) -> None:
        self._f.write(line + "\n")
        self._f.flush()
        os.fsync(self._f.fileno())

    def write(self, metrics: dict) -> None:
        self._write_line(",".join(_cell(metrics.get(c)) for c in self.columns))

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> MetricsLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _rows(path: Path, columns: tuple[str, ...] = COLUMNS) -> list[dict[str, str]]:
    """Complete, well-formed rows of a metrics.csv with header `columns`; a torn last line (a kill
    mid-write) is dropped. Raises ValueError if the header is not the expected one (e.g. a file of
    another version, or of the other algorithm)."""
    header = ",".join(columns)
    text = path.read_text(encoding="utf-8")
    lines = text.split("\n")
    complete = lines[:-1]  # everything before the last newline; a torn tail is lines[-1]
    if not complete:
        return []
    if complete[0] != header:
        raise ValueError(f"{path}: header {complete[0]!r} is not the expected {header!r}")
    out = []
    for row in csv.reader(complete[1:]):
        if len(row) != len(columns):
            continue
        d = dict(zip(columns, row, strict=True))
        try:
            int(d["update"])
        except ValueError:
            continue
        out.append(d)
    return out


def truncate_metrics(path: str | os.PathLike, updates: int, columns: tuple[str, ...] = COLUMNS) -> int:
    """Keep the rows of updates 1..`updates` (a checkpoint's count) and rewrite the file
    atomically; returns how many rows were dropped. A missing file is created with the header
    (`columns`, by default COLUMNS)."""
    path = Path(path)
    rows = _rows(path, columns) if path.exists() else []
    keep = [r for r in rows if int(r["update"]) <= updates]
    buf = io.StringIO()
    buf.write(",".join(columns) + "\n")
    for r in keep:
        buf.write(",".join(r[c] for c in columns) + "\n")
    atomic_write(path, lambda f: f.write(buf.getvalue().encode("utf-8")))
    return len(rows) - len(keep)


def read_metrics(path: str | os.PathLike, columns: tuple[str, ...] = COLUMNS) -> dict[str, np.ndarray]:
    """metrics.csv (header `columns`, by default COLUMNS) as float columns (blank cells are NaN)."""
    rows = _rows(Path(path), columns)

    def num(s: str) -> float:
        return float(s) if s else math.nan

    return {c: np.array([num(r[c]) for r in rows], np.float64) for c in columns}


def _json_safe(obj):
    """Non-finite floats become None so the file is standard JSON (RFC 8259 has no NaN)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def write_json(path: str | os.PathLike, data: dict) -> Path:
    """Write `data` as indented standard JSON, atomically."""
    text = json.dumps(_json_safe(data), indent=2, allow_nan=False) + "\n"
    return atomic_write(path, lambda f: f.write(text.encode("utf-8")))


# --- the run directory's lock ---------------------------------------------------------------


class RunDirBusy(Exception):
    """Another process holds the run directory's lock: one line, exit code 1."""


_held: dict[Path, int] = {}  # run directory → the open lock file descriptor of this process


def _busy(directory: Path, fd: int) -> RunDirBusy:
    try:
        pid = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        pid = ""
    who = f"another run (pid {pid})" if pid.isdigit() else "another run"
    return RunDirBusy(f"{directory} is in use by {who}; wait for it to end, or stop it, then try again")


def lock_run_dir(directory: str | os.PathLike) -> None:
    """Take `directory/LOCK` (created if missing) with flock(LOCK_EX | LOCK_NB) and hold it until
    `release_run_dirs()` or the end of the process. Raises RunDirBusy at once if another process
    holds it (touching nothing), OSError if the directory cannot be written."""
    try:
        import fcntl
    except ImportError:  # no flock (Windows): runs are not locked there
        return
    directory = Path(directory)
    key = directory.resolve()
    if key in _held:
        return
    fd = os.open(directory / LOCK, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        err = _busy(directory, fd)
        os.close(fd)
        raise err from None
    except BaseException:
        os.close(fd)
        raise
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
    _held[key] = fd


def check_run_dir_free(directory: str | os.PathLike) -> None:
    """Raise RunDirBusy if another process holds `directory`'s lock; creates and changes nothing
    (for refusing a request before anything is checked or built)."""
    try:
        import fcntl
    except ImportError:
        return
    directory = Path(directory)
    if directory.resolve() in _held:
        return
    try:
        fd = os.open(directory / LOCK, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:  # no lock file (or no directory): nobody holds it
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # flock(2) takes a read-only descriptor too
    except BlockingIOError:
        raise _busy(directory, fd) from None
    finally:
        os.close(fd)  # closing drops the probe's own lock at once


def release_run_dirs() -> None:
    """Drop every run-directory lock this process holds (the end of a run)."""
    while _held:
        os.close(_held.popitem()[1])


def holds_run_files(directory: str | os.PathLike) -> bool:
    """True if `directory` holds anything but its lock file."""
    return any(p.name != LOCK for p in Path(directory).iterdir())
