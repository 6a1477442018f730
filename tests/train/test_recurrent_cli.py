"""`quad-train --arch lstm` end to end on a tiny budget: the run writes its files (with the sensor
noise and motor lag in its configuration), resumes, exports with explicit state and passes parity,
and the exported file flies one software-in-the-loop episode with noise on."""

import json

import pytest

from quadpilot.train.algorithms import load_checkpoint
from quadpilot.train.cli import main

TINY = ["--num-envs", "16", "--rollout-steps", "32", "--threads", "1", "--eval-episodes", "4", "--eval-every", "2"]
LSTM = ["--arch", "lstm", "--sensor-noise", "--motor-tau", "0.03"]


@pytest.fixture(scope="module")
def lstm_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("lstm") / "run"
    assert main(["--task", "hover", "--out", str(out), *TINY, *LSTM, "--total-steps", "1024"]) == 0
    return out


def test_an_lstm_run_writes_every_file_with_its_configuration(lstm_run):
    names = {p.name for p in lstm_run.iterdir()}
    assert {"config.json", "metrics.csv", "checkpoint.pt", "policy.pt", "eval.json", "curves.png"} <= names
    cfg = json.loads((lstm_run / "config.json").read_text())
    assert cfg["ppo"]["arch"] == "lstm"
    assert cfg["env"]["sensor_noise"]["name"] == "seed" and cfg["env"]["sensor_noise"]["imu"]["name"] == "adis16448"
    assert cfg["env"]["vehicle"]["motor_tau"] == 0.03
    assert "--arch lstm" in cfg["command"]
    ckpt = load_checkpoint(lstm_run / "policy.pt")
    assert {"rollout_state", "noise"} <= set(ckpt["trainer"]["extra_state"])
    assert json.loads((lstm_run / "eval.json").read_text())["episodes"] == 4


def test_an_lstm_run_resumes_and_keeps_its_architecture(lstm_run, capsys):
    assert main(["--task", "hover", "--out", str(lstm_run), *TINY, "--total-steps", "2048", "--resume"]) == 0
    assert load_checkpoint(lstm_run / "policy.pt")["global_step"] == 2048
    capsys.readouterr()
    assert main(["--task", "hover", "--out", str(lstm_run), *TINY, "--arch", "mlp", "--resume"]) == 2
    assert "--arch mlp (checkpoint: lstm)" in capsys.readouterr().err
    assert main(["--task", "hover", "--out", str(lstm_run), *TINY, "--sensor-noise", "crazyflie", "--resume"]) == 2
    assert "--sensor-noise crazyflie (checkpoint: seed)" in capsys.readouterr().err


def test_options_of_our_ppo_are_refused_for_other_algorithms(tmp_path, capsys):
    assert main(["--task", "hover", "--out", str(tmp_path / "x"), "--algo", "sb3", "--arch", "lstm"]) == 2
    assert "--arch: options of our PPO" in capsys.readouterr().err


@pytest.mark.sitl
def test_exported_lstm_passes_parity_and_flies_in_sitl_with_noise(lstm_run, capsys):
    from quadpilot.export.cli import main as export
    from quadpilot.sitl import main as sitl

    assert export([str(lstm_run / "policy.pt")]) == 0
    printed = capsys.readouterr().out
    assert "parity within 1e-05: ok" in printed and "sequences" in printed
    onnx = str(lstm_run / "policy.onnx")
    assert sitl([onnx, "--episodes", "1", "--duration", "1", "--gcs", "none"]) == 0
    summary = lstm_run / "sitl.json"
    noisy = [onnx, "--episodes", "1", "--duration", "1", "--gcs", "none", "--imu-noise", "--estimator-noise"]
    assert sitl([*noisy, "--motor-tau", "0.03", "--json", str(summary)]) == 0
    s = json.loads(summary.read_text())
    assert s["episodes"] == 1 and s["steps"] == 100 and s["failsafe_events"] == 0
    assert not s["packets_dropped"]  # ODOMETRY is understood, not counted as unexpected
