"""Batch-1 step latency of the RAPTOR policy (dense 22 → 16, GRU 16, dense 16 → 4) in the torch-free
runtime, against RAPTOR's own package (`foundation_policy`, NumPy) measured in the same run:

    gru_numpy          runtime.gru.GruStep: one step, hidden state in and out
    gru_onnxruntime    runtime.gru.OnnxGruStep: the ONNX graph in ONNX Runtime (session.run)
    gru_c              runtime.cgru.CGruStep: the generated C (ccode.gru), called through ctypes
    executor_numpy     RaptorPolicy.act: mc_raptor's executor (state kept or advanced, previous
                       action, clamp, remap, (a + 1)/2) around the NumPy step
    node_step_numpy    what the node runs per simulator step: the contract's observation from the
                       state (RaptorPolicy.own_observation) and SafetyMonitor.act
    package            foundation_policy.Raptor().evaluate_step on a (1, 22) batch (the baseline)

    .venv/bin/python -m pytest benchmarks/test_gru_step.py --benchmark-enable --benchmark-only \
        --benchmark-json=docs/bench/gru_step.json -p no:cacheprovider
    .venv/bin/python benchmarks/report_gru.py docs/bench/gru_step.json --strip-data

Each round is one call (`pedantic`, iterations=1): p50 and p99 of the per-call times go into
extra_info; the report divides each p50 by the package's. Without --benchmark-enable each case runs
once, a smoke test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadpilot.runtime import SafetyMonitor
from quadpilot.runtime.gru import GruStep, OnnxGruStep, weights_from_h5
from quadpilot.runtime.raptor import FOUNDATION, foundation_checkpoint, load_raptor

ROUNDS = 20_000
WARMUP = 500
CASES = ("gru_numpy", "gru_onnxruntime", "gru_c", "executor_numpy", "node_step_numpy", "package")
OBS = np.r_[0.1, -0.2, 0.05, np.eye(3).ravel(), 0.1, 0.0, -0.1, 0.01, 0.02, -0.03, np.zeros(4)].astype(np.float32)
STATE = [0.1, -0.2, 2.05, 0.1, 0.0, -0.1, 0.02, -0.01, 0.3, 0.01, 0.02, -0.03]


def _callable(case: str):
    weights, _ = weights_from_h5(foundation_checkpoint())
    if case in ("gru_numpy", "gru_onnxruntime", "gru_c"):
        from quadpilot.runtime.cgru import CGruStep

        step = {"gru_numpy": GruStep, "gru_onnxruntime": OnnxGruStep, "gru_c": CGruStep}[case](weights)
        h = step.initial_state.copy()
        return lambda: step(OBS, h)[0]
    if case == "package":
        import foundation_policy

        policy = foundation_policy.Raptor()
        policy.reset()
        batch = OBS[None]
        return lambda: policy.evaluate_step(batch)[0]
    policy = load_raptor(FOUNDATION, "numpy")
    if case == "executor_numpy":
        return lambda: policy.act(OBS)
    monitor = SafetyMonitor(policy)
    t = [0]

    def node_step():
        t[0] += 10_000
        return monitor.act(policy.own_observation(STATE, [0.0, 0.0, 2.0], None, 0.3, t[0]))

    return node_step


@pytest.mark.parametrize("case", CASES)
def test_gru_step_latency(benchmark, case):
    fn = _callable(case)
    benchmark.group = "RAPTOR GRU step, batch 1"
    benchmark.extra_info.update(case=case)
    out = np.asarray(benchmark.pedantic(fn, rounds=ROUNDS, iterations=1, warmup_rounds=WARMUP))
    assert out.shape == (4,) and np.isfinite(out).all()
    stats = getattr(benchmark, "stats", None)
    if stats is not None:  # None when benchmarks are disabled (the smoke-test run)
        data = np.asarray(stats.stats.data) * 1e6
        benchmark.extra_info.update(
            p50_us=float(np.percentile(data, 50)), p99_us=float(np.percentile(data, 99)), rounds=len(data)
        )
    assert math.isfinite(float(out[0]))
