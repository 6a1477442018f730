"""The bytes of an exported policy.tar do not depend on the machine: its stored example (two flights
of the policy and its outputs on them) is computed without BLAS, whose kernels order and fuse a
matrix product's terms by CPU, and without the float32 SIMD functions NumPy picks by CPU. The same
checkpoint gives the same file under other OpenBLAS kernels, thread counts and SIMD levels, and the
shipped policy.tar files are what the export writes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from quadpilot.export.cli import main as export
from quadpilot.runtime import gru
from quadpilot.runtime import rltools_tar as rt

MODELS = Path(__file__).parents[2] / "models"
SHIPPED = ["hover_px4_raptor_sih", "hover_px4_raptor_hummingbird"]
SRC = Path(__file__).parents[2] / "src"

# the example of the shipped checkpoint, its SHA-256 printed
EXAMPLE = """
import hashlib, sys
from pathlib import Path
from quadpilot.export import px4_raptor_export as E
from quadpilot.train.envs import EnvConfig
from quadpilot.train.raptor.distill import load_student
student, ckpt = load_student(Path(sys.argv[1]))
xs, ys = E.example(student.weights(), EnvConfig.from_json(ckpt["env_config"]))
print(hashlib.sha256(xs.tobytes() + ys.tobytes()).hexdigest())
"""
# other machines, as far as one machine can be them: OpenBLAS' kernels for older CPUs (the wheel's
# DYNAMIC_ARCH build picks them at start) and its threads; NumPy's SIMD paths above its baseline off
OTHER_MACHINES = {
    "this machine": {},
    "OpenBLAS Prescott kernels, 2 threads": {"OPENBLAS_CORETYPE": "Prescott", "OPENBLAS_NUM_THREADS": "2"},
    "OpenBLAS Sandybridge kernels, no AVX2 or AVX-512 in NumPy": {
        "OPENBLAS_CORETYPE": "Sandybridge",
        "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL X86_V3",
    },
}


def _example_digest(checkpoint: Path, env: dict) -> str:
    full = {**os.environ, "PYTHONPATH": str(SRC), **env}
    done = subprocess.run(
        [sys.executable, "-c", EXAMPLE, str(checkpoint)], env=full, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.split()[-1]


def test_the_stored_example_is_the_same_bytes_under_other_blas_kernels_and_simd_levels():
    checkpoint = MODELS / "hover_px4_raptor_sih" / "policy.pt"
    digests = {what: _example_digest(checkpoint, env) for what, env in OTHER_MACHINES.items()}
    assert len(set(digests.values())) == 1, digests


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_policy_tar_is_what_the_export_writes(name, tmp_path):
    assert export(["--format", "px4-raptor", str(MODELS / name / "policy.pt"), "-o", str(tmp_path)]) == 0
    assert (tmp_path / "policy.tar").read_bytes() == (MODELS / name / "policy.tar").read_bytes()
    assert (tmp_path / "policy.tar.sha256").read_text() == (MODELS / name / "policy.tar.sha256").read_text()


def test_portable_step_is_the_runtime_step_within_float32_and_gave_the_stored_output():
    tar = rt.read_policy_tar(MODELS / "hover_px4_raptor_sih" / "policy.tar")
    xs = tar.example_in
    portable = gru.PortableStep(tar.weights)
    ours = gru.sequences(portable, xs)
    assert np.max(np.abs(ours - gru.sequences(gru.GruStep(tar.weights), xs))) <= 1e-6
    np.testing.assert_array_equal(ours, tar.example_out)  # the stored output is the portable step's


def test_portable_exp_is_exp():
    x = np.linspace(-160.0, 80.0, 100_001)
    np.testing.assert_allclose(gru._portable_exp(x), np.exp(x), rtol=4e-16, atol=0)
