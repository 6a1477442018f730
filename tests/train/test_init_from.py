"""quad-train --init-from: a fresh run that starts from a trained policy's network, weights (the
action head in the new vehicle's rotor order) and observation statistics, recorded in config.json;
refused in one line where it cannot be honoured."""

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from quadpilot.train.algorithms import load_policy
from quadpilot.train.cli import main
from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPOConfig
from quadpilot.train.ppo.checkpoint import save_untrained_policy
from quadpilot.train.ppo.retarget import _head_names

ROOT = Path(__file__).resolve().parents[2]
ROTORPY_ORDER = str(ROOT / "benchmarks/airframes/rotorpy_hummingbird.toml")  # RotorPy numbers from front-left
TINY = ["--num-envs", "16", "--rollout-steps", "16", "--minibatch-size", "64", "--threads", "1"]
TINY += ["--eval-episodes", "0", "--eval-every", "0", "--task", "hover"]


@pytest.fixture(scope="module")
def generalist(tmp_path_factory):
    """An untrained LSTM generalist with drawn head biases and observation statistics that are not
    the fresh ones, so that a run that forgot either shows."""
    path = tmp_path_factory.mktemp("gen") / "policy.pt"
    save_untrained_policy(
        path,
        PPOConfig(arch="lstm", lstm_hidden=16, normalize_obs=True),
        make_config("hover", randomization="airframes"),
    )
    data = torch.load(path, weights_only=True)
    bias = _head_names(data)[1]
    data["model"][bias] = torch.linspace(-0.4, 0.5, len(data["model"][bias]))
    data["obs_rms"]["mean"] = torch.linspace(-1.0, 1.0, len(data["obs_rms"]["mean"]), dtype=torch.float64)
    data["obs_rms"]["count"] = 1e12  # what the run's few steps add moves it by nothing
    torch.save(data, path)
    return path


def test_a_run_starts_from_the_files_weights_in_the_vehicles_rotor_order(generalist, tmp_path):
    out = tmp_path / "run"
    # one update of learning rate 0: the run's policy is the start it was given
    flags = [*TINY, "--total-steps", "256", "--set", "lr=0.0", "--vehicle", ROTORPY_ORDER]
    assert main([*flags, "--init-from", str(generalist), "--out", str(out)]) == 0
    record = json.loads((out / "config.json").read_text())["init_from"]
    assert record["sha256"] == hashlib.sha256(generalist.read_bytes()).hexdigest()
    assert record["rotor_order"] == [2, 0, 3, 1] and record["randomization"] == "airframes"
    source, tuned = load_policy(generalist), load_policy(out / "policy.pt")
    ppo = json.loads((out / "config.json").read_text())["ppo"]
    assert ppo["arch"] == "lstm" and ppo["lstm_hidden"] == 16  # the file's network, though no flag named it
    obs = np.random.default_rng(0).normal(0, 0.5, (8, make_config("hover").layout.dim)).astype(np.float32)
    a, _ = source.step(obs, source.initial_state(8))
    b, _ = tuned.step(obs, tuned.initial_state(8))
    np.testing.assert_allclose(b, a[:, [2, 0, 3, 1]], atol=1e-6)


def test_refusals_are_one_line(generalist, tmp_path, capsys):
    def refused(flags, code, words):
        assert main([*TINY, "--total-steps", "256", *flags]) == code
        err = capsys.readouterr().err.strip()
        assert words in err and len(err.splitlines()) == 1 and "Traceback" not in err, err

    out = ["--out", str(tmp_path / "r")]
    refused(["--init-from", str(generalist), "--arch", "mlp", *out], 2, "the run's network is the file's")
    refused(["--init-from", str(generalist), "--algo", "sac", *out], 2, "not --algo sac")
    refused(["--init-from", str(generalist), "--algo", "sb3", *out], 2, "not --algo sb3")
    refused(["--init-from", str(generalist), "--resume", *out], 2, "continues from its own checkpoint")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    refused(["--init-from", str(bad), *out], 1, str(bad))
    plus = tmp_path / "plus.toml"  # a '+' frame: no rotor in a corner of the file's quad-X
    text = (ROOT / "benchmarks/airframes/x500.toml").read_text()
    assert "[[rotor]]" in text
    head = text.split("[[rotor]]")[0]
    rotors = "".join(
        f'[[rotor]]\nx = {x}\ny = {y}\nspin = "{s}"\n'
        for x, y, s in ((0.246, 0.0, "ccw"), (-0.246, 0.0, "ccw"), (0.0, 0.246, "cw"), (0.0, -0.246, "cw"))
    )
    plus.write_text(head + rotors)
    refused(["--init-from", str(generalist), "--vehicle", str(plus), *out], 2, "not within 30° of a corner")
    assert not (tmp_path / "r").exists()


def test_the_resume_hint_drops_init_from():
    from quadpilot.train.runs.loop import resume_argv

    argv = ["--task", "hover", "--init-from", "gen.pt", "--out", "r", "--init-from=x.pt"]
    assert resume_argv(argv) == ["--task", "hover", "--out", "r", "--resume"]


def test_a_history_policy_starts_only_on_its_own_rotor_order(tmp_path, capsys):
    """Its input holds its past actions in its own rotor order, which a permuted head would not match,
    and without a hover trim, which a trimmed head's would hold."""
    source = tmp_path / "hist"
    assert main([*TINY, "--total-steps", "256", "--obs-history", "2", "--out", str(source)]) == 0
    capsys.readouterr()
    flags = [*TINY, "--total-steps", "256", "--init-from", str(source / "policy.pt")]
    assert main([*flags, "--vehicle", ROTORPY_ORDER, "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err.strip()
    assert "--obs-history 2" in err and len(err.splitlines()) == 1
    assert main([*flags, "--out", str(tmp_path / "b")]) == 0  # the same order: fine
    # the same order but a hover trim the seed frame has not: its past actions would hold it
    asymmetric = str(ROOT / "benchmarks/airframes/asymmetric.toml")
    capsys.readouterr()
    assert main([*flags, "--vehicle", asymmetric, "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err.strip()
    assert "hover trim" in err and "--obs-history 2" in err and len(err.splitlines()) == 1


def test_a_run_on_an_unbalanced_frame_starts_with_its_hover_trim(generalist, tmp_path):
    """From the generalist (square frames) onto the asymmetric frame, the head's bias gains the
    frame's trim; from a policy trained on the asymmetric frame onto it again, nothing is added (its
    weights hold the trim already)."""
    from quadpilot.core.vehicle_file import load_vehicle_file
    from quadpilot.train.ppo.retarget import hover_trim

    asymmetric = str(ROOT / "benchmarks/airframes/asymmetric.toml")
    trim = hover_trim(load_vehicle_file(asymmetric))
    flags = [*TINY, "--total-steps", "256", "--set", "lr=0.0", "--vehicle", asymmetric]
    first, again = tmp_path / "first", tmp_path / "again"
    assert main([*flags, "--init-from", str(generalist), "--out", str(first)]) == 0
    assert main([*flags, "--init-from", str(first / "policy.pt"), "--out", str(again)]) == 0
    bias = _head_names(torch.load(generalist, weights_only=True))[1]
    b0, b1, b2 = (
        torch.load(p, weights_only=True)["model"][bias].numpy()
        for p in (generalist, first / "policy.pt", again / "policy.pt")
    )
    np.testing.assert_allclose(b1, b0 + trim, atol=1e-6)
    np.testing.assert_allclose(b2, b1, atol=1e-6)
