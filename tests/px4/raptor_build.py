"""RLtools' headers from the pinned `rltools` sdist (PyPI) and the mc_raptor harness compiled against
them, cached outside the repository where the C backend keeps its builds (runtime.cbackend.cache_root:
$QUADPILOT_CACHE_DIR, else ~/.cache/quadpilot). Used by tests/px4 and benchmarks/rltools_proof.py."""

from __future__ import annotations

import hashlib
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from quadpilot.runtime.cbackend import cache_root

RLTOOLS_VERSION = "2.2.1"
RLTOOLS_SDIST_SHA256 = "1ee45ae609380fc6a6c5b91e18ea023a3895d69fe148cd4cc25ace415da756b0"
HEADERS_IN_SDIST = f"rltools-{RLTOOLS_VERSION}/rltools/external/rl_tools/include/"
HARNESS = Path(__file__).parent / "harness" / "raptor_check.cpp"
# an RLtools checkout's include/ at the commit PX4 pins (it has operations_posix.h; not on PyPI)
PX4_INCLUDE_ENV = "QUADPILOT_RLTOOLS_PX4_INCLUDE"


class Unavailable(Exception):
    """An outside tool this machine lacks: (what is missing, how to get it)."""


class BuildFailed(Exception):
    """The download is not the pinned file, or the harness does not compile."""


def sha256_of(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def rltools_headers() -> Path:
    """RLtools' include/ from the pinned sdist, downloaded once with pip and checked by SHA-256."""
    root = cache_root() / f"rltools-{RLTOOLS_VERSION}"
    include = root / "include"
    sdist = root / f"rltools-{RLTOOLS_VERSION}.tar.gz"
    if (include / "rl_tools" / "version.h").is_file() and sdist.is_file() and sha256_of(sdist) == RLTOOLS_SDIST_SHA256:
        return include
    root.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:"]
    cmd += [f"rltools=={RLTOOLS_VERSION}", "-d", str(root), "-q"]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    except subprocess.TimeoutExpired:
        done = None
    if done is None or done.returncode != 0 or not sdist.is_file():
        what = f"could not download the rltools {RLTOOLS_VERSION} sdist"
        raise Unavailable(what, f"needs network: {' '.join(cmd[2:])}")
    if sha256_of(sdist) != RLTOOLS_SDIST_SHA256:
        raise BuildFailed(f"{sdist}: SHA-256 {sha256_of(sdist)}, expected {RLTOOLS_SDIST_SHA256}")
    with tempfile.TemporaryDirectory(dir=root) as tmp, tarfile.open(sdist, "r:gz") as tar:
        wanted = [m for m in tar.getmembers() if m.name.startswith(HEADERS_IN_SDIST) and m.isreg()]
        for m in wanted:
            m.name = m.name[len(HEADERS_IN_SDIST) :]
        tar.extractall(tmp, members=wanted, filter="data")
        shutil.rmtree(include, ignore_errors=True)
        Path(tmp).rename(include)
        include.mkdir(exist_ok=True)  # TemporaryDirectory removes a path that is gone without complaint
    return include


def _headers_digest(include: Path) -> bytes:
    h = hashlib.sha256()
    for p in sorted(include.rglob("*.h")):
        h.update(str(p.relative_to(include)).encode() + b"\0" + p.read_bytes())
    return h.digest()


def compile_harness(include: Path, posix: bool) -> Path:
    """The harness built against `include` (-DQP_RLTOOLS_POSIX: PX4's pinned RLtools), cached."""
    gxx = shutil.which("g++")
    if gxx is None:
        raise Unavailable("g++ not found", "install it with: apt-get install g++")
    version = subprocess.run([gxx, "--version"], capture_output=True, text=True).stdout
    flags = ["-std=c++17", "-O1", *(["-DQP_RLTOOLS_POSIX"] if posix else [])]
    key = hashlib.sha256(HARNESS.read_bytes() + _headers_digest(include) + version.encode() + str(flags).encode())
    out = cache_root() / "harness" / f"raptor_check-{key.hexdigest()[:16]}"
    if out.is_file():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:
        built = Path(tmp) / "raptor_check"
        done = subprocess.run(
            [gxx, *flags, f"-I{include}", str(HARNESS), "-o", str(built)], capture_output=True, text=True
        )
        if done.returncode != 0:
            raise BuildFailed(f"the harness does not compile against {include}:\n{done.stderr[-3000:]}")
        built.replace(out)
    return out


def run(harness: Path, *args) -> subprocess.CompletedProcess:
    return subprocess.run([str(harness), *map(str, args)], capture_output=True, text=True, timeout=300)
