"""A policy trained here for PX4's mc_raptor, end to end, as a user runs it:
`quad-train --task hover --contract px4-raptor --vehicle px4_sih_quadx`, then
`quad-export --format px4-raptor`, gives a policy.tar that RLtools' own loader (the harness of
conftest.py, built against the pinned rltools sdist) loads and self-tests with mc_raptor's procedure,
and whose actions RLtools' L2F executor reproduces at mc_raptor's timing. The training here is a tiny
one (it proves the pipeline, not the flying); the shipped policies (models/hover_px4_raptor_*) are the
ones that fly, and they go through the same loader and executor here, and through quad-sitl in
tests/sitl/test_px4_raptor_flights.py."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import raptor_build as build
from raptor_files import fly_like_mc_raptor, observations, our_stepper

from quadpilot.export.cli import main as export
from quadpilot.runtime import rltools_tar as rt
from quadpilot.train.cli import main as train

MODELS = Path(__file__).parents[2] / "models"
SHIPPED = ["hover_px4_raptor_sih", "hover_px4_raptor_hummingbird"]
TINY = [
    "--num-envs",
    "4",
    "--total-steps",
    "4000",
    "--set",
    "gradient_steps=3",
    "--set",
    "minibatch=4",
    "--threads",
    "1",
]


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("px4raptor")
    assert (
        train(["--task", "hover", "--contract", "px4-raptor", "--vehicle", "px4_sih_quadx", "--out", str(out), *TINY])
        == 0
    )
    assert export(["--format", "px4-raptor", str(out / "policy.pt")]) == 0
    return out


def _self_test(harness, tar: Path) -> float:
    done = build.run(harness, "check", tar)
    assert done.returncode == 0, done.stdout + done.stderr
    return float(re.search(r"Checkpoint test passed with diff ([0-9.e-]+)", done.stdout).group(1))


def test_trained_and_exported_file_loads_and_self_tests_in_rltools(harness, exported):
    written = {"policy.onnx", "policy.pt", "policy.tar", "policy.tar.sha256", "vehicle.toml"}
    assert written <= {p.name for p in exported.iterdir()}
    assert _self_test(harness, exported / "policy.tar") < 1e-5  # mc_raptor's bar
    done = build.run(harness, "check", exported / "policy.tar")
    assert "Checkpoint name: quadpilot/px4_sih_quadx/px4-raptor" in done.stdout


def test_the_export_is_the_same_bytes_every_time(exported, tmp_path):
    assert export(["--format", "px4-raptor", str(exported / "policy.pt"), "-o", str(tmp_path)]) == 0
    assert (tmp_path / "policy.tar").read_bytes() == (exported / "policy.tar").read_bytes()
    digest = (exported / "policy.tar.sha256").read_text().split()[0]
    assert digest == rt.sha256_hex((exported / "policy.tar").read_bytes())


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_policy_tar_passes_mc_raptors_check_and_the_executor_gives_our_actions(harness, name, tmp_path):
    tar = MODELS / name / "policy.tar"
    assert _self_test(harness, tar) < 1e-5
    obs = observations(2000)
    obs.tofile(tmp_path / "obs.f32")
    done = build.run(harness, "fly", tar, tmp_path / "obs.f32", tmp_path / "actions.f32")
    assert done.returncode == 0, done.stdout + done.stderr
    theirs = np.fromfile(tmp_path / "actions.f32", dtype="<f4").reshape(-1, 4)
    ours = fly_like_mc_raptor(our_stepper(rt.read_policy_tar(tar).weights), obs)
    assert np.ptp(theirs, axis=0).min() > 0.05  # the actions move
    assert np.max(np.abs(theirs - ours)) <= 1e-5


def test_a_checkpoint_of_another_kind_is_one_line_for_either_format(exported, capsys):
    assert export(["--format", "px4-raptor", str(MODELS / "hover" / "policy.pt"), "-o", str(exported / "x")]) == 1
    assert export([str(exported / "policy.pt"), "-o", str(exported / "x.onnx")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "not a px4-raptor policy" in err[0] and "--format px4-raptor" in err[1]


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_policy_onnx_is_the_same_gru_as_its_policy_tar(name):
    import json

    import onnx

    from quadpilot.runtime import gru

    model = onnx.load(MODELS / name / "policy.onnx")
    tar = rt.read_policy_tar(MODELS / name / "policy.tar")
    weights = tar.weights
    meta = {p.key: p.value for p in model.metadata_props}
    assert meta["quadpilot.contract"] == "px4-raptor"
    h0 = np.array(json.loads(meta["quadpilot.initial_hidden_state"]), np.float32)
    np.testing.assert_array_equal(h0, weights["layers/1/initial_hidden_state"])
    shipped = gru.OnnxGruStep.__new__(gru.OnnxGruStep)  # the shipped graph, run as the runtime runs its own
    import onnxruntime as ort

    shipped.session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    shipped.initial_state = h0  # from the file's metadata
    xs = tar.example_in  # two flights of the policy, 500 steps each
    diff = np.max(np.abs(gru.sequences(shipped, xs) - gru.sequences(gru.GruStep(weights), xs)))
    assert diff <= 1e-5


def test_a_refused_export_leaves_the_files_there_untouched(exported, tmp_path, capsys):
    import shutil

    import torch

    out = tmp_path / "out"
    shutil.copytree(exported, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    ckpt = torch.load(exported / "policy.pt", weights_only=True)
    ckpt["env_config"]["vehicle"]["name"] = "../x\n\0" * 20  # no vehicle file can hold it
    torch.save(ckpt, tmp_path / "bad.pt")
    assert export(["--format", "px4-raptor", str(tmp_path / "bad.pt"), "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot be exported" in err[0]
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_what_lies_beside_a_policy_tar_is_checked(exported, tmp_path, capsys):
    import shutil

    from quadpilot.sitl import main as sitl

    d = tmp_path / "m"
    shutil.copytree(exported, d)
    (d / "vehicle.toml").write_text(
        (d / "vehicle.toml")
        .read_text()
        .replace('spin = "ccw"', 'spin = "tmp"')
        .replace('spin = "cw"', 'spin = "ccw"')
        .replace('spin = "tmp"', 'spin = "cw"')
    )  # every rotor's spin reversed: not PX4's quad-X
    (d / "policy.tar.sha256").unlink()
    (d / "policy.tar.sha256").mkdir()
    assert sitl([str(d / "policy.tar"), "--episodes", "1", "--gcs", "none"]) == 1
    assert "cannot read" in capsys.readouterr().err
    (d / "policy.tar.sha256").rmdir()
    assert sitl([str(d / "policy.tar"), "--episodes", "1", "--gcs", "none"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "its vehicle.toml" in err[0] and "spins" in err[0]
