"""The PyTorch GRU student of mc_raptor's shape computes what the runtime flies and the tar holds."""

from __future__ import annotations

import numpy as np
import torch

from quadpilot.runtime import rltools_tar as rt
from quadpilot.runtime.gru import GruStep, OnnxGruStep, sequences
from quadpilot.train.raptor.student import RaptorStudent


def _student(seed: int = 0) -> RaptorStudent:
    torch.manual_seed(seed)
    net = RaptorStudent()
    with torch.no_grad():
        net.initial_hidden_state.normal_(0, 0.5)  # non-zero, so a wrong reset state shows
    return net


def _inputs(seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).normal(0, 1.5, (60, 3, 22)).astype(np.float32)


def test_student_has_blob_policy_h_shape():
    assert sum(p.numel() for p in _student().parameters()) == rt.N_PARAMETERS == 2084


def test_torch_numpy_and_onnx_forward_agree_within_1e_5():
    net, x = _student(), _inputs()
    with torch.no_grad():
        ours, _ = net(torch.from_numpy(x))
    w = net.weights()
    assert np.max(np.abs(sequences(GruStep(w), x) - ours.numpy())) <= 1e-5
    assert np.max(np.abs(sequences(OnnxGruStep(w), x) - ours.numpy())) <= 1e-5


def test_hidden_state_carried_across_calls_equals_one_sequence():
    net, x = _student(), torch.from_numpy(_inputs())
    with torch.no_grad():
        whole, _ = net(x)
        first, h = net(x[:25])
        rest, _ = net(x[25:], h)
    assert torch.allclose(torch.cat([first, rest]), whole, atol=1e-6)


def test_weights_round_trip_and_tar_replay():
    net = _student()
    w = net.weights()
    back = RaptorStudent.from_weights(w).weights()
    assert all(np.array_equal(w[k], back[k]) for k in w)
    ex_in = np.random.default_rng(2).normal(0, 1, (rt.EXAMPLE_STEPS, rt.EXAMPLE_BATCH, 22)).astype(np.float32)
    with torch.no_grad():
        ex_out = net(torch.from_numpy(ex_in))[0].numpy()
    data = rt.policy_tar_bytes(w, ex_in, ex_out, "student")
    assert (
        rt.parse_policy_tar(data).weights["layers/1/initial_hidden_state"].tolist()
        == w["layers/1/initial_hidden_state"].tolist()
    )
