"""The RAPTOR policy's GRU step (`runtime.gru`) and its loading (`runtime.raptor`): the NumPy step
and the ONNX graph run by ONNX Runtime reproduce the checkpoint's own example (what mc_raptor's
test_policy replays before it flies) and RAPTOR's own package (`foundation_policy`, outside software)
step for step, and agree with each other within 1e-5; a bad weight dict or checkpoint is refused in
one line."""

import itertools
import os

import h5py
import numpy as np
import pytest

from quadpilot.runtime import ModelContractError, SafetyMonitor, load_policy
from quadpilot.runtime.gru import GRU_KEYS, GruStep, OnnxGruStep, check_example, check_weights, weights_from_h5
from quadpilot.runtime.raptor import FOUNDATION, foundation_checkpoint, load_raptor


def _package():
    try:
        import foundation_policy
    except ImportError:
        if os.environ.get("CI"):
            pytest.fail('foundation-policy is not installed: the dev extra installs it (pip install -e ".[dev]")')
        pytest.skip("needs the foundation-policy package: pip install foundation-policy")
    return foundation_policy


@pytest.fixture(scope="module")
def checkpoint():
    _package()
    return weights_from_h5(foundation_checkpoint())


def test_the_checkpoint_has_blob_policy_h_s_shape(checkpoint):
    weights, example = checkpoint
    assert {k: v.shape for k, v in weights.items()} == GRU_KEYS
    assert sum(v.size for v in weights.values()) == 2084
    assert example["input"].shape == (500, 2, 22) and example["output"].shape == (500, 2, 4)


@pytest.mark.parametrize("make", [GruStep, OnnxGruStep], ids=["numpy", "onnxruntime"])
def test_each_step_reproduces_the_checkpoints_example(checkpoint, make):
    weights, example = checkpoint
    assert check_example(make(weights), example) < 1e-6


def test_onnx_and_numpy_agree_within_1e_5_and_with_raptors_own_package(checkpoint):
    weights, _ = checkpoint
    ours, onnx = GruStep(weights), OnnxGruStep(weights)
    theirs = _package().Raptor()
    theirs.reset()
    rng = np.random.default_rng(0)
    h_ours = h_onnx = ours.initial_state.copy()
    worst_onnx = worst_package = 0.0
    for t in range(300):
        x = (rng.normal(size=22) * (0.5 if t % 50 else 3.0)).astype(np.float32)
        a, h_ours = ours(x, h_ours)
        b, h_onnx = onnx(x, h_onnx)
        c = theirs.evaluate_step(x[None])[0]
        worst_onnx = max(worst_onnx, np.abs(a - b).max(), np.abs(h_ours - h_onnx).max())
        worst_package = max(worst_package, np.abs(a - c).max())
    assert worst_onnx <= 1e-5 and worst_package <= 1e-5


def test_the_hidden_state_is_explicit_and_reset_to_the_initial_state(checkpoint):
    weights, _ = checkpoint
    step = GruStep(weights)
    x = np.full(22, 0.3, np.float32)
    a1, h1 = step(x, step.initial_state)
    a2, _ = step(x, h1)
    a3, _ = step(x, step.initial_state)
    assert not np.allclose(a1, a2) and np.array_equal(a1, a3)
    policy = load_raptor(FOUNDATION)
    first = policy.act(np.r_[x[:18], np.zeros(4, np.float32)])
    policy.act(np.r_[x[:18], np.zeros(4, np.float32)])
    policy.reset()
    assert np.array_equal(policy.act(np.r_[x[:18], np.zeros(4, np.float32)]), first)


@pytest.mark.parametrize("backend", ["numpy", "onnxruntime"])
def test_load_policy_knows_the_foundation_policy_and_its_checkpoint_file(backend):
    _package()
    for name in (FOUNDATION, foundation_checkpoint()):
        policy = load_policy(name, backend)
        assert policy.info.layout.name == "px4-raptor" and policy.backend == backend
        assert policy.verify_golden() <= 1e-5
        motors = SafetyMonitor(policy).act(np.r_[np.zeros(3), np.eye(3).ravel(), np.zeros(10)].astype(np.float32))
        assert motors.shape == (4,) and ((0 <= motors) & (motors <= 1)).all()


def test_unknown_backends_and_names_are_refused_in_one_line():
    from quadpilot.runtime.raptor import load_raptor

    with pytest.raises(ValueError, match="numpy, onnxruntime, c backend"):
        load_raptor(FOUNDATION, "torch")
    with pytest.raises(ModelContractError, match="unknown RAPTOR policy name"):
        load_policy("raptor:nonesuch", "numpy")


