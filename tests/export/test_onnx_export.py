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
from quadpilot.export.onnx_export import ONNX_SCHEMA, check_parity, export_onnx, reference_commands
from quadpilot.train.checkpoint import load_policy

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
    assert json.loads(props["quadpilot.obs_layout"])["name"] == "quadpilot.obs.hover/1"
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


def test_cli_writes_reports_and_refuses_bad_files(tmp_path, capsys):
    out = tmp_path / "p.onnx"
    assert main([str(MODELS / "waypoint" / "policy.pt"), "-o", str(out), "--parity-samples", "1000"]) == 0
    text = capsys.readouterr().out
    assert out.is_file() and "onnx.checker: ok" in text and "parity within 1e-05: ok" in text
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint at all")
    assert main([str(garbage)]) == 2
    err = capsys.readouterr().err
    assert "garbage.pt" in err and "a quadpilot checkpoint" in err and "Traceback" not in err
    assert main([str(tmp_path / "missing.pt")]) == 2
