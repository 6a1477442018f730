"""Atomic output files that keep the usual permissions."""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_output(out: Path) -> Iterator[Path]:
    """Yield a not-yet-existing temporary path beside `out` (same suffix, so writers that go by the
    extension still work); rename it onto `out` when the block succeeds, delete it when it fails.
    Unlike `tempfile.mkstemp` (mode 0600) the writer creates the file, so the umask applies."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.stem}.{os.getpid()}.{secrets.token_hex(4)}.tmp{out.suffix}")
    try:
        yield tmp
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