def test_bad_weight_dicts_are_refused(checkpoint):
    weights, _ = checkpoint
    for key, bad, why in [
        ("layers/1/weights_hidden", np.zeros((16, 48), np.float32), "shape"),
        ("layers/0/biases", np.full(16, np.nan, np.float32), "non-finite"),
        ("layers/2/biases", "four", "not an array of numbers"),
        ("layers/2/biases", np.ones(4, np.int64), "holds int64 values; expected floating-point"),
        ("layers/2/biases", np.ones(4, bool), "holds bool values; expected floating-point"),
    ]:
        with pytest.raises(ModelContractError, match=why):
            check_weights({**weights, key: bad})
    with pytest.raises(ModelContractError, match="no 'layers/0/weights'"):
        check_weights({k: v for k, v in weights.items() if k != "layers/0/weights"})
    with pytest.raises(ModelContractError, match="unexpected keys"):
        check_weights({**weights, "layers/3/weights": np.zeros(1)})


def test_a_checkpoint_that_is_not_raptors_shape_or_not_its_example_is_refused(tmp_path, checkpoint):
    weights, example = checkpoint
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5 at all")
    with pytest.raises(ModelContractError, match="not an RLtools GRU checkpoint") as e:
        load_policy(junk, "numpy")
    assert "\n" not in str(e.value)

    def write(path, tanh_output=False, scale=1.0):
        with h5py.File(path, "w") as f:
            layers = f.create_group("actor/layers")
            for key, value in weights.items():
                layers.create_dataset(key.split("/", 1)[1] + "/parameters", data=value * scale)
            layers["0"].attrs["activation_function"] = "RELU"
            layers["2"].attrs["activation_function"] = "TANH" if tanh_output else "IDENTITY"
            f.create_dataset("example/input", data=example["input"])
            f.create_dataset("example/output", data=example["output"])

    write(tmp_path / "same.h5")
    assert load_policy(tmp_path / "same.h5", "numpy").info.layout.name == "px4-raptor"
    write(tmp_path / "tanh.h5", tanh_output=True)
    with pytest.raises(ModelContractError, match="activation 'TANH'"):
        load_policy(tmp_path / "tanh.h5", "numpy")
    write(tmp_path / "other.h5", scale=1.01)
    with pytest.raises(ModelContractError, match="example is not reproduced"):
        load_policy(tmp_path / "other.h5", "numpy")


@pytest.mark.parametrize(("step_us", "force_sync"), [(4_000, 2), (10_000, 1), (2_000, 5), (20_000, 0)])
def test_the_gyro_rate_is_measured_from_the_first_two_steps(step_us, force_sync):
    """IMU_GYRO_RATEMAX / 100 from the simulator's step: at 250 Hz the GRU state advances on every
    second call, the calls between leave it as it was; a reset measures again."""
    _package()
    policy = load_raptor(FOUNDATION)
    state = [0.1, -0.2, 2.05, 0.1, 0.0, -0.1, 0.02, -0.01, 0.3, 0.01, 0.02, -0.03]
    states = []
    for k in range(4):
        policy.act(policy.own_observation(state, [0.0, 0.0, 2.0], None, 0.3, 1_000_000 + k * step_us))
        states.append(policy.executor.state.copy())
    assert policy.executor.force_sync == force_sync
    advanced = [not np.array_equal(a, b) for a, b in itertools.pairwise(states)]
    assert advanced == [force_sync <= 1 or (k + 1) % force_sync == 0 for k in range(3)]
    policy.reset()
    assert policy.step_s is None and np.array_equal(policy.executor.state, policy.executor.initial_state)


def test_the_safety_monitor_checks_the_previous_action_and_hands_over_to_a_fallback_that_reads_it():
    """In range, the policy flies; a previous action outside [−1, 1] is a bad observation (blind);
    beyond the envelope the fallback flies on the hover-layout form of the observation."""
    from quadpilot.core.px4_raptor import fallback_observation
    from quadpilot.runtime.fallback import FallbackController

    _package()
    policy = load_raptor(FOUNDATION)
    monitor = SafetyMonitor(policy)
    level = np.r_[0.1, -0.2, 0.05, np.eye(3).ravel(), 0.1, 0.0, -0.1, 0.01, 0.02, -0.03].astype(np.float32)
    monitor.act(np.r_[level, 0.9, -0.9, 0.2, 1.0].astype(np.float32))
    assert monitor.source == "policy" and not monitor.events
    monitor.act(np.r_[level, 1.5, 0.0, 0.0, 0.0].astype(np.float32))
    assert monitor.events["obs_out_of_range"] == 1
    monitor.reset()
    c, s = np.cos(np.radians(88.0)), np.sin(np.radians(88.0))  # rolled 88°: beyond the 85° envelope
    rolled = np.array([[1, 0, 0], [0, c, -s], [0, s, c]], np.float32).ravel()
    obs = np.r_[0.1, -0.2, 0.05, rolled, 0.1, 0.0, -0.1, 0.01, 0.02, -0.03, np.zeros(4)].astype(np.float32)
    cmd = monitor.act(obs)
    want = FallbackController(policy.info.vehicle, policy.info.control_period_s, heading_frame=True)
    assert monitor.events["out_of_envelope"] == 1 and monitor.source == "fallback"
    np.testing.assert_array_equal(cmd, np.clip(want.act(fallback_observation(obs)), 0.0, 1.0))


