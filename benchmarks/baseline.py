"""The code a speed figure is measured against, run in the same session as the code it judges.

The speed targets are ratios against main as it stood when they were set (commit bb5efb7): every
benchmark that claims one runs that commit's source next to today's, on the same machine, in the
same run, so that a loaded or a fast machine moves both figures together. `baseline_src` unpacks
the commit's `src/` with `git archive` into a cache directory (once per commit) and returns it; a
child process run with `PYTHONPATH=<it>` imports that version of `quadpilot` instead of the
installed one (the installed package's dependencies serve both).
"""

from __future__ import annotations

import io
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BASELINE_COMMIT = "bb5efb7"
"""main when the speed targets were set (time to the hover bar, vector env, SITL lockstep)."""


class BaselineUnavailable(RuntimeError):
    """This checkout cannot produce the baseline's source (no git, or a shallow clone without it)."""


def baseline_src(commit: str = BASELINE_COMMIT) -> Path:
    """The `src` directory of `commit`, unpacked from this repository's history."""
    cache = Path(os.environ.get("QUADPILOT_BASELINE_CACHE", Path(tempfile.gettempdir()) / f"quadpilot-{os.getuid()}"))
    try:
        full = subprocess.run(
            ["git", "-C", str(REPO), "rev-parse", "--verify", f"{commit}^{{commit}}"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError) as e:
        raise BaselineUnavailable(f"commit {commit} is not in {REPO}'s history (a shallow clone?): {e}") from None
    dest = cache / f"baseline-{full[:12]}"
    src = dest / "src"
    if (src / "quadpilot" / "__init__.py").is_file():
        return src
    tar = subprocess.run(["git", "-C", str(REPO), "archive", full, "src"], capture_output=True, check=True).stdout
    cache.mkdir(mode=0o700, parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=cache))
    with tarfile.open(fileobj=io.BytesIO(tar)) as t:
        t.extractall(tmp, filter="data")
    if dest.exists() and not (src / "quadpilot" / "__init__.py").is_file():
        shutil.rmtree(dest)  # left half-written by a run that was killed
    try:
        tmp.rename(dest)
    except OSError:  # another process unpacked it first
        shutil.rmtree(tmp, ignore_errors=True)
    return src


def run_python(code: str, src: Path | None, *args: str, timeout: float = 1800) -> str:
    """Run `python -c code args` with `src` (a baseline's source, or None for today's installed
    package) first on the import path; returns its stdout (stderr goes to ours)."""
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(src), *filter(None, [env.get("PYTHONPATH")])])
    out = subprocess.run(
        [sys.executable, "-c", code, *args], env=env, stdout=subprocess.PIPE, text=True, check=True, timeout=timeout
    )
    return out.stdout
