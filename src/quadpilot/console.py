"""The command-line scaffold every console script shares (quad-train, quad-export, quad-sitl, the
simulator's own command line, quad-demo, quad-compare, the montage).

- `Parser`: argparse that reads a value starting with "-" and a digit as a value, not an unknown
  option (`--wind -0.9,0,0`, `--target=-0.5,0.7,0.3`; argparse's own rule admits only plain numbers
  such as -1), and reports a bad flag as `UsageError` so that each command prints it in one line.
- Exit codes: `EXIT_BAD_FILE` (1) for a file that exists but cannot be used, `EXIT_BAD_FLAG` (2) for
  a bad flag (docs/security.md lists the rest).
- `check_output_path`: an output is checked before any work starts, so that no run is lost to a
  path it cannot write at the end.

Imports nothing of ours and nothing heavy: the runtime and the simulator use it too."""

from __future__ import annotations

import argparse
import math
import os
import re
import tempfile
from pathlib import Path

EXIT_OK, EXIT_BAD_FILE, EXIT_BAD_FLAG = 0, 1, 2
NEGATIVE_VALUE = re.compile(r"^-\.?\d")
"""A token that starts with "-" and a digit (or "-." and a digit) is a flag's value."""


class UsageError(Exception):
    """A bad flag or flag value; the message is the one line the command prints (exit 2)."""


class Parser(argparse.ArgumentParser):
    """argparse with negative numbers as values and errors raised as `UsageError`."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        # argparse's private matcher, consulted when it decides whether "-…" is an option (CPython
        # Lib/argparse.py, _negative_number_matcher)
        self._negative_number_matcher = NEGATIVE_VALUE

    def error(self, message: str):
        raise UsageError(message)


def int_in(lo: int, hi: int):
    """An argparse type: an integer in [lo, hi], else a one-line error saying the range."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"expected {lo} to {hi:,}, got {v:,}")
        return v

    parse.__name__ = "integer"
    return parse


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0, else a one-line error."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return v


positive_float.__name__ = "number > 0"


def check_output_path(path: Path, flag: str, *, directory: bool = False) -> None:
    """Raise ValueError (one line naming `flag`) unless `path` can be written: a file whose parent
    directory exists and takes a new file, not an existing directory (`directory`: a directory that
    exists, or whose parent does, and takes a new file). A probe file is created and removed, since
    permission bits do not tell (root ignores them, /proc and /sys refuse anyway)."""
    path = Path(path)
    if not str(path):
        raise ValueError(f"{flag}: empty path")
    if directory:
        if path.exists() and not path.is_dir():
            raise ValueError(f"{flag} {path}: exists and is not a directory")
        where = path if path.is_dir() else path.parent
    else:
        if path.is_dir():
            raise ValueError(f"{flag} {path}: is a directory; expected a file name")
        where = path.parent
    if not where.is_dir():
        raise ValueError(f"{flag} {path}: directory {where} does not exist")
    try:
        fd, probe = tempfile.mkstemp(prefix=".quadpilot-write-check-", dir=where)
    except OSError as e:
        raise ValueError(f"{flag} {path}: cannot write in {where} ({e.strerror or e})") from None
    os.close(fd)
    os.unlink(probe)