def test_a_checkpoint_is_checked_shape_by_shape_before_anything_is_read(tmp_path, checkpoint):
    """A dataset of the wrong shape (here a 10⁸-row example, which a reader that reads first would
    allocate) or a checkpoint without an example is refused in one line, naming what was wrong."""
    weights, example = checkpoint

    def write(path, big_example=False, no_example=False):
        with h5py.File(path, "w") as f:
            layers = f.create_group("actor/layers")
            for key, value in weights.items():
                layers.create_dataset(key.split("/", 1)[1] + "/parameters", data=value)
            layers["0"].attrs["activation_function"] = "RELU"
            layers["2"].attrs["activation_function"] = "IDENTITY"
            if big_example:  # declared, never written: HDF5 stores nothing for it
                f.create_dataset("example/input", shape=(100_000_000, 2, 22), dtype="f4")
                f.create_dataset("example/output", shape=(100_000_000, 2, 4), dtype="f4")
            elif not no_example:
                f.create_dataset("example/input", data=example["input"])
                f.create_dataset("example/output", data=example["output"])

    write(tmp_path / "big.h5", big_example=True)
    with pytest.raises(ModelContractError, match=r"input has shape \(100000000, 2, 22\)"):
        load_policy(tmp_path / "big.h5", "numpy")
    write(tmp_path / "none.h5", no_example=True)
    with pytest.raises(ModelContractError, match="no input/output example to replay"):
        load_policy(tmp_path / "none.h5", "numpy")


def test_a_plain_weight_dict_from_any_reader_makes_the_same_policy(checkpoint):
    """What an RLtools policy.tar reader would hand over: named float32 arrays (dense biases as RLtools
    stores them, (1, n)) and the example; the policy flies the same commands as the .h5's."""
    from quadpilot.runtime.raptor import raptor_from_weights

    weights, example = checkpoint
    plain = {
        k: (v[None] if k.endswith("/biases") and k.startswith(("layers/0", "layers/2")) else v)
        for k, v in weights.items()
    }
    policy = raptor_from_weights(plain, example, "plain dict", "0" * 64)
    reference = load_raptor(FOUNDATION)
    for t in range(5):
        obs = example["input"][t, 1]
        np.testing.assert_array_equal(policy.act(obs), reference.act(obs))


# --- the generated C (ccode.gru, runtime.cgru) ----------------------------------------------


NO_COMPILER = "no C compiler on PATH (nor $CC); install one: apt-get install gcc"


def _c_step_or_skip(weights):
    """The compiled step. Only a missing compiler skips, and only outside CI (env CI unset); a
    compiler that fails on the generated C fails the test (CCompilerError propagates)."""
    from quadpilot.runtime.cbackend import find_compiler
    from quadpilot.runtime.cgru import CGruStep

    if find_compiler() is None:
        if os.environ.get("CI"):
            pytest.fail(f"{NO_COMPILER} (CI must run this test)")
        pytest.skip(NO_COMPILER)
    return CGruStep(weights)


def test_a_failed_compile_of_the_generated_c_fails_and_only_a_missing_compiler_skips(monkeypatch, tmp_path):
    from pathlib import Path

    from quadpilot.runtime.cbackend import CCompilerError
    from quadpilot.runtime.rltools_tar import read_policy_tar

    weights = read_policy_tar(Path(__file__).parents[2] / "models/hover_px4_raptor_sih/policy.tar").weights
    monkeypatch.setenv("QUADPILOT_CACHE_DIR", str(tmp_path))  # nothing cached to load instead
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.setenv("CC", "false")  # a compiler that exits 1 on anything
    try:
        _c_step_or_skip(weights)
    except pytest.skip.Exception as e:  # the test would be reported skipped, not failed
        pytest.fail(f"a failed compile of the generated C was turned into a skip: {e}")
    except CCompilerError as e:
        assert "compiler failed" in str(e)
    else:
        pytest.fail("`false` compiled the generated C")
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    with pytest.raises(pytest.skip.Exception, match="apt-get install gcc"):
        _c_step_or_skip(weights)
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="CI must run this test"):
        _c_step_or_skip(weights)


def test_the_c_step_gives_the_numpy_steps_actions_and_states():
    import numpy as np

    from quadpilot.runtime.gru import GruStep, sequences, weights_from_h5
    from quadpilot.runtime.raptor import foundation_checkpoint

    weights, example = weights_from_h5(foundation_checkpoint())
    c, n = _c_step_or_skip(weights), GruStep(weights)
    xs = example["input"]
    assert np.max(np.abs(sequences(c, xs) - sequences(n, xs))) <= 1e-5
    assert np.max(np.abs(sequences(c, xs) - example["output"])) <= 1e-5
    rng = np.random.default_rng(5)  # and off the example: wide inputs, a state carried 200 steps
    h_c = h_n = c.initial_state.copy()
    for _ in range(200):
        x = rng.uniform(-3, 3, 22).astype(np.float32)
        (a_c, h_c), (a_n, h_n) = c(x, h_c), n(x, h_n)
        assert np.max(np.abs(a_c - a_n)) <= 1e-5 and np.max(np.abs(h_c - h_n)) <= 1e-5
