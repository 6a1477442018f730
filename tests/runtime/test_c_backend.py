"""The runtime's third backend, "c": the file's network as generated C, compiled once with the
system C compiler and called through ctypes, behind the same `Policy` interface and safety monitor.

It computes what the other backends compute (the contract and golden-vector tests of
test_model_contract.py and the monitor tests of test_safety.py run it too); here: agreement with
the graph beyond the golden vectors, the compile cache, what happens without a compiler, and that
it stays torch-free.
"""

from pathlib import Path

import numpy as np
import pytest

from quadpilot.ccode.generate import SOURCE_NAME, generate, initializers
from quadpilot.modelfile.model import read_model
from quadpilot.runtime import CCompilerError, CPolicy, SafetyMonitor, load_policy
from quadpilot.runtime.cbackend import LIBRARY_NAME, find_compiler

MODELS = Path(__file__).resolve().parents[2] / "models"
HOVER = MODELS / "hover" / "policy.onnx"
REPO = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(find_compiler() is None, reason="the c backend needs a C compiler")


@pytest.fixture
def private_cache(monkeypatch, tmp_path):
    """A cache directory of this test's own (the default is the user's cache)."""
    monkeypatch.setenv("QUADPILOT_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


@pytest.mark.parametrize("task", ["hover", "circle"])
def test_c_backend_gives_the_graphs_commands_off_the_golden_vectors(task):
    """Against ONNX Runtime (the graph itself) on random, even unphysical, observations. The C
    computes the graph's u_hover*sqrt(1 + a); the NumPy backend folds that map into the head (see
    NumpyPolicy), which near a = -1, where sqrt magnifies rounding, differs from both by up to
    4e-5 on such inputs (measured), so it is not the reference here."""
    path = MODELS / task / "policy.onnx"
    c, ref = load_policy(path, "c"), load_policy(path, "onnxruntime")
    assert isinstance(c, CPolicy) and c.backend == "c"
    rng = np.random.default_rng(0)
    obs = rng.normal(0.0, 1.0, (2000, c.obs_dim)).astype(np.float32)
    got = np.stack([c.act(o) for o in obs])
    want = np.stack([ref.act(o) for o in obs])
    assert got.dtype == np.float32 and got.shape == (2000, 4)
    assert np.max(np.abs(got - want)) <= 1e-5
    assert REPO not in c.library.parents, "compiled artefacts stay out of the repository"
    model, info = read_model(path)
    assert c.code.source == generate(info, initializers(model)).source  # the one generator


def test_the_monitor_flies_the_c_kernel_and_still_guards_it():
    monitor = SafetyMonitor(load_policy(HOVER, "c"))
    obs = monitor.policy.info.golden_obs[1].copy()
    assert monitor.act(obs).shape == (4,) and monitor.source == "policy"
    obs[0] = np.inf  # +Inf through the kernel would be full thrust: it must never reach it
    motors = monitor.act(obs)
    assert np.all(np.isfinite(motors)) and monitor.events["obs_nonfinite"] == 1


def test_the_library_is_built_once_and_reused(private_cache):
    first = load_policy(HOVER, "c")
    built = first.library
    assert built.is_file() and built.name == LIBRARY_NAME and private_cache in built.parents
    assert (built.parent / SOURCE_NAME).read_text() == first.code.source  # kept for inspection
    stamp = built.stat().st_mtime_ns
    second = load_policy(HOVER, "c")
    assert second.library == built and built.stat().st_mtime_ns == stamp  # no recompile
    # a cache entry whose source is not the generated one is rebuilt, not trusted
    (built.parent / SOURCE_NAME).write_text("/* something else */\n")
    third = load_policy(HOVER, "c")
    assert (built.parent / SOURCE_NAME).read_text() == third.code.source
    assert third.verify_golden() <= 1e-5


def test_an_unwritable_cache_falls_back_to_a_temporary_directory(monkeypatch, tmp_path):
    blocker = tmp_path / "not_a_directory"
    blocker.write_text("")
    monkeypatch.setenv("QUADPILOT_CACHE_DIR", str(blocker))
    policy = load_policy(HOVER, "c")
    assert blocker not in policy.library.parents and policy.verify_golden() <= 1e-5


def test_without_a_compiler_the_error_says_so(monkeypatch, tmp_path, private_cache):
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))  # no cc, gcc or clang
    with pytest.raises(CCompilerError, match=r"needs a C compiler.*numpy and onnxruntime backends need none") as e:
        load_policy(HOVER, "c")
    assert isinstance(e.value, RuntimeError) and isinstance(e.value, ValueError)
    load_policy(HOVER, "numpy")  # the others are unaffected


def test_a_failing_compiler_is_reported_with_its_output(monkeypatch, tmp_path, private_cache):
    fake = tmp_path / "fakecc"
    fake.write_text("#!/bin/sh\necho 'fakecc: fatal error: no such luck' >&2\nexit 3\n")
    fake.chmod(0o755)
    monkeypatch.setenv("CC", str(fake))
    with pytest.raises(CCompilerError, match=r"compiler failed.*exit 3.*no such luck"):
        load_policy(HOVER, "c")


@pytest.mark.parametrize("activations", [("relu", "elu"), ("elu", "tanh"), ("relu", None)])
def test_every_activation_the_numpy_backend_computes(activations):
    """The generator writes each activation the NumPy backend knows (tanh, relu, elu, none): the
    hover file's weights with other activations named in its architecture give the same commands
    on both backends."""
    import dataclasses

    from quadpilot.runtime.backends import NumpyPolicy
    from quadpilot.runtime.cbackend import build_library

    model, info = read_model(HOVER)
    arch = {**info.architecture, "layers": [dict(layer) for layer in info.architecture["layers"]]}
    for layer, act in zip(arch["layers"], activations, strict=False):
        layer["activation"] = act
    info = dataclasses.replace(info, architecture=arch)
    weights = initializers(model)
    code = generate(info, weights)
    c, ref = CPolicy(info, code, build_library(code)), NumpyPolicy(info, weights)
    obs = np.random.default_rng(1).normal(0.0, 0.5, (500, 18)).astype(np.float32)
    got, want = np.stack([c.act(o) for o in obs]), np.stack([ref.act(o) for o in obs])
    assert np.max(np.abs(got - want)) <= 1e-5
    assert want.std() > 0.01
    if "elu" in activations:
        assert "expm1f(" in code.source
