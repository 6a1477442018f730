"""quad-export on the shipped policies: the ONNX file holds everything inference needs, passes the
full checker, carries its metadata and golden vectors, has a dynamic batch axis, and gives the same
motor commands as PyTorch and as the training-side path (≤ 1e-5)."""

import json
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from quadpilot.export.cli import main
from quadpilot.export.onnx_export import ONNX_SCHEMA, check_parity, export_onnx, parity_sequences, reference_commands
from quadpilot.modelfile.model import read_model
from quadpilot.train.algorithms import load_checkpoint, load_policy
from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPOConfig
from quadpilot.train.ppo.checkpoint import save_untrained_policy

MODELS = Path(__file__).parents[2] / "models"


@pytest.fixture(scope="module")
def hover_onnx(tmp_path_factory):
    out = tmp_path_factory.mktemp("export") / "hover.onnx"
    meta = export_onnx(MODELS / "hover" / "policy.pt", out)
    return out, meta


def session(path):
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def test_file_passes_the_full_checker_and_carries_metadata(hover_onnx):
    path, meta = hover_onnx
    model = onnx.load(str(path))
    onnx.checker.check_model(model, full_check=True)
    props = {p.key: p.value for p in model.metadata_props}
    assert props == meta
    assert props["quadpilot.schema"] == ONNX_SCHEMA
    assert json.loads(props["quadpilot.obs_layout"])["name"] == "quadpilot.obs.hover/2"
    assert props["quadpilot.task"] == "hover" and float(props["quadpilot.control_period_s"]) == 0.01
    assert json.loads(props["quadpilot.vehicle"])["mass"] == 0.665
    assert len(props["quadpilot.source_sha256"]) == 64
    assert "PX4 quad-X" in props["quadpilot.action"]
    # the weights are inside the file: no external data
    assert all(t.data_location != onnx.TensorProto.EXTERNAL for t in model.graph.initializer)


def test_io_names_shapes_and_dynamic_batch(hover_onnx):
    path, _ = hover_onnx
    s = session(path)
    (inp,), (out,) = s.get_inputs(), s.get_outputs()
    assert (inp.name, inp.type, inp.shape[1]) == ("obs", "tensor(float)", 18)
    assert (out.name, out.type, out.shape[1]) == ("action", "tensor(float)", 4)
    assert isinstance(inp.shape[0], str)  # symbolic batch
    for b in (1, 7, 256):
        y = s.run(["action"], {"obs": np.zeros((b, 18), np.float32)})[0]
        assert y.shape == (b, 4) and y.dtype == np.float32


def test_golden_vectors_reproduce_and_commands_stay_in_range(hover_onnx):
    path, meta = hover_onnx
    golden = json.loads(meta["quadpilot.golden"])
    obs, expected = np.array(golden["obs"], np.float32), np.array(golden["action"], np.float32)
    got = session(path).run(["action"], {"obs": obs})[0]
    np.testing.assert_allclose(got, expected, atol=1e-6)
    huge = np.full((3, 18), 1e6, np.float32)
    huge[1] *= -1
    y = session(path).run(["action"], {"obs": huge})[0]
    assert np.all((y >= 0) & (y <= 1))


def test_at_hover_the_policy_commands_about_hover_trim(hover_onnx):
    path, _ = hover_onnx
    policy = load_policy(MODELS / "hover" / "policy.pt")
    at_target = np.zeros((1, 18), np.float32)
    at_target[0, 6:15] = np.eye(3).ravel()  # level, at the target, still
    y = session(path).run(["action"], {"obs": at_target})[0]
    u_hover = policy.env_config.params.hover_command
    np.testing.assert_allclose(y, u_hover, atol=0.05)
    np.testing.assert_allclose(y, reference_commands(policy, at_target), atol=1e-5)


