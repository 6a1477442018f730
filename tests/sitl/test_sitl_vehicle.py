"""--vehicle end to end: a policy trained with `quad-train --vehicle FILE` carries that vehicle into
its checkpoint and its ONNX metadata; `quad-sitl` flies a policy on its own vehicle by default, and
warns (one line) when --vehicle overrides it with a different one."""

import dataclasses
import json

import onnx
import pytest

import quadpilot.sitl as sitl
from quadpilot.core.vehicle_file import VEHICLES_DIR, load_vehicle_file
from quadpilot.runtime import load_policy
from quadpilot.simulator import build_sim_parser, config_from_args
from quadpilot.sitl import simulator_process

pytest.importorskip("torch")
pytestmark = pytest.mark.sitl

TINY = ["--num-envs", "64", "--rollout-steps", "16", "--threads", "1", "--eval-episodes", "0", "--eval-every", "0"]
FLY = ["--episodes", "1", "--duration", "0.3", "--gcs", "none"]


@pytest.fixture(scope="module")
def heavy(tmp_path_factory):
    """(vehicle file, its VehicleParams, the ONNX policy trained on it for two updates)."""
    from quadpilot.export.cli import main as export
    from quadpilot.train.cli import main as train

    d = tmp_path_factory.mktemp("heavy")
    path = d / "heavy.toml"
    seed = (VEHICLES_DIR / "seed.toml").read_text(encoding="utf-8")
    path.write_text(seed.replace('name = "seed"', 'name = "heavy"').replace("mass = 0.665", "mass = 0.8"))
    vehicle = load_vehicle_file(path)
    assert vehicle.mass == 0.8
    out = d / "run"
    assert train(["--task", "hover", "--vehicle", str(path), "--total-steps", "2048", "--out", str(out), *TINY]) == 0
    assert export([str(out / "policy.pt"), "-o", str(d / "policy.onnx"), "--parity-samples", "100"]) == 0
    return path, vehicle, d / "policy.onnx"


def test_a_policy_trained_on_a_vehicle_file_exports_that_vehicle(heavy):
    _, vehicle, onnx_path = heavy
    config = json.loads((onnx_path.parent / "run" / "config.json").read_text())
    assert config["env"]["vehicle"] == dataclasses.asdict(vehicle)
    meta = {p.key: p.value for p in onnx.load(str(onnx_path)).metadata_props}
    assert json.loads(meta["quadpilot.vehicle"]) == dataclasses.asdict(vehicle)
    assert load_policy(onnx_path, "numpy").info.vehicle == vehicle


class _Recorder(simulator_process.SimulatorProcess):
    """The simulator process as quad-sitl starts it, with the configuration its flags give (read
    while any temporary vehicle file still exists)."""

    configs: list = []

    def __init__(self, cmd):
        assert cmd[3] == "--sim-only"
        _Recorder.configs.append(config_from_args(build_sim_parser().parse_args(cmd[3:])))
        super().__init__(cmd)


@pytest.fixture
def recorder(monkeypatch):
    _Recorder.configs = []
    monkeypatch.setattr(simulator_process, "SimulatorProcess", _Recorder)
    return _Recorder.configs


def test_quad_sitl_flies_the_policy_on_its_own_vehicle(heavy, recorder, capsys):
    _, vehicle, onnx_path = heavy
    assert sitl.main([str(onnx_path), *FLY]) == 0
    assert "warning" not in capsys.readouterr().err
    (cfg,) = recorder
    assert cfg.vehicle_params.mass == vehicle.mass == 0.8
    assert cfg.vehicle_params == vehicle  # every parameter, not only the mass
    assert sitl.main([str(onnx_path), *FLY, "--imu-noise"]) == 2  # refused before the simulator starts
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no sensor model for vehicle 'heavy'" in err[0], err
    assert len(recorder) == 1


def test_quad_sitl_flies_a_shipped_policy_on_its_preset(recorder, capsys):
    assert sitl.main([str(sitl.SHIPPED_HOVER), *FLY]) == 0
    assert "warning" not in capsys.readouterr().err
    (cfg,) = recorder
    assert cfg.vehicle == "seed" and cfg.vehicle_params == load_vehicle_file(VEHICLES_DIR / "seed.toml")


def test_quad_sitl_warns_when_vehicle_overrides_the_policys(heavy, recorder, capsys):
    path, _, _ = heavy
    assert sitl.main([str(sitl.SHIPPED_HOVER), *FLY, "--vehicle", str(path)]) == 0
    warnings = [ln for ln in capsys.readouterr().err.splitlines() if "warning" in ln]
    assert len(warnings) == 1 and str(path) in warnings[0] and "seed" in warnings[0], warnings
    assert recorder[0].vehicle_params.mass == 0.8
    assert sitl.main([str(sitl.SHIPPED_HOVER), *FLY, "--vehicle", "seed"]) == 0  # the policy's own: no warning
    assert "warning" not in capsys.readouterr().err


def test_a_resumed_run_keeps_its_vehicle_file(heavy, tmp_path, capsys):
    """--resume with the same vehicle file continues; with a file whose numbers differ, or with a
    noise model the file's vehicle has none of, one line and exit 2."""
    from quadpilot.train.cli import main as train

    path, _, onnx_path = heavy
    run = ["--task", "hover", "--out", str(onnx_path.parent / "run"), *TINY]
    other = tmp_path / "other.toml"
    other.write_text(path.read_text().replace("mass = 0.8", "mass = 0.81"))
    assert train([*run, "--vehicle", str(other), "--total-steps", "3072", "--resume"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--vehicle heavy from a file whose parameters differ" in err[0], err
    assert train([*run, "--vehicle", str(path), "--total-steps", "3072", "--resume"]) == 0
    capsys.readouterr()
    fresh = ["--task", "hover", "--out", str(tmp_path / "noisy"), *TINY, "--vehicle", str(path)]
    assert train([*fresh, "--sensor-noise"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no sensor model for vehicle 'heavy'" in err[0], err
