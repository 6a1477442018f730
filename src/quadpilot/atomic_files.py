"""The one way every file the package writes is written (run files, checkpoints, ONNX and C
exports, plots, videos, reports, traces): whole or not at all.

    atomic_write(path, lambda f: f.write(data))      # a writer that takes an open binary file
    with atomic_output(path) as tmp:                 # a writer that creates a file by its name
        fig.savefig(tmp)

A crash or an error leaves the previous file (or none), never a torn one. Imports nothing of ours:
the runtime, the simulator, the plots and the commands all use it."""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO


@contextlib.contextmanager
def atomic_output(out: str | os.PathLike, keep_previous: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside `out` (not yet existing, named `.<name>.<pid>.<random>.tmp`
    plus `out`'s suffix, so that writers choosing a format by extension still work) for the block
    to create. When the block succeeds: the file is fsync'd, the current `out` is moved to
    `keep_previous` if given (a name in the same directory), the temporary is renamed onto `out`
    and the directory fsync'd. When it fails, the temporary is deleted and the error goes on.

    A crash leaves the old `out` (or, between the two renames, only `keep_previous`), never a torn
    file; a leftover temporary is harmless and may be deleted. The writer creates the file, so the
    umask gives its permissions (`tempfile.mkstemp` would make it 0600)."""
    out = Path(out)
    directory = out.parent
    directory.mkdir(parents=True, exist_ok=True)
    tmp = directory / f".{out.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp{out.suffix}"
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        if keep_previous is not None and out.exists():
            os.replace(out, directory / keep_previous)
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(directory)


def atomic_write(path: str | os.PathLike, write: Callable[[IO[bytes]], None], keep_previous: str | None = None) -> Path:
    """Write `path` atomically (`atomic_output`): `write(f)` writes the bytes into a new file."""
    with atomic_output(path, keep_previous) as tmp:
        with open(tmp, "xb") as f:  # "x": never through a file or link that is already there
            write(f)
    return Path(path)


def _fsync_dir(directory: Path) -> None:
    """Make a rename durable: fsync the directory entry (POSIX; Windows cannot open directories)."""
    if os.name == "nt":
        return
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
