"""Batch-1 policy latency, every backend and its baseline measured in one run (DESIGN.md, rule 10).

For the shipped hover MLP (18 → 64 → 64 → 4, tanh) and an LSTM of the same width (18 → LSTM 64 →
4, built by the training code's `RecurrentActorCritic` and exported the same way), one `act(obs)`:

    monitored_numpy, monitored_onnxruntime   SafetyMonitor.act: observation validation, envelope
                                             check, inference, command check (what flies)
    bare_numpy, bare_onnxruntime             the backend's Policy.act alone
    session_run                              onnxruntime InferenceSession.run, as most code calls it
    torch_eager                              the exported torch module, batch 1, inference_mode,
                                             including numpy → tensor → numpy (the baseline)

Run (the project's addopts disable benchmarks, so enable them here):

    .venv/bin/python -m pytest benchmarks/test_policy_latency.py --benchmark-enable --benchmark-only \
        --benchmark-json=docs/bench/policy_latency.json -p no:cacheprovider
    .venv/bin/python benchmarks/report_latency.py docs/bench/policy_latency.json --strip-data

Each round is one call (`pedantic`, iterations=1), so the round times are the per-call latency
distribution; p50 and p99 are taken from it (pytest-benchmark reports no p99 itself, so it goes into
`extra_info`). Garbage collection stays on, as in the control loop. Without --benchmark-enable each
case runs once, a smoke test.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from quadpilot.export.onnx_export import deployable, export_onnx
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.train.checkpoint import load_policy as load_trained
from quadpilot.train.checkpoint import save_untrained_policy
from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPOConfig

MODELS = Path(__file__).parents[1] / "models"
ROUNDS = {"torch_eager": 5_000}
DEFAULT_ROUNDS = 20_000
WARMUP = 500
CASES = ("monitored_numpy", "monitored_onnxruntime", "bare_numpy", "bare_onnxruntime", "session_run", "torch_eager")


@pytest.fixture(scope="module")
def networks(tmp_path_factory):
    """{"mlp": (policy.pt, policy.onnx), "lstm": (...)}."""
    d = tmp_path_factory.mktemp("latency")
    lstm_pt = save_untrained_policy(d / "lstm.pt", PPOConfig(arch="lstm", lstm_hidden=64), make_config("hover"))
    export_onnx(lstm_pt, d / "lstm.onnx")
    return {
        "mlp": (MODELS / "hover" / "policy.pt", MODELS / "hover" / "policy.onnx"),
        "lstm": (lstm_pt, d / "lstm.onnx"),
    }


def _callable(case: str, pt: Path, onnx_path: Path):
    """A zero-argument function doing one batch-1 act on a real observation."""
    obs = load_policy(onnx_path, "numpy").info.golden_obs[0].copy()
    if case.startswith(("monitored", "bare")):
        backend = case.split("_", 1)[1]
        policy = load_policy(onnx_path, backend)
        act = SafetyMonitor(policy).act if case.startswith("monitored") else policy.act
        return lambda: act(obs)
    if case == "session_run":
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = opts.inter_op_num_threads = 1
        s = ort.InferenceSession(str(onnx_path), opts, providers=["CPUExecutionProvider"])
        names = [i.name for i in s.get_inputs()]
        feed = {"obs": obs[None]}
        if "h_in" in names:
            h = int(s.get_inputs()[1].shape[1])
            feed |= {"h_in": np.zeros((1, h), np.float32), "c_in": np.zeros((1, h), np.float32)}
        return lambda: s.run(None, feed)[0][0]
    torch.set_num_threads(1)
    module = deployable(load_trained(pt))
    if not module.recurrent:

        def eager():
            with torch.inference_mode():
                return module(torch.from_numpy(obs[None]))[0].numpy()

        return eager
    state = [torch.zeros(1, module.hidden), torch.zeros(1, module.hidden)]

    def eager_step():
        with torch.inference_mode():
            action, state[0], state[1] = module(torch.from_numpy(obs[None]), state[0], state[1])
            return action[0].numpy()

    return eager_step


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("net", ["mlp", "lstm"])
def test_act_latency(benchmark, networks, net, case):
    pt, onnx_path = networks[net]
    fn = _callable(case, pt, onnx_path)
    benchmark.group = f"batch-1 act, {net}"
    benchmark.extra_info.update(net=net, case=case)
    out = benchmark.pedantic(fn, rounds=ROUNDS.get(case, DEFAULT_ROUNDS), iterations=1, warmup_rounds=WARMUP)
    out = np.asarray(out)
    assert out.shape == (4,) and np.all((out >= 0) & (out <= 1))
    stats = getattr(benchmark, "stats", None)
    if stats is not None:  # None when benchmarks are disabled (the smoke-test run)
        data = np.asarray(stats.stats.data) * 1e6
        benchmark.extra_info.update(
            p50_us=float(np.percentile(data, 50)), p99_us=float(np.percentile(data, 99)), rounds=len(data)
        )
