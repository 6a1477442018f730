"""quad-export --format c: the policy as dependency-free C99, checked the way a flight-controller
build would use it.

The generated policy.c compiles with the system C compiler under strict warnings as errors, calls
nothing but libm, keeps no mutable state, holds the ONNX file's float32 weights bit for bit, and,
called through ctypes, gives the ONNX model's motor commands within 1e-5 on the ONNX parity check's
own inputs: the 10,000 observations of `parity_observations` (MLP: the shipped hover policy and a
normalised one) and the 500-step sequences with resets of `parity_sequences` (an untrained LSTM).
The header documents what the ONNX metadata says. Where arm-none-eabi-gcc is installed it builds
for a Cortex-M4F and reports the flash and RAM footprint.
"""

from __future__ import annotations

import ctypes
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest

from quadpilot.ccode.bench import bench_source, operation_count
from quadpilot.ccode.text import ENTRY, RESET, STEP
from quadpilot.export.c_export import export_c
from quadpilot.export.cli import main
from quadpilot.export.onnx_export import _step_sequences, parity_observations, parity_sequences, sha256_of
from quadpilot.modelfile.model import read_model
from quadpilot.runtime.cbackend import find_compiler
from quadpilot.train.algorithms import load_checkpoint, load_policy
from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPOConfig
from quadpilot.train.ppo.checkpoint import save_untrained_policy

