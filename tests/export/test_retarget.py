"""quad-export --vehicle: a generalist policy (trained over drawn airframes) exported for one vehicle
file: the file's rotor order (each rotor driven by the output of the training layout's rotor in the
same corner with the same spin), the file's hover command in the graph, the file in the metadata,
and one-line refusals for a one-airframe policy, a layout it cannot drive and a bad flag."""

import json
import math
import shutil

import numpy as np
import onnx
import pytest
import torch

from quadpilot.core.dynamics import action_to_command
from quadpilot.core.params import QUAD_X_UNIT, flu_layout, unit_layout
from quadpilot.core.vehicle_file import get_preset, load_vehicle_file, resolve_vehicle
from quadpilot.export.cli import main
from quadpilot.runtime.backends import load_policy as load_runtime_policy
from quadpilot.train.algorithms import load_policy
from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPOConfig
from quadpilot.train.ppo.checkpoint import save_untrained_policy
from quadpilot.train.ppo.retarget import RetargetError, _head_names, hover_trim, rotor_permutation

ROTORPY_ORDER = "benchmarks/airframes/rotorpy_hummingbird.toml"  # RotorPy numbers from front-left
ASYMMETRIC = "benchmarks/airframes/asymmetric.toml"


def test_rotor_permutation_matches_corners_and_spins():
    assert rotor_permutation(QUAD_X_UNIT, QUAD_X_UNIT) == (0, 1, 2, 3)
    # RotorPy: front-left (cw), front-right (ccw), rear-right (cw), rear-left (ccw)
    assert rotor_permutation(QUAD_X_UNIT, unit_layout(load_vehicle_file(ROTORPY_ORDER))) == (2, 0, 3, 1)
    # a frame stretched out of square keeps each rotor in its corner
    assert rotor_permutation(QUAD_X_UNIT, unit_layout(load_vehicle_file(ASYMMETRIC))) == (0, 1, 2, 3)
    flipped = tuple((x, y, -s) for x, y, s in QUAD_X_UNIT)  # every rotor spinning the other way
    with pytest.raises(RetargetError, match="spins the other way"):
        rotor_permutation(QUAD_X_UNIT, flipped)
    with pytest.raises(RetargetError, match="6 rotors"):
        rotor_permutation(QUAD_X_UNIT, QUAD_X_UNIT + QUAD_X_UNIT[:2])


@pytest.mark.parametrize("turn_deg", [45.0, -45.0, 31.0])
def test_a_plus_frame_or_a_turned_one_is_refused(turn_deg):
    """A rotor 45° off the diagonals (a "+" frame) is as near two corners as one: refused, not
    matched to either; so is one past the tolerance."""
    c, s = math.cos(math.radians(turn_deg)), math.sin(math.radians(turn_deg))
    turned = tuple((c * x - s * y, s * x + c * y, spin) for x, y, spin in QUAD_X_UNIT)
    with pytest.raises(RetargetError, match="not within 30° of a corner"):
        rotor_permutation(QUAD_X_UNIT, turned)
    c, s = math.cos(math.radians(29.0)), math.sin(math.radians(29.0))  # still in its corner
    assert rotor_permutation(QUAD_X_UNIT, tuple((c * x - s * y, s * x + c * y, sp) for x, y, sp in QUAD_X_UNIT)) == (
        0,
        1,
        2,
        3,
    )


@pytest.fixture(scope="module")
def generalists(tmp_path_factory):
    """Untrained generalists (head gain 1 and biases drawn, so that commands differ per rotor and a
    permutation that forgets the biases shows): LSTM and MLP."""
    d = tmp_path_factory.mktemp("generalist")
    env = make_config("hover", randomization="airframes")
    out = {}
    for arch in ("lstm", "mlp"):
        path = save_untrained_policy(d / f"{arch}.pt", PPOConfig(arch=arch, lstm_hidden=16), env)
        data = torch.load(path, weights_only=True)
        bias = _head_names(data)[1]
        data["model"][bias] = torch.linspace(-0.4, 0.5, len(data["model"][bias]))
        torch.save(data, path)
        out[arch] = path
    return out


