"""Batch-1 policy latency, every backend and its baseline measured in one run (docs/architecture.md, rule 10).

For the shipped hover MLP (18 → 64 → 64 → 4, tanh) and an LSTM of the same width (18 → LSTM 64 →
4, built by the training code's `RecurrentActorCritic` and exported the same way), one `act(obs)`:

    monitored_numpy, monitored_onnxruntime,  SafetyMonitor.act: observation validation, envelope
    monitored_c                              check, inference, command check (what flies)
    bare_numpy, bare_onnxruntime, bare_c     the backend's Policy.act alone
    ctypes_c                                 the c backend's compiled kernel called through ctypes
                                             on its preallocated buffers, nothing else
    session_run                              onnxruntime InferenceSession.run, as most code calls it
    torch_eager                              the exported torch module, batch 1, inference_mode,
                                             including numpy → tensor → numpy (the baseline)

and, in the same run, the C kernel timed by a loop in C (`test_c_kernel_loop`): `ccode.bench.bench_source`
generates bench.c, which replays the golden vectors and then times 201 repeats of N back-to-back
calls (about 1 ms each) with clock_gettime; built with the c backend's flags (-std=c99 -O2), with
the default expf-based tanh and with libm's tanhf (-DQP_USE_TANHF). The kernel's own latency is the
median repeat; the ctypes call overhead is ctypes_c minus it. Its extra_info also carries the
operation count and the Cortex-M4F cycle estimate of `ccode.bench.cortex_m4_estimate` (the per-operation
figures and their sources are in `ccode.bench.CORTEX_M4_CYCLES`).

Run (the project's addopts disable benchmarks, so enable them here):

    .venv/bin/python -m pytest benchmarks/test_policy_latency.py --benchmark-enable --benchmark-only \
        --benchmark-json=docs/bench/policy_latency.json -p no:cacheprovider
    .venv/bin/python benchmarks/report_latency.py docs/bench/policy_latency.json --strip-data

Each round is one call (`pedantic`, iterations=1), so the round times are the per-call latency
distribution; p50 and p99 are taken from it (pytest-benchmark reports no p99 itself, so it goes into
`extra_info`). Garbage collection stays on, as in the control loop. Without --benchmark-enable each
case runs once, a smoke test (the C loop runs 1,000 calls). The c cases and the C loop need a C
compiler and skip without one. The compiled files go to the c backend's cache and pytest's tmp_path,
never into the repository.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from quadpilot.ccode.bench import bench_source, cortex_m4_estimate, operation_count
from quadpilot.export.onnx_export import deployable, export_onnx
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.runtime.cbackend import COMPILE_FLAGS, find_compiler
from quadpilot.train.algorithms import load_policy as load_trained
from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPOConfig
from quadpilot.train.ppo.checkpoint import save_untrained_policy

MODELS = Path(__file__).parents[1] / "models"
ROUNDS = {"torch_eager": 5_000}
DEFAULT_ROUNDS = 20_000
WARMUP = 500
CASES = (
    "monitored_numpy",
    "monitored_onnxruntime",
    "monitored_c",
    "bare_numpy",
    "bare_onnxruntime",
    "bare_c",
    "ctypes_c",
    "session_run",
    "torch_eager",
)
COMPILER = find_compiler()
LOOP_CALLS = {"mlp": 2_000, "lstm": 500}  # per repeat of the C loop: about a millisecond each
LOOP_REPEATS = 201


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
    if case.endswith("_c") and COMPILER is None:
        pytest.skip("the c backend needs a C compiler")
    if case == "ctypes_c":
        policy = load_policy(onnx_path, "c")
        policy._obs[...] = obs
        kernel, args, out = policy.kernel, policy.kernel_args, policy._out

        def through_ctypes():
            kernel(*args)
            return out

        return through_ctypes
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


@pytest.mark.parametrize("tanh", ["expf", "tanhf"])
@pytest.mark.parametrize("net", ["mlp", "lstm"])
def test_c_kernel_loop(benchmark, networks, net, tanh, tmp_path):
    """The generated kernel timed by a loop in C (bench.c), its golden vectors checked first."""
    if COMPILER is None:
        pytest.skip("the c backend needs a C compiler")
    from quadpilot.ccode.generate import generate, initializers
    from quadpilot.modelfile.model import read_model

    _, onnx_path = networks[net]
    model, info = read_model(onnx_path)
    code = generate(info, initializers(model))
    code.write(tmp_path)
    (tmp_path / "bench.c").write_text(bench_source(info))
    flags = [f for f in COMPILE_FLAGS if f not in ("-fPIC", "-shared")]
    defines = ["-DQP_USE_TANHF"] if tanh == "tanhf" else []
    exe = tmp_path / "bench"
    argv = [*COMPILER, *flags, *defines, "-o", str(exe), "bench.c", "policy.c", "-lm"]
    subprocess.run(argv, cwd=tmp_path, check=True)
    disabled = getattr(benchmark, "disabled", False)
    calls, repeats = (1_000, 1) if disabled else (LOOP_CALLS[net], LOOP_REPEATS)
    done = []

    def run():
        done.append(subprocess.run([str(exe), str(calls), str(repeats)], capture_output=True, text=True, check=True))

    benchmark.group = f"C kernel loop, {net}"
    benchmark.pedantic(run, rounds=1, iterations=1)
    out = done[-1].stdout
    ns = [float(v) for v in re.findall(r"ns_per_inference (\S+)", out)]
    golden = float(re.search(r"golden_max_abs_diff (\S+)", out).group(1))
    assert len(ns) == repeats and golden <= 1e-5, out
    counts = operation_count(code.network)
    benchmark.extra_info.update(
        net=net,
        case=f"kernel_loop_{tanh}",
        p50_us=float(np.median(ns)) / 1000.0,
        min_us=min(ns) / 1000.0,
        max_us=max(ns) / 1000.0,
        calls_per_repeat=calls,
        repeats=repeats,
        golden_max_abs_diff=golden,
        compile=" ".join([*flags, *defines, "bench.c", "policy.c", "-lm"]),
        operations=counts,
        cortex_m4=cortex_m4_estimate(counts),
    )