@pytest.mark.parametrize("task", ["hover", "circle"])
def test_parity_torch_onnxruntime_and_training_path(tmp_path, task):
    out = tmp_path / f"{task}.onnx"
    export_onnx(MODELS / task / "policy.pt", out)
    parity = check_parity(MODELS / task / "policy.pt", out, n=4000)
    assert parity["observations"] == 4000
    assert max(v for k, v in parity.items() if k != "observations") <= 1e-5, parity
    assert {"torch_vs_runtime_numpy", "torch_vs_runtime_onnxruntime"} <= set(parity)


def test_cli_writes_reports_and_refuses_bad_files(tmp_path, capsys):
    out = tmp_path / "p.onnx"
    assert main([str(MODELS / "waypoint" / "policy.pt"), "-o", str(out), "--parity-samples", "1000"]) == 0
    text = capsys.readouterr().out
    assert out.is_file() and "onnx.checker: ok" in text and "parity within 1e-05: ok" in text
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint at all")
    assert main([str(garbage)]) == 1  # a bad file
    err = capsys.readouterr().err
    assert "garbage.pt" in err and "a quadpilot checkpoint" in err and "Traceback" not in err
    assert main([str(tmp_path / "missing.pt")]) == 2  # a bad argument: no such file


def test_cli_given_an_onnx_file_says_what_it_is_and_speaks_of_no_flag_not_given(tmp_path, capsys):
    onnx_file = MODELS / "hover" / "policy.onnx"
    assert main([str(onnx_file)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1, err
    assert "--output" not in err  # no --output was given
    assert "is an ONNX file, already exported; fly it with quad-sitl" in err
    assert str(MODELS / "hover" / "policy.pt") in err  # the checkpoint beside it
    lone = tmp_path / "lone.onnx"
    lone.write_bytes(onnx_file.read_bytes())
    assert main([str(lone), "-o", str(tmp_path / "x.onnx")]) == 2
    err = capsys.readouterr().err
    assert "is an ONNX file" in err and "its checkpoint is" not in err and not (tmp_path / "x.onnx").exists()


# --- the recurrent variant and the normalised MLP -------------------------------------------


@pytest.fixture(scope="module")
def lstm_files(tmp_path_factory):
    """An LSTM actor of the training code's class (`RecurrentActorCritic`, 64 wide), untrained,
    its head re-initialised with gain 1 so that commands vary, exported."""
    d = tmp_path_factory.mktemp("lstm")
    pt = save_untrained_policy(d / "policy.pt", PPOConfig(arch="lstm", lstm_hidden=64), make_config("hover"))
    meta = export_onnx(pt, d / "policy.onnx")
    return pt, d / "policy.onnx", meta


@pytest.mark.parametrize("fmt", [[], ["--format", "c"], ["--format", "px4-raptor"]])
def test_cli_given_a_policy_tar_says_what_it_is_in_one_line(tmp_path, capsys, fmt):
    shipped = Path(__file__).parents[2] / "models" / "hover_px4_raptor_sih" / "policy.tar"
    renamed = tmp_path / "my policy.pt"  # what the file is, not what it is called
    renamed.write_bytes(shipped.read_bytes())
    for tar in (shipped, renamed):
        assert main([str(tar), *fmt, "-o", str(tmp_path / "out")]) == 2
        out, err = capsys.readouterr()
        assert out == "" and len(err.strip().splitlines()) == 1, err
        assert "is a PX4 mc_raptor policy.tar, already exported; fly it with quad-sitl" in err
        assert "Traceback" not in err and "legacy" not in err
    assert f"quad-sitl '{renamed}'" in err  # quoted as a shell reads it
    assert not (tmp_path / "out").exists()


def test_lstm_exports_with_explicit_state(lstm_files):
    _, path, meta = lstm_files
    onnx.checker.check_model(onnx.load(str(path)), full_check=True)
    s = session(path)
    assert [(i.name, i.shape[1]) for i in s.get_inputs()] == [("obs", 18), ("h_in", 64), ("c_in", 64)]
    assert [(o.name, o.shape[1]) for o in s.get_outputs()] == [("action", 4), ("h_out", 64), ("c_out", 64)]
    assert json.loads(meta["quadpilot.architecture"])["kind"] == "lstm"
    obs, z = np.zeros((5, 18), np.float32), np.zeros((5, 64), np.float32)
    action, h, c = s.run(None, {"obs": obs, "h_in": z, "c_in": z})
    assert action.shape == (5, 4) and h.shape == c.shape == (5, 64)
    # the state carries memory: the same observation from a different state gives another command
    action2, _, _ = s.run(None, {"obs": obs, "h_in": h, "c_in": c})
    assert np.max(np.abs(action2 - action)) > 1e-4


def test_lstm_parity_over_500_step_sequences_with_a_reset(lstm_files):
    pt, path, _ = lstm_files
    parity = check_parity(pt, path, n=2000)
    assert parity["sequences"] == 4 and parity["observations"] == 2000
    assert max(v for k, v in parity.items() if k not in ("observations", "sequences")) <= 1e-5, parity


def test_lstm_parity_is_not_blind(lstm_files):
    """The commands of the test LSTM span a real range, and the state reset matters."""
    pt, _, _ = lstm_files
    policy = load_policy(pt)
    obs, starts = parity_sequences(policy, steps=100, sequences=3)
    assert starts[0].all() and starts[50].all()
    ref = reference_commands(policy, obs, starts)
    assert ref.std() > 0.02
    no_reset = starts.copy()
    no_reset[50] = False
    assert np.max(np.abs(reference_commands(policy, obs, no_reset)[50] - ref[50])) > 1e-3


def test_normalised_mlp_parity(tmp_path):
    """A run with observation normalisation: mean, 1/std and the ±clip travel in the graph, and
    the NumPy backend reads them too."""
    import torch

    ckpt = load_checkpoint(MODELS / "hover" / "policy.pt")
    ckpt["ppo_config"]["normalize_obs"] = True
    rng = np.random.default_rng(0)
    ckpt["obs_rms"]["mean"] = torch.as_tensor(rng.normal(0, 0.3, 18))
    ckpt["obs_rms"]["var"] = torch.as_tensor(rng.uniform(0.05, 2.0, 18))
    pt = tmp_path / "norm.pt"
    torch.save(ckpt, pt)
    export_onnx(pt, tmp_path / "norm.onnx")
    info = read_model(tmp_path / "norm.onnx")[1]
    assert info.architecture["normalize"]["clip"] == 10.0
    parity = check_parity(pt, tmp_path / "norm.onnx", n=2000)
    assert max(v for k, v in parity.items() if k != "observations") <= 1e-5, parity


def test_cli_exports_an_lstm(lstm_files, tmp_path, capsys):
    pt, _, _ = lstm_files
    assert main([str(pt), "-o", str(tmp_path / "l.onnx"), "--parity-samples", "1000"]) == 0
    text = capsys.readouterr().out
    assert "2 sequences with a state reset half-way" in text and "runtime numpy" in text


def test_parity_is_judged_on_thrust_so_a_rounding_near_rest_is_not_magnified():
    """u = u_hover·√(1 + a): one float32 rounding of a near −1 moved a rotor at 0.4 % speed by 1e-5
    between torch and ONNX Runtime. In thrust (u²) that is 1e-7 of full thrust; the same 1e-5 at full
    speed is 2e-5 of full thrust, over the bar."""
    from quadpilot.export.cli import PARITY_TOLERANCE
    from quadpilot.export.onnx_export import _thrust_difference

    near_rest = np.array([[0.004456478, 0.5, 0.5, 0.5]], np.float32)
    other = near_rest.copy()
    other[0, 0] = 0.0044667344  # the measured pair
    assert np.max(np.abs(near_rest - other)) > PARITY_TOLERANCE
    assert _thrust_difference(near_rest, other) < 1e-7
    full = np.array([[1.0, 0.5, 0.5, 0.5]], np.float32)
    assert _thrust_difference(full, full - np.float32(1e-5)) > PARITY_TOLERANCE
