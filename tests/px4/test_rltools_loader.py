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

import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import raptor_build as build
from raptor_files import (
    DAMAGE,
    FOUNDATION_NAME,
    fly_like_mc_raptor,
    foundation,
    foundation_stepper,
    members,
    observations,
    our_stepper,
)

from quadpilot.runtime import rltools_tar as rt

PX4_BLOB_ENV = "QUADPILOT_PX4_RAPTOR_BLOB"
PX4_BLOB_SHA256 = "5327c83dc57f094ca1977a2533ebce318645be010e16b9354c96c337cd5c278b"  # px4-blob bc6683a9


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    w, ex_in, ex_out = foundation()
    path = tmp_path_factory.mktemp("raptor") / "policy.tar"
    rt.write_policy_tar(path, w, ex_in, ex_out, FOUNDATION_NAME)
    return path


def test_rltools_loads_our_file_and_it_passes_mc_raptors_check(harness, good):
    done = build.run(harness, "check", good)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"Checkpoint name: {FOUNDATION_NAME}" in done.stdout
    diff = float(re.search(r"Checkpoint test passed with diff ([0-9.]+)", done.stdout).group(1))
    assert diff < 1e-6  # mc_raptor's bar is 1e-5


def test_rltools_writer_writes_our_bytes_and_our_reader_reads_its_file(harness, good, tmp_path):
    done = build.run(harness, "save", good, tmp_path / "theirs.tar")
    assert done.returncode == 0, done.stdout + done.stderr
    theirs = (tmp_path / "theirs.tar").read_bytes()
    assert list(members(theirs)) == rt.MEMBER_NAMES
    assert theirs == good.read_bytes()  # RLtools' writer, given what it loaded, writes our file byte for byte
    back = rt.parse_policy_tar(theirs)
    assert back.checkpoint_name == FOUNDATION_NAME and back.replay_max_difference <= 1e-5


def test_px4s_shipped_policy_tar_is_what_our_writer_writes(harness):
    """PX4's own file (the mc_raptor blob submodule, rl-tools/px4-blob, not on a registry): our reader
    accepts it, mc_raptor's check passes, and our writer given its content writes its bytes (and the
    two zero blocks that end a tar, which the blob lacks)."""
    path = os.environ.get(PX4_BLOB_ENV)
    if not path:
        pytest.skip(f"set {PX4_BLOB_ENV} to PX4's src/modules/mc_raptor/blob/policy.tar (docs/px4.md)")
    blob = Path(path).read_bytes()
    assert rt.sha256_hex(blob) == PX4_BLOB_SHA256, "not the policy.tar of rl-tools/px4-blob bc6683a9"
    p = rt.parse_policy_tar(blob)
    assert p.checkpoint_name == FOUNDATION_NAME
    assert rt.policy_tar_bytes(p.weights, p.example_in, p.example_out, p.checkpoint_name) == blob + bytes(1024)
    w, _, _ = foundation()
    assert all(np.array_equal(p.weights[n], w[n]) for n in w)  # foundation-policy's weights
    done = build.run(harness, "check", path)
    assert done.returncode == 0 and "Checkpoint test passed" in done.stdout, done.stdout + done.stderr


def test_executor_at_mc_raptor_timing_gives_our_actions(harness, good, tmp_path):
    obs = observations(2000)
    obs.tofile(tmp_path / "obs.f32")
    done = build.run(harness, "fly", good, tmp_path / "obs.f32", tmp_path / "actions.f32")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "flown: 2000 gyro updates, 500 native steps" in done.stdout
    theirs = np.fromfile(tmp_path / "actions.f32", dtype="<f4").reshape(-1, 4)
    ours = fly_like_mc_raptor(our_stepper(rt.read_policy_tar(good).weights), obs)
    package = fly_like_mc_raptor(foundation_stepper(), obs)
    assert theirs.shape == (2000, 4) and np.ptp(theirs, axis=0).min() > 0.05  # the actions move
    assert np.max(np.abs(theirs - ours)) <= 1e-5
    assert np.max(np.abs(theirs - package)) <= 1e-5


# what mc_raptor's loader says when it refuses (exit 1: its check; -6: an RLtools assert aborts,
# as it does in PX4's POSIX build)
REFUSED_BY_BOTH = {
    "a weight changed": (1, "Checkpoint test failed with diff"),
    "another shape": (-6, "Dimension mismatch in metadata"),
    "NaN in the first example input steps": (-6, "input is nan"),
    "NaN in the first example output steps": (-6, "output is nan"),
    "truncated in the weights": (-6, "Failed to read metadata entry"),
    "truncated in the example input": (1, "Checkpoint test failed with diff"),  # it compares garbage
    "an empty file": (-6, "Failed to read metadata entry"),
    "shorter than a tar header": (-6, "Failed to read metadata entry"),
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
    path.write_bytes(DAMAGE[how](good.read_bytes()))
    done = build.run(harness, "check", path)
    code, says = REFUSED_BY_BOTH[how]
    assert done.returncode == code and says in done.stdout + done.stderr, done.stdout + done.stderr
    with pytest.raises(rt.PolicyTarError) as e:
        rt.read_policy_tar(path)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("how", MISSED_BY_MC_RAPTOR)
def test_damage_mc_raptors_check_passes_and_our_reader_refuses(harness, good, tmp_path, how):
    path = tmp_path / "policy.tar"
    path.write_bytes(DAMAGE[how](good.read_bytes()))
    done = build.run(harness, "check", path)
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