MODELS = Path(__file__).parents[2] / "models"
COMPILER = find_compiler()
needs_cc = pytest.mark.skipif(COMPILER is None, reason="no C compiler found (CC, cc, gcc or clang)")
STRICT = [
    "-std=c99",
    "-O2",
    "-Wall",
    "-Wextra",
    "-Wpedantic",
    "-Werror",
    "-Wconversion",
    "-Wshadow",
    "-Wdouble-promotion",  # a double on a single-precision FPU is software-emulated
    "-Wstrict-prototypes",
    "-Wmissing-prototypes",
    "-Wvla",
    "-Wcast-qual",
]
LIBM = {"expf", "sqrtf", "tanhf", "expm1f"}
TOLERANCE = 1e-5
TANHF_TOLERANCE = 2e-5
"""libm's tanhf (-DQP_USE_TANHF) against ONNX: not the form quad-export writes and checks against
TOLERANCE, but an option for a libm whose tanhf is cheap; it rounds differently from ONNX Runtime's
tanh, and on models/hover as retrained through delay it reached 1.12e-5 over the parity observations."""
ARM_GCC, ARM_SIZE = shutil.which("arm-none-eabi-gcc"), shutil.which("arm-none-eabi-size")
CORTEX_M4F = ["-mcpu=cortex-m4", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-mthumb"]


@pytest.fixture(scope="module")
def exports(tmp_path_factory):
    """name → (policy.pt, policy.onnx, the C directory), each exported by `export_c`."""
    import torch

    root = tmp_path_factory.mktemp("c_export")
    lstm_pt = save_untrained_policy(
        root / "lstm.pt", PPOConfig(arch="lstm", lstm_hidden=64), make_config("hover")
    )  # untrained, head gain 1: commands that vary (as in test_onnx_export)
    ckpt = load_checkpoint(MODELS / "hover" / "policy.pt")
    ckpt["ppo_config"]["normalize_obs"] = True  # as test_onnx_export's normalised MLP
    rng = np.random.default_rng(0)
    ckpt["obs_rms"]["mean"] = torch.as_tensor(rng.normal(0, 0.3, 18))
    ckpt["obs_rms"]["var"] = torch.as_tensor(rng.uniform(0.05, 2.0, 18))
    norm_pt = root / "norm.pt"
    torch.save(ckpt, norm_pt)
    out = {}
    for name, pt in (("hover", MODELS / "hover" / "policy.pt"), ("normalised", norm_pt), ("lstm", lstm_pt)):
        d = root / name
        d.mkdir()
        export_c(pt, d / "c", onnx_path=d / "policy.onnx")
        out[name] = (pt, d / "policy.onnx", d / "c")
    return out


def compile_strict(c_dir: Path, out: Path, *extra: str) -> ctypes.CDLL:
    argv = [*COMPILER, *STRICT, *extra, "-fPIC", "-shared", "-o", str(out), str(c_dir / "policy.c"), "-lm"]
    done = subprocess.run(argv, capture_output=True, text=True)
    assert done.returncode == 0, f"{' '.join(argv)}\n{done.stderr}"
    return ctypes.CDLL(str(out))


def session(path: Path) -> ort.InferenceSession:
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def c_mlp(lib: ctypes.CDLL, obs: np.ndarray) -> np.ndarray:
    """The C entry point on each row of obs (N, D), one call per observation."""
    fn = getattr(lib, ENTRY)
    fn.argtypes, fn.restype = [ctypes.c_void_p, ctypes.c_void_p], None
    obs = np.ascontiguousarray(obs, np.float32)
    out = np.zeros((len(obs), 4), np.float32)
    o, y, d = obs.ctypes.data, out.ctypes.data, obs.shape[1] * 4
    for k in range(len(obs)):
        fn(o + k * d, y + k * 16)
    return out


def c_sequences(lib: ctypes.CDLL, obs: np.ndarray, starts: np.ndarray, hidden: int) -> np.ndarray:
    """The C step over (T, B, D), one sequence at a time, state reset (by the C helper) at starts."""
    step, reset = getattr(lib, STEP), getattr(lib, RESET)
    step.argtypes, step.restype = [ctypes.c_void_p] * 4, None
    reset.argtypes, reset.restype = [ctypes.c_void_p] * 2, None
    t_len, b, d = obs.shape
    obs = np.ascontiguousarray(obs, np.float32)
    out = np.zeros((t_len, b, 4), np.float32)
    h = np.full(hidden, np.nan, np.float32)  # reset must overwrite whatever was there
    c = np.full(hidden, np.nan, np.float32)
    hp, cp, o, y = h.ctypes.data, c.ctypes.data, obs.ctypes.data, out.ctypes.data
    for j in range(b):
        for t in range(t_len):
            if starts[t, j]:
                reset(hp, cp)
            k = t * b + j
            step(o + 4 * d * k, hp, cp, y + 16 * k)
    return out


# --- what the files say and hold -------------------------------------------------------------


@pytest.mark.parametrize("name", ["hover", "normalised", "lstm"])
def test_header_documents_what_the_onnx_metadata_says(exports, name):
    pt, onnx_path, c_dir = exports[name]
    _, info = read_model(onnx_path)
    header = (c_dir / "policy.h").read_text()
    for text in (header, (c_dir / "policy.c").read_text()):
        assert text.isascii()
    assert f'#define QP_SOURCE_SHA256 "{sha256_of(pt)}"' in header
    assert f"#define QP_OBS_DIM {info.obs_dim}" in header and "#define QP_NUM_MOTORS 4" in header
    assert f'#define QP_OBS_LAYOUT "{info.layout.name}"' in header and '#define QP_TASK "hover"' in header
    assert "#define QP_CONTROL_PERIOD_S 0.01f" in header and "100 Hz" in header
    assert "#define QP_MAX_DISTANCE_M 5.0f" in header and "#define QP_MAX_TILT_DEG 60.0f" in header
    assert '"mass": 0.665' in header  # the vehicle, from the metadata
    for field, sl in info.layout.slices().items():  # every field of the layout table, with its unit
        f = next(f for f in info.layout.fields if f.name == field)
        assert re.search(rf"\[{sl.start}\.\.{sl.stop - 1}\]\s+{field}\s+{re.escape(f.unit)}\s", header), field
        assert f"#define QP_OBS_{field.upper()} {sl.start} " in header
    assert "HIL_ACTUATOR_CONTROLS" in header and "PX4 quad-X order: 0 front_right, 1 rear_left" in header
    assert info.action_meaning in header.replace("\n * ", " ")
    if info.recurrent:
        assert f"#define QP_HIDDEN {info.hidden}" in header and STEP in header and RESET in header
    else:
        assert f"void {ENTRY}(const float obs[QP_OBS_DIM], float motors[QP_NUM_MOTORS]);" in header


@pytest.mark.parametrize("name", ["hover", "normalised", "lstm"])
def test_weights_are_the_onnx_initializers_bit_for_bit(exports, name):
    import onnx
    from onnx import numpy_helper

    _, onnx_path, c_dir = exports[name]
    model = onnx.load(str(onnx_path))
    init = {t.name: numpy_helper.to_array(t) for t in model.graph.initializer}
    arch = json.loads(next(p.value for p in model.metadata_props if p.key == "quadpilot.architecture"))
    source = (c_dir / "policy.c").read_text()
    arrays = {}
    for m in re.finditer(r"static const float (\w+)((?:\[\d+\])+) = \{(.*?)\};", source, re.S):
        shape = tuple(int(n) for n in re.findall(r"\d+", m.group(2)))
        values = [float(v.rstrip("f")) for v in re.findall(r"-?[\d.]+(?:e[-+]?\d+)?f", m.group(3))]
        arrays[m.group(1)] = np.array(values, np.float32).reshape(shape)

    def same(c_name, onnx_value):
        want = np.asarray(onnx_value, np.float32)
        got = arrays[c_name]
        assert got.shape == want.shape and np.array_equal(got.view(np.int32), want.view(np.int32)), c_name

    for k, layer in enumerate(arch["layers"]):
        same(f"qp_w{k}", init[layer["weight"]].T)  # stored [in][out]
        same(f"qp_b{k}", init[layer["bias"]] if layer["bias"] else np.zeros(init[layer["weight"]].shape[0]))
    if arch["normalize"]:
        same("qp_obs_mean", init[arch["normalize"]["mean"]])
        same("qp_obs_inv_std", init[arch["normalize"]["inv_std"]])
    if arch["kind"] == "lstm":
        same("qp_lstm_w_ih", init[arch["lstm"]["weight_ih"]].T)
        same("qp_lstm_w_hh", init[arch["lstm"]["weight_hh"]].T)
    n_weights = sum(a.size for a in arrays.values())
    assert n_weights == operation_count_for(onnx_path)["weights"]


def operation_count_for(onnx_path):
    from quadpilot.ccode.generate import initializers, network_from_model

    model, info = read_model(onnx_path)
    return operation_count(network_from_model(info, initializers(model)))


@needs_cc
@pytest.mark.parametrize("name", ["hover", "lstm"])
def test_object_calls_only_libm_and_keeps_no_state(exports, name, tmp_path):
    """No heap, no stdio, no global or static mutable data: the undefined symbols of policy.o are
    libm's, and it has no .data or .bss symbol."""
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("nm (binutils) not found")
    _, _, c_dir = exports[name]
    obj = tmp_path / "policy.o"
    subprocess.run([*COMPILER, *STRICT, "-c", "-o", str(obj), str(c_dir / "policy.c")], check=True)
    for extra in ([], ["-DQP_USE_TANHF"]):
        subprocess.run([*COMPILER, *STRICT, *extra, "-c", "-o", str(obj), str(c_dir / "policy.c")], check=True)
        symbols = [
            line.split() for line in subprocess.run([nm, str(obj)], capture_output=True, text=True).stdout.splitlines()
        ]
        undefined = {s[-1] for s in symbols if s[-2] == "U"}
        assert undefined <= LIBM, undefined
        assert not [s for s in symbols if s[-2] in "bBdDcC"], symbols
        exported = {s[-1] for s in symbols if s[-2] == "T"}
        assert exported == ({STEP, RESET} if name == "lstm" else {ENTRY})


# --- parity with the ONNX model ----------------------------------------------------------------


@needs_cc
@pytest.mark.parametrize("tanh", ["expf", "tanhf"])
@pytest.mark.parametrize("name", ["hover", "normalised"])
def test_mlp_parity_with_onnx_on_the_parity_observations(exports, name, tanh, tmp_path):
    pt, onnx_path, c_dir = exports[name]
    lib = compile_strict(c_dir, tmp_path / "libpolicy.so", *(["-DQP_USE_TANHF"] if tanh == "tanhf" else []))
    obs = parity_observations(load_policy(pt))  # the 10,000 of the ONNX parity check
    assert obs.shape == (10_000, 18)
    want = session(onnx_path).run(["action"], {"obs": obs})[0]
    got = c_mlp(lib, obs)
    diff = float(np.max(np.abs(got - want)))
    print(f"{name} ({tanh}): max abs difference C vs ONNX over {len(obs):,} observations {diff:.2e}")
    assert diff <= (TOLERANCE if tanh == "expf" else TANHF_TOLERANCE)
    assert want.std() > 0.05  # the comparison is not blind: commands span a real range


@pytest.fixture(scope="module")
def lstm_reference(exports):
    """The ONNX parity check's LSTM inputs (500 steps × 20 sequences; state reset at the start, on
    episode ends and half-way) and the ONNX model's commands over them."""
    pt, onnx_path, _ = exports["lstm"]
    obs, starts = parity_sequences(load_policy(pt))
    s = session(onnx_path)

    def ort_step(o, h, c):
        return tuple(s.run(None, {"obs": o, "h_in": h, "c_in": c}))

    return obs, starts, _step_sequences(ort_step, obs, starts, 64)


@needs_cc
@pytest.mark.parametrize("tanh", ["expf", "tanhf"])
def test_lstm_parity_with_onnx_over_sequences_with_resets(exports, lstm_reference, tanh, tmp_path):
    _, _, c_dir = exports["lstm"]
    lib = compile_strict(c_dir, tmp_path / "libpolicy.so", *(["-DQP_USE_TANHF"] if tanh == "tanhf" else []))
    obs, starts, want = lstm_reference
    got = c_sequences(lib, obs, starts, 64)
    diff = float(np.max(np.abs(got - want)))
    print(f"lstm ({tanh}): max abs difference C vs ONNX over {obs.shape[0] * obs.shape[1]:,} steps {diff:.2e}")
    assert diff <= TOLERANCE
    # not blind: without the half-way reset the C gives other commands
    no_reset = starts.copy()
    no_reset[obs.shape[0] // 2] = False
    assert np.max(np.abs(c_sequences(lib, obs, no_reset, 64) - want)) > 1e-3


@needs_cc
def test_bench_program_replays_the_golden_vectors(exports, tmp_path):
    """bench.c (the timing loop of benchmarks/test_policy_latency.py) checks the golden vectors
    first and fails with exit status 1 if the kernel does not reproduce them."""
    for name in ("hover", "lstm"):
        _, onnx_path, c_dir = exports[name]
        _, info = read_model(onnx_path)
        (tmp_path / "bench.c").write_text(bench_source(info))
        exe = tmp_path / f"bench_{name}"
        argv = [*COMPILER, *STRICT, f"-I{c_dir}", "-o", str(exe), str(tmp_path / "bench.c"), str(c_dir / "policy.c")]
        subprocess.run([*argv, "-lm"], check=True)
        done = subprocess.run([str(exe), "1000", "1"], capture_output=True, text=True)
        assert done.returncode == 0, done.stdout + done.stderr
        assert re.search(r"golden_max_abs_diff \S+\nns_per_inference \d+", done.stdout), done.stdout


# --- the command line --------------------------------------------------------------------------


def test_cli_format_c_writes_the_directory_and_reports_parity(exports, tmp_path, capsys):
    pt, _, _ = exports["lstm"]
    out = tmp_path / "policy_c"
    assert main([str(pt), "--format", "c", "-o", str(out), "--parity-samples", "1000"]) == 0
    text = capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["policy.c", "policy.h"]
    assert "parity within 1e-05: ok" in text
    if COMPILER is not None:
        assert "runtime c" in text and "golden vectors" in text
    (tmp_path / "a_file").write_text("")
    assert main([str(pt), "--format", "c", "-o", str(tmp_path / "a_file")]) == 2
    assert "not a directory" in capsys.readouterr().err
    assert main([str(pt), "--format", "rust"]) == 2


# --- a Cortex-M4F build ------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["hover", "lstm"])
def test_cortex_m4f_build_and_footprint(exports, name, tmp_path):
    """The kernel builds for a Cortex-M4F with the same strict warnings; flash = text (code and
    the const weights), RAM = data + bss (none: no state) + the stack the compiler reports."""
    if ARM_GCC is None or ARM_SIZE is None:  # in CI (.ci/run installs it) a missing cross compiler fails
        why = "arm-none-eabi-gcc not installed: apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi"
        pytest.fail(why) if os.environ.get("CI") else pytest.skip(why)
    _, onnx_path, c_dir = exports[name]
    obj = tmp_path / "policy.o"
    argv = [ARM_GCC, *STRICT, *CORTEX_M4F, "-fstack-usage", "-c", "-o", str(obj), str(c_dir / "policy.c")]
    done = subprocess.run(argv, capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    size = subprocess.run([ARM_SIZE, str(obj)], capture_output=True, text=True, check=True).stdout
    text, data, bss = (int(v) for v in size.splitlines()[1].split()[:3])
    stack = {
        line.split()[0].split(":")[-1]: int(line.split()[1])
        for line in (tmp_path / "policy.su").read_text().splitlines()
    }
    entry = STEP if name == "lstm" else ENTRY
    weights = operation_count_for(onnx_path)["weights"]
    print(
        f"Cortex-M4F {name}: text {text} B (weights {4 * weights} B, code {text - 4 * weights} B), "
        f"data {data} B, bss {bss} B, stack of {entry} {stack[entry]} B"
    )
    assert data == 0 and bss == 0
    assert 4 * weights <= text <= 4 * weights + 4096
    assert stack[entry] < 2048
    # linked with newlib's libm: the libm code it pulls in is single precision (a call to a
    # software double helper, __aeabi_d*, would cost hundreds of cycles per call on the M4F)
    call = f"{STEP}(o, h, c, m)" if name == "lstm" else f"{ENTRY}(o, m)"
    state = "float h[QP_HIDDEN] = {0}, c[QP_HIDDEN] = {0};" if name == "lstm" else ""
    (tmp_path / "main.c").write_text(
        '#include "policy.h"\nvolatile float in[QP_OBS_DIM], out[QP_NUM_MOTORS];\n'
        "int main(void)\n{\n    float o[QP_OBS_DIM], m[QP_NUM_MOTORS];\n    int i;\n"
        f"    {state}\n    for (i = 0; i < QP_OBS_DIM; ++i) o[i] = in[i];\n    {call};\n"
        "    for (i = 0; i < QP_NUM_MOTORS; ++i) out[i] = m[i];\n    return 0;\n}\n"
    )
    elf = tmp_path / "policy.elf"
    link = [ARM_GCC, "-std=c99", "-O2", *CORTEX_M4F, f"-I{c_dir}", "-Wl,--gc-sections", "--specs=nano.specs"]
    link += ["--specs=nosys.specs", "-o", str(elf), str(tmp_path / "main.c"), str(c_dir / "policy.c"), "-lm"]
    subprocess.run(link, check=True, capture_output=True)
    nm = shutil.which("arm-none-eabi-nm")
    if nm is not None:
        symbols = subprocess.run([nm, "-S", str(elf)], capture_output=True, text=True, check=True).stdout
        assert "__aeabi_d" not in symbols, [line for line in symbols.splitlines() if "__aeabi_d" in line]
        libm = {
            parts[-1]: int(parts[1], 16)
            for parts in (line.split() for line in symbols.splitlines())
            if len(parts) == 4 and parts[-1] in ("expf", "__ieee754_expf", "sqrtf", "__ieee754_sqrtf", "finitef")
        }
        print(f"  libm code linked (newlib): {libm} = {sum(libm.values())} B")