@pytest.mark.parametrize("arch", ["lstm", "mlp"])
def test_exported_file_drives_the_files_rotors_with_its_hover_command(generalists, arch, tmp_path, capsys):
    out = tmp_path / "hb.onnx"
    assert main([str(generalists[arch]), "-o", str(out), "--vehicle", ROTORPY_ORDER, "--parity-samples", "200"]) == 0
    text = capsys.readouterr().out
    assert "rotors driven by outputs 3 1 4 2" in text and "parity within" in text
    vehicle = load_vehicle_file(ROTORPY_ORDER)
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert json.loads(meta["quadpilot.vehicle"])["name"] == vehicle.name
    assert (tmp_path / "hb.pt").is_file()  # the retargeted policy the metadata's checksum names
    # the same observations through the original policy (outputs in quad-X order) and the file
    original = load_policy(generalists[arch])
    obs = np.random.default_rng(0).normal(0, 0.3, (8, 18)).astype(np.float32)
    if original.recurrent:
        actions, _ = original.step(obs, original.initial_state(8))
    else:
        actions = original(obs)
    expect = action_to_command(actions, vehicle.hover_command)[:, [2, 0, 3, 1]]
    # the runtime flies one drone: a fresh policy per observation gives each its zero start state
    got = np.stack([load_runtime_policy(str(out), backend="numpy").act(o) for o in obs])
    np.testing.assert_allclose(got, expect, atol=2e-6)


