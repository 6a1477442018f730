"""The command-line scaffold every console script shares (quad-train, quad-export, quad-sitl, the
simulator's own command line, quad-demo, quad-compare, the montage).

- `Parser`: argparse that reads a value starting with "-" and a digit as a value, not an unknown
  option (`--wind -0.9,0,0`, `--target=-0.5,0.7,0.3`; argparse's own rule admits only plain numbers
  such as -1), and reports a bad flag as `UsageError` so that each command prints it in one line.
- Exit codes: `EXIT_BAD_FILE` (1) for a file that exists but cannot be used, `EXIT_BAD_FLAG` (2) for
  a bad flag (docs/security.md lists the rest).
- `check_output_path`: an output is checked before any work starts, so that no run is lost to a
  path it cannot write at the end.
- `docs_quick` / `quick`: the one switch (`QUADPILOT_DOCS_QUICK=1`) under which the commands the
  documentation shows run as a smoke test (a few training steps, one or two episodes) instead of at
  full size, so that tests/docs/test_doc_commands.py can run them as written.

Files are written with `quadpilot.atomic_files`. Imports nothing of ours and nothing heavy."""

from __future__ import annotations

import argparse
import math
import os
import re
import stat
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

EXIT_OK, EXIT_BAD_FILE, EXIT_BAD_FLAG = 0, 1, 2
NEGATIVE_VALUE = re.compile(r"^-\.?\d")
"""A token that starts with "-" and a digit (or "-." and a digit) is a flag's value."""


QUICK_ENV = "QUADPILOT_DOCS_QUICK"
"""The environment variable that shrinks every long command to a smoke test (docs/testing.md)."""


def docs_quick() -> bool:
    """Whether `QUADPILOT_DOCS_QUICK` is set to anything but "", "0" or "false": the documentation's
    commands are being run as a test, at the smallest size that still exercises each step."""
    return os.environ.get(QUICK_ENV, "").strip().lower() not in ("", "0", "false", "no")


def quick(full, small):
    """`small` under `QUADPILOT_DOCS_QUICK`, else `full`; a size given as None (the default) becomes
    `small` too. The caller passes the smaller of what the user asked for and its own quick size."""
    if not docs_quick():
        return full
    return small if full is None else min(full, small)


class UsageError(Exception):
    """A bad flag or flag value; the message is the one line the command prints (exit 2)."""


class BadFile(Exception):
    """A file that exists but cannot be used; the message is the one line the command prints (exit 1)."""


def run_command(prog: str, body: Callable[[], int]) -> int:
    """Run a command's `body` (parse, check, work; returns the exit code) with the errors every
    command reports alike: a bad flag (`UsageError`) in one line and exit 2, a bad file (`BadFile`)
    in one line and exit 1, a file that could not be read or written after the checks (`OSError`:
    the disk filled, a directory went away) in one line and exit 1, --help's exit as it is."""
    try:
        return body()
    except SystemExit as e:  # --help
        return e.code if isinstance(e.code, int) else EXIT_OK
    except UsageError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return EXIT_BAD_FLAG
    except BadFile as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return EXIT_BAD_FILE
    except OSError as e:
        print(f"{prog}: error: {os_error_line(e)}", file=sys.stderr)
        return EXIT_BAD_FILE


def os_error_line(e: OSError) -> str:
    """'<file>: <the OS's reason>' for an OSError, in one line."""
    return f"{os.fsdecode(e.filename) + ': ' if e.filename else ''}{os_reason(e)}"


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


def float_in(lo: float, hi: float):
    """An argparse type: a number in [lo, hi], else a one-line error saying the range."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not lo <= v <= hi:  # False for NaN too
            raise argparse.ArgumentTypeError(f"expected a number from {lo:,.10g} to {hi:,.10g}, got {text!r}")
        return v

    parse.__name__ = "number"
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


def os_reason(e: OSError) -> str:
    """The OS's reason for `e` in a few words ("File name too long", "Permission denied", ...)."""
    return e.strerror or str(e) or type(e).__name__


def input_path_problem(path: str | os.PathLike, what: str, *, directory: bool = False) -> str | None:
    """Why `path` cannot be read as `what` (one line: empty, missing, a directory where a file is
    expected or the reverse, or the reason the OS gives: a name too long, a loop of symbolic links, a
    file where a directory is expected on the way), or None. Only `stat`: whether the bytes can be
    read is the reader's to say."""
    path = Path(path)
    if not str(path):
        return f"{what}: empty path"
    try:
        st = path.stat()
    except FileNotFoundError:
        return f"{path}: does not exist; expected {what}"
    except (OSError, ValueError) as e:  # ValueError: an embedded NUL byte
        return f"{path}: {os_reason(e) if isinstance(e, OSError) else e}; expected {what}"
    is_dir = stat.S_ISDIR(st.st_mode)
    if is_dir != directory:
        return f"{path}: {'is a directory' if is_dir else 'is not a directory'}; expected {what}"
    return None


def check_output_path(path: Path, flag: str, *, directory: bool = False) -> None:
    """Raise ValueError (one line naming `flag`) unless `path` can be written: a file whose parent
    directory exists and takes a new file, not an existing directory (`directory`: a directory that
    exists, or whose parent does, and takes a new file). A probe file is created and removed, since
    permission bits do not tell (root ignores them, /proc and /sys refuse anyway). Whatever the OS
    says on the way (a name too long, a loop of links, a read-only file system) is that one line."""
    path = Path(path)
    if not str(path):
        raise ValueError(f"{flag}: empty path")
    try:
        _check_output_path(path, flag, directory)
    except OSError as e:
        raise ValueError(f"{flag} {path}: {os_reason(e)}") from None


def _check_output_path(path: Path, flag: str, directory: bool) -> None:
    try:
        os.stat(path)  # a name the OS refuses (too long, a loop of links) says so here, not at the end
    except FileNotFoundError:
        pass
    if directory:
        if path.exists() and not path.is_dir():
            raise ValueError(f"{flag} {path}: exists and is not a directory")
        where = path if path.is_dir() else path.parent
    else:
        if path.is_dir():
            raise ValueError(f"{flag} {path}: is a directory; expected a file name")
        where = path.parent
    try:
        if not stat.S_ISDIR(os.stat(where).st_mode):
            raise ValueError(f"{flag} {path}: {where} is not a directory")
    except FileNotFoundError:
        raise ValueError(f"{flag} {path}: directory {where} does not exist") from None
    try:
        fd, probe = tempfile.mkstemp(prefix=".quadpilot-write-check-", dir=where)
    except OSError as e:
        raise ValueError(f"{flag} {path}: cannot write in {where} ({e.strerror or e})") from None
    os.close(fd)
    os.unlink(probe)
