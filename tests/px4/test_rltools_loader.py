"""Our policy.tar read by RLtools' own code, as PX4's mc_raptor reads it.

The `rltools` sdist (PyPI, pinned version and SHA-256) brings RLtools' headers; g++ compiles
tests/px4/harness/raptor_check.cpp against them: the policy type of mc_raptor's blob/policy.h,
RLtools' tar loader, mc_raptor's start-up check and RLtools' L2F inference executor at mc_raptor's
timing. Sdist, headers and binary are cached outside the repository, where the C backend keeps
its builds (runtime.cbackend.cache_root: $QUADPILOT_CACHE_DIR, else ~/.cache/quadpilot). In CI
(env CI set) a failed download or compile fails the test; elsewhere it skips with one line.

RLtools as PX4 pins it (mc_raptor reads through persist/backends/tar/operations_posix.h, which
2.2.1 lacks) is run too when QUADPILOT_RLTOOLS_PX4_INCLUDE names the include/ directory of an
RLtools checkout at that commit (docs/px4.md: how it was done).
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest
from raptor_files import (
    FOUNDATION_NAME,
    data_offset,
    example_index,
    flip_low_byte,
    fly_like_mc_raptor,
    foundation,
    foundation_stepper,
    members,
    observations,
    our_stepper,
    patch_float,
    wider_first_layer,
)

from quadpilot.runtime import rltools_tar as rt
from quadpilot.runtime.cbackend import cache_root

RLTOOLS_VERSION = "2.2.1"
RLTOOLS_SDIST_SHA256 = "1ee45ae609380fc6a6c5b91e18ea023a3895d69fe148cd4cc25ace415da756b0"
HEADERS_IN_SDIST = f"rltools-{RLTOOLS_VERSION}/rltools/external/rl_tools/include/"
HARNESS = Path(__file__).parent / "harness" / "raptor_check.cpp"
PX4_INCLUDE_ENV = "QUADPILOT_RLTOOLS_PX4_INCLUDE"


def unavailable(why: str, install: str) -> None:
    if os.environ.get("CI"):
        pytest.fail(f"{why} (CI must run this test)")
    pytest.skip(f"{why}; {install}")


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
        unavailable(f"could not download the rltools {RLTOOLS_VERSION} sdist", f"needs network: {' '.join(cmd[2:])}")
    if sha256_of(sdist) != RLTOOLS_SDIST_SHA256:
        pytest.fail(f"{sdist}: SHA-256 {sha256_of(sdist)}, expected {RLTOOLS_SDIST_SHA256}")
    shutil.rmtree(include, ignore_errors=True)
    with tarfile.open(sdist, "r:gz") as tar:
        wanted = [m for m in tar.getmembers() if m.name.startswith(HEADERS_IN_SDIST) and m.isreg()]
        for m in wanted:
            m.name = m.name[len(HEADERS_IN_SDIST) :]
        tar.extractall(include, members=wanted, filter="data")
    return include


def compile_harness(include: Path, posix: bool) -> Path:
    gxx = shutil.which("g++")
    if gxx is None:
        unavailable("g++ not found", "install it with: apt-get install g++")
    version = subprocess.run([gxx, "--version"], capture_output=True, text=True).stdout
    flags = ["-std=c++17", "-O1", *(["-DQP_RLTOOLS_POSIX"] if posix else [])]
    key = hashlib.sha256(
        HARNESS.read_bytes() + str(include.resolve()).encode() + version.encode() + str(flags).encode()
    )
    out = cache_root() / "harness" / f"raptor_check-{key.hexdigest()[:16]}"
    if out.is_file():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    done = subprocess.run([gxx, *flags, f"-I{include}", str(HARNESS), "-o", str(tmp)], capture_output=True, text=True)
    if done.returncode != 0:
        pytest.fail(f"the harness does not compile against {include}:\n{done.stderr[-3000:]}")
    tmp.replace(out)
    return out


@pytest.fixture(scope="session", params=["rltools-2.2.1", "rltools-px4-pin"])
def harness(request) -> Path:
    if request.param == "rltools-2.2.1":
        return compile_harness(rltools_headers(), posix=False)
    include = os.environ.get(PX4_INCLUDE_ENV)
    if not include or not (Path(include) / "rl_tools/persist/backends/tar/operations_posix.h").is_file():
        pytest.skip(f"set {PX4_INCLUDE_ENV} to the include/ of RLtools at PX4's pinned commit (docs/px4.md)")
    return compile_harness(Path(include), posix=True)


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    w, ex_in, ex_out = foundation()
    path = tmp_path_factory.mktemp("raptor") / "policy.tar"
    rt.write_policy_tar(path, w, ex_in, ex_out, FOUNDATION_NAME)
    return path


def run(harness: Path, *args) -> subprocess.CompletedProcess:
    return subprocess.run([str(harness), *map(str, args)], capture_output=True, text=True, timeout=300)


def test_rltools_loads_our_file_and_it_passes_mc_raptors_check(harness, good):
    done = run(harness, "check", good)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"Checkpoint name: {FOUNDATION_NAME}" in done.stdout
    diff = float(re.search(r"Checkpoint test passed with diff ([0-9.]+)", done.stdout).group(1))
    assert diff < 1e-6  # mc_raptor's bar is 1e-5


def test_rltools_writer_writes_our_members_and_our_reader_reads_its_file(harness, good, tmp_path):
    done = run(harness, "save", good, tmp_path / "theirs.tar")
    assert done.returncode == 0, done.stdout + done.stderr
    theirs = (tmp_path / "theirs.tar").read_bytes()
    assert list(members(theirs)) == rt.MEMBER_NAMES  # the same members in the same order ...
    assert members(theirs) == members(good.read_bytes())  # ... holding the same bytes
    back = rt.parse_policy_tar(theirs)
    assert back.checkpoint_name == FOUNDATION_NAME and back.replay_max_difference <= 1e-5


def test_executor_at_mc_raptor_timing_gives_our_actions(harness, good, tmp_path):
    obs = observations(2000)
    obs.tofile(tmp_path / "obs.f32")
    done = run(harness, "fly", good, tmp_path / "obs.f32", tmp_path / "actions.f32")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "flown: 2000 gyro updates, 500 native steps" in done.stdout
    theirs = np.fromfile(tmp_path / "actions.f32", dtype="<f4").reshape(-1, 4)
    ours = fly_like_mc_raptor(our_stepper(rt.read_policy_tar(good).weights), obs)
    package = fly_like_mc_raptor(foundation_stepper(), obs)
    assert theirs.shape == (2000, 4) and np.ptp(theirs, axis=0).min() > 0.05  # the actions move
    assert np.max(np.abs(theirs - ours)) <= 1e-5
    assert np.max(np.abs(theirs - package)) <= 1e-5


def _damaged(good: Path, how: str) -> bytes:
    data = good.read_bytes()
    if how == "a weight changed":
        return patch_float(data, "actor/layers/1/weights_hidden/parameters/data", 7, 0.9)
    if how == "another shape":
        return wider_first_layer(data)
    if how == "NaN in the first example input steps":
        return patch_float(data, "example/input/data", example_index(2, 1, 4, rt.OBS_DIM), np.nan)
    if how == "NaN in the first example output steps":
        return patch_float(data, "example/output/data", example_index(2, 1, 1, rt.ACTION_DIM), np.nan)
    if how == "truncated in the weights":
        return data[:6000]
    if how == "truncated in the example input":
        return data[: len(data) // 2]
    if how == "an output bias moved by 2e-5":
        at = data_offset(data, "actor/layers/2/biases/parameters/data")
        return patch_float(
            data, "actor/layers/2/biases/parameters/data", 0, np.frombuffer(data[at : at + 4], "<f4")[0] + 2e-5
        )
    if how == "NaN at example step 300":
        return patch_float(data, "example/input/data", example_index(300, 0, 5, rt.OBS_DIM), np.nan)
    if how == "example output changed at step 300":
        return patch_float(data, "example/output/data", example_index(300, 1, 2, rt.ACTION_DIM), 0.25)
    if how == "truncated in the example output":
        return data[: len(data) - 20_000]
    assert how == "a weight's low-order byte changed"
    return flip_low_byte(data, "actor/layers/0/weights/parameters/data", 3)


# what mc_raptor's loader says when it refuses (exit 1: its check; -6: an RLtools assert aborts,
# as it does in PX4's POSIX build)
REFUSED_BY_BOTH = {
    "a weight changed": (1, "Checkpoint test failed with diff"),
    "another shape": (-6, "Dimension mismatch in metadata"),
    "NaN in the first example input steps": (-6, "input is nan"),
    "NaN in the first example output steps": (-6, "output is nan"),
    "truncated in the weights": (-6, "Failed to read metadata entry"),
    "truncated in the example input": (1, "Checkpoint test failed with diff"),  # it compares garbage
}
MISSED_BY_MC_RAPTOR = [
    "an output bias moved by 2e-5",  # mean over 40 values 5e-6, under its 1e-5
    "NaN at example step 300",
    "example output changed at step 300",
    "truncated in the example output",  # its 5 steps are still there
    "a weight's low-order byte changed",  # outputs move by ~1e-8: only the SHA-256 sees it
]


@pytest.mark.parametrize("how", list(REFUSED_BY_BOTH))
def test_damage_refused_by_rltools_as_mc_raptor_and_by_our_reader(harness, good, tmp_path, how):
    path = tmp_path / "policy.tar"
    path.write_bytes(_damaged(good, how))
    done = run(harness, "check", path)
    code, says = REFUSED_BY_BOTH[how]
    assert done.returncode == code and says in done.stdout + done.stderr, done.stdout + done.stderr
    with pytest.raises(rt.PolicyTarError) as e:
        rt.read_policy_tar(path)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("how", MISSED_BY_MC_RAPTOR)
def test_damage_mc_raptors_check_passes_and_our_reader_refuses(harness, good, tmp_path, how):
    path = tmp_path / "policy.tar"
    path.write_bytes(_damaged(good, how))
    done = run(harness, "check", path)
    assert done.returncode == 0 and "Checkpoint test passed" in done.stdout, done.stdout + done.stderr
    shutil.copy(rt.sha256_path(good), rt.sha256_path(path))  # the SHA-256 written with the good file
    with pytest.raises(rt.PolicyTarError) as e:
        rt.read_policy_tar(path)
    assert "\n" not in str(e.value)
    if how == "a weight's low-order byte changed":
        assert "SHA-256" in str(e.value)
        assert rt.parse_policy_tar(path.read_bytes()).replay_max_difference <= 1e-5  # no replay sees it
    else:
        rt.sha256_path(path).unlink()  # the content check alone refuses it too
        with pytest.raises(rt.PolicyTarError):
            rt.read_policy_tar(path)