def test_refusals_are_one_line(generalists, tmp_path, capsys):
    one_airframe = save_untrained_policy(tmp_path / "one.pt", PPOConfig(arch="mlp"), make_config("hover"))
    assert main([str(one_airframe), "-o", str(tmp_path / "a.onnx"), "--vehicle", ROTORPY_ORDER]) == 1
    err = capsys.readouterr().err.strip()
    assert "--randomize airframes" in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "a.onnx").exists()
    assert main([str(generalists["mlp"]), "-o", str(tmp_path / "b.onnx"), "--vehicle", "no_such_vehicle"]) == 2
    assert "--vehicle: unknown vehicle" in capsys.readouterr().err
    assert main([str(generalists["mlp"]), "--format", "c", "-o", str(tmp_path / "c"), "--vehicle", "crazyflie"]) == 2
    assert "--vehicle needs --format onnx" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nmass = -1\n')
    assert main([str(generalists["mlp"]), "-o", str(tmp_path / "d.onnx"), "--vehicle", str(bad)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_the_shipped_presets_are_retargeted_by_name(generalists, tmp_path, capsys):
    out = tmp_path / "cf.onnx"
    assert main([str(generalists["mlp"]), "-o", str(out), "--vehicle", "crazyflie", "--parity-samples", "200"]) == 0
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert json.loads(meta["quadpilot.vehicle"])["mass"] == get_preset("crazyflie").mass


def test_output_names_never_overwrite_the_checkpoint_or_another_policy(generalists, tmp_path, capsys, monkeypatch):
    ckpt = tmp_path / "policy.pt"
    shutil.copy(generalists["mlp"], ckpt)
    # no -o: <checkpoint>_<vehicle>.onnx and .pt beside the checkpoint
    assert main([str(ckpt), "--vehicle", "crazyflie", "--parity-samples", "200"]) == 0
    assert (tmp_path / "policy_crazyflie.onnx").is_file() and (tmp_path / "policy_crazyflie.pt").is_file()
    # exporting again replaces the earlier retargeted file
    assert main([str(ckpt), "--vehicle", "crazyflie", "--parity-samples", "200"]) == 0
    capsys.readouterr()
    # -o X.pt: the ONNX file would be written over the retargeted policy
    assert main([str(ckpt), "-o", str(tmp_path / "x.pt"), "--vehicle", "crazyflie"]) == 2
    assert "name a .onnx file" in capsys.readouterr().err
    # a file that is not a retargeted policy is not overwritten
    other = tmp_path / "other.pt"
    shutil.copy(ckpt, other)
    before = other.read_bytes()
    assert main([str(ckpt), "-o", str(tmp_path / "other.onnx"), "--vehicle", "crazyflie"]) == 2
    err = capsys.readouterr().err.strip()
    assert "is not a retargeted policy" in err and len(err.splitlines()) == 1
    assert other.read_bytes() == before
    # an export that fails after the retarget leaves no retargeted file that no ONNX file names

    def fail(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("quadpilot.export.onnx_export.export_onnx", fail)
    assert main([str(ckpt), "-o", str(tmp_path / "full.onnx"), "--vehicle", "crazyflie"]) == 1
    assert "No space left" in capsys.readouterr().err
    assert not (tmp_path / "full.pt").exists() and not (tmp_path / "full.onnx").exists()
    # a failed export over an earlier one leaves that pair as it was: the ONNX file names its .pt
    pair = tmp_path / "policy_crazyflie.pt"
    earlier = pair.read_bytes()
    assert main([str(ckpt), "--vehicle", ROTORPY_ORDER, "-o", str(pair.with_suffix(".onnx"))]) == 1
    assert pair.read_bytes() == earlier and not list(tmp_path.glob("*.prev"))


def test_an_unbalanced_frame_gets_its_hover_trim_in_the_head(generalists, tmp_path, capsys):
    """The asymmetric frame hovers only with more thrust on the front rotors (6 cm ahead of the
    centre of mass) than on the rear ones (11 cm behind): the exported file adds that trim to every
    action, so that the policy's zero action holds the frame level; a square frame gets none."""
    vehicle = load_vehicle_file(ASYMMETRIC)
    trim = hover_trim(vehicle)
    thrusts = vehicle.hover_thrust * (1.0 + trim)  # the motor map's thrust at action `trim`
    lay = np.asarray(flu_layout(vehicle.rotors))
    assert thrusts.sum() == pytest.approx(vehicle.weight)
    assert abs(thrusts @ lay[:, 0]) < 1e-9 and abs(thrusts @ lay[:, 1]) < 1e-9 and abs(thrusts @ lay[:, 2]) < 1e-9
    assert trim[0] == pytest.approx(2 * 0.11 / 0.17 - 1) and trim[1] == pytest.approx(2 * 0.06 / 0.17 - 1)
    for name in ("crazyflie", ROTORPY_ORDER):
        assert hover_trim(resolve_vehicle(name)) is None
    out = tmp_path / "asym.onnx"
    assert main([str(generalists["lstm"]), "-o", str(out), "--vehicle", ASYMMETRIC, "--parity-samples", "200"]) == 0
    assert "hover trim +0.294 -0.294 +0.294 -0.294" in capsys.readouterr().out
    original = load_policy(generalists["lstm"])
    obs = np.random.default_rng(1).normal(0, 0.3, (8, 18)).astype(np.float32)
    actions, _ = original.step(obs, original.initial_state(8))
    assert np.abs(actions).max() < 1.0 - np.abs(trim).max()  # unclipped, so the trim adds as it is
    expect = action_to_command(actions + trim, vehicle.hover_command)
    got = np.stack([load_runtime_policy(str(out), backend="numpy").act(o) for o in obs])
    np.testing.assert_allclose(got, expect, atol=2e-6)


def test_a_history_policy_is_retargeted_only_where_its_past_actions_match(tmp_path, capsys):
    """A policy that sees its past actions (--obs-history) takes them in its own rotor order, with no
    trim: onto a file that numbers its rotors otherwise, or onto an unbalanced frame, its input would
    hold what it never saw, so it is refused; onto one with its order and no trim it is retargeted.
    quad-export then refuses it in one line (such a policy runs in-process only) and leaves no file."""
    from quadpilot.train.algorithms import load_checkpoint
    from quadpilot.train.cli import main as train
    from quadpilot.train.ppo.retarget import retarget_checkpoint

    tiny = ["--num-envs", "16", "--rollout-steps", "16", "--minibatch-size", "64", "--threads", "1"]
    tiny += ["--eval-episodes", "0", "--eval-every", "0", "--task", "hover", "--total-steps", "256"]
    assert train([*tiny, "--randomize", "airframes", "--obs-history", "2", "--out", str(tmp_path / "run")]) == 0
    history = tmp_path / "run" / "policy.pt"
    ckpt = load_checkpoint(history)
    for vehicle, why in ((ROTORPY_ORDER, "numbers its rotors otherwise"), (ASYMMETRIC, "hover trim")):
        with pytest.raises(RetargetError, match=why):
            retarget_checkpoint(ckpt, load_vehicle_file(vehicle))
    assert retarget_checkpoint(ckpt, get_preset("crazyflie"))["extra"]["retargeted"]["rotor_order"] == [0, 1, 2, 3]
    capsys.readouterr()
    out = tmp_path / "cf.onnx"
    assert main([str(history), "-o", str(out), "--vehicle", "crazyflie"]) == 1
    err = capsys.readouterr().err.strip()
    assert "in-process only" in err and len(err.splitlines()) == 1
    assert not out.exists() and not out.with_suffix(".pt").exists()
