"""A dense → GRU → dense policy step in NumPy, and the same step as an ONNX graph for ONNX Runtime,
both with the hidden state explicit (in and out): the shape of the RAPTOR foundation policy PX4's
mc_raptor flies (src/modules/mc_raptor/blob/policy.h: dense 22 → 16 ReLU, GRU 16, dense 16 → 4
identity; 2,084 parameters).

The weights are a plain dict of float32 arrays (`GRU_KEYS`), named after RLtools' layers and
parameters as its checkpoints store them (actor/layers/<i>/<parameter>/parameters), so any reader
of an RLtools checkpoint can fill it:

    layers/0/weights                (16, 22)  dense input layer, y = ReLU(W·x + b)
    layers/0/biases                 (16,)
    layers/1/weights_input          (48, 16)  GRU, gates stacked r, z, n (RLtools' order)
    layers/1/biases_input           (48,)
    layers/1/weights_hidden         (48, 16)
    layers/1/biases_hidden          (48,)
    layers/1/initial_hidden_state   (16,)     the state after a reset (learned; zero in RAPTOR's)
    layers/2/weights                (4, 16)   dense output layer, identity
    layers/2/biases                 (4,)

The GRU is RLtools' (rl_tools/nn/layers/gru), the same equations as PyTorch's: with
gi = W_i·y + b_i and gh = W_h·h + b_h split into r, z, n thirds,
r = σ(gi_r + gh_r), z = σ(gi_z + gh_z), n = tanh(gi_n + r ⊙ gh_n), h' = (1 − z) ⊙ n + z ⊙ h.
ONNX's GRU operator computes this with linear_before_reset = 1 and its gates ordered z, r, h.

`weights_from_h5` reads an RLtools HDF5 checkpoint (what the foundation-policy package ships; h5py
is imported there only) and `check_example` replays the input/output example an RLtools checkpoint
carries, as mc_raptor's `test_policy` does before it flies.
"""

from __future__ import annotations

import math

import numpy as np

from quadpilot.core.px4_raptor import ACTION_DIM, OBS_DIM
from quadpilot.modelfile.contract import ModelContractError, one_line, quote

HIDDEN = 16
GRU_KEYS = {
    "layers/0/weights": (HIDDEN, OBS_DIM),
    "layers/0/biases": (HIDDEN,),
    "layers/1/weights_input": (3 * HIDDEN, HIDDEN),
    "layers/1/biases_input": (3 * HIDDEN,),
    "layers/1/weights_hidden": (3 * HIDDEN, HIDDEN),
    "layers/1/biases_hidden": (3 * HIDDEN,),
    "layers/1/initial_hidden_state": (HIDDEN,),
    "layers/2/weights": (ACTION_DIM, HIDDEN),
    "layers/2/biases": (ACTION_DIM,),
}
"""The weight dict's keys and shapes (see the module docstring)."""
ACTIVATIONS = {"layers/0": "RELU", "layers/2": "IDENTITY"}
"""What blob/policy.h fixes the dense layers' activation functions to."""
EXAMPLE_TOLERANCE = 1e-5
"""Mean absolute difference on a checkpoint's example that mc_raptor's test_policy accepts."""


def check_weights(weights: dict, where: str = "GRU weights") -> dict:
    """The dict as float32 arrays of exactly `GRU_KEYS`' shapes, all finite (a (1, n) bias, as RLtools
    stores dense biases, is taken as (n,)), from floating-point arrays only (bool, integer and complex
    ones are refused, not cast); ModelContractError naming the first problem otherwise."""
    out = {}
    for key, shape in GRU_KEYS.items():
        if key not in weights:
            raise ModelContractError(f"{where}: no {key!r}; expected the keys {sorted(GRU_KEYS)}")
        try:
            a = np.asarray(weights[key])
        except (TypeError, ValueError):
            a = np.asarray(None)
        # a cast would pass true/false, integers or the real part of complex numbers off as weights
        if a.dtype.kind in "biuc":
            raise ModelContractError(f"{where}: {key} holds {a.dtype} values; expected floating-point numbers")
        try:
            a = a.astype(np.float32)
        except (TypeError, ValueError):
            raise ModelContractError(f"{where}: {key} is not an array of numbers") from None
        if a.ndim == 2 and a.shape[0] == 1 and len(shape) == 1:
            a = a.reshape(-1)
        if a.shape != shape:
            raise ModelContractError(f"{where}: {key} has shape {a.shape}; expected {shape}")
        if not np.isfinite(a).all():
            raise ModelContractError(f"{where}: {key} holds non-finite values")
        out[key] = np.ascontiguousarray(a)
    extra = sorted(set(weights) - set(GRU_KEYS))
    if extra:
        raise ModelContractError(f"{where}: unexpected keys {extra[:3]}; expected only {sorted(GRU_KEYS)}")
    return out


class GruStep:
    """The NumPy step: `step(x, h) → (action (4,), h' (16,))`, float32 throughout. The weights are
    rearranged once (biases of r and z summed; each product a matrix-vector call on contiguous
    rows), which is what makes a step some 20 NumPy calls."""

    def __init__(self, weights: dict) -> None:
        w = check_weights(weights)
        self.initial_state = w["layers/1/initial_hidden_state"]
        self._w0, self._b0 = w["layers/0/weights"], w["layers/0/biases"]
        self._wi, self._wh = w["layers/1/weights_input"], w["layers/1/weights_hidden"]
        bi, bh = w["layers/1/biases_input"], w["layers/1/biases_hidden"]
        self._b_rz = bi[: 2 * HIDDEN] + bh[: 2 * HIDDEN]
        self._bi_n, self._bh_n = bi[2 * HIDDEN :].copy(), bh[2 * HIDDEN :].copy()
        self._w2, self._b2 = w["layers/2/weights"], w["layers/2/biases"]
        self._one = np.float32(1.0)

    def __call__(self, x: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        y = self._w0 @ x
        y += self._b0
        np.maximum(y, 0.0, out=y)
        gi = self._wi @ y
        gh = self._wh @ h
        rz = gi[: 2 * HIDDEN] + gh[: 2 * HIDDEN]
        rz += self._b_rz
        np.negative(rz, out=rz)
        np.exp(rz, out=rz)
        rz += self._one
        np.reciprocal(rz, out=rz)  # σ(v) = 1 / (1 + e^−v)
        r, z = rz[:HIDDEN], rz[HIDDEN:]
        ghn = gh[2 * HIDDEN :]
        ghn += self._bh_n
        ghn *= r
        n = gi[2 * HIDDEN :]
        n += self._bi_n
        n += ghn
        np.tanh(n, out=n)
        new = h - n
        new *= z
        new += n  # (1 − z)·n + z·h = n + z·(h − n)
        a = self._w2 @ new
        a += self._b2
        return a, new


# exp by Cody and Waite's reduction and a Taylor polynomial, IEEE-754 double operations alone (no
# libm, no SIMD function, no fused multiply-add): the same bits on any machine
_LN2_HI = 6.93147180369123816490e-01  # ln 2 in its 32 high bits: k * _LN2_HI is exact for |k| < 2^20
_LN2_LO = 1.90821492927058770002e-10
_EXP_TAYLOR = [1.0 / math.factorial(i) for i in range(14, -1, -1)]  # |r| <= ln2/2: error below 1e-17


def _portable_exp(x: np.ndarray) -> np.ndarray:
    """e^x in float64 for -700 < x < 700 (the caller keeps it there), elementwise +, -, * only."""
    k = np.rint(x * 1.4426950408889634)  # 1 / ln 2
    r = (x - k * _LN2_HI) - k * _LN2_LO
    p = np.full_like(r, _EXP_TAYLOR[0])
    for c in _EXP_TAYLOR[1:]:
        p = p * r + c
    return np.ldexp(p, k.astype(np.int64))


class PortableStep:
    """`GruStep`'s equations computed so that the result is the same to the bit on every machine:
    in float64, every product and sum an elementwise NumPy operation in one fixed order (a matrix
    row's terms added left to right, no BLAS, whose kernels order and fuse them by CPU), exp from
    `_portable_exp` (no libm or SIMD function), and the action and state rounded to float32. It is
    the reference the stored example of a policy.tar is computed with, so the file's bytes do not
    depend on the machine that wrote it; within 1e-6 of `GruStep` (float32, BLAS)."""

    def __init__(self, weights: dict) -> None:
        w = check_weights(weights)
        self.initial_state = w["layers/1/initial_hidden_state"]
        w64 = {k: v.astype(np.float64) for k, v in w.items()}
        # columns as contiguous rows: W·v = sum over j of W[:, j] * v[j], in order j = 0, 1, ...
        self._cols = {
            k: np.ascontiguousarray(w64[k].T)
            for k in ("layers/0/weights", "layers/1/weights_input", "layers/1/weights_hidden", "layers/2/weights")
        }
        self._b = {
            k: w64[k] for k in ("layers/0/biases", "layers/1/biases_input", "layers/1/biases_hidden", "layers/2/biases")
        }

    def _affine(self, weights: str, biases: str, v: np.ndarray) -> np.ndarray:
        acc = self._b[biases].copy()
        for col, vj in zip(self._cols[weights], v, strict=True):
            acc = acc + col * vj
        return acc

    def __call__(self, x: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x64 = np.asarray(x, np.float32).astype(np.float64)
        h64 = np.asarray(h, np.float32).astype(np.float64)
        y = np.maximum(self._affine("layers/0/weights", "layers/0/biases", x64), 0.0)
        gi = self._affine("layers/1/weights_input", "layers/1/biases_input", y)
        gh = self._affine("layers/1/weights_hidden", "layers/1/biases_hidden", h64)
        rz = 1.0 / (1.0 + _portable_exp(-np.clip(gi[: 2 * HIDDEN] + gh[: 2 * HIDDEN], -80.0, 80.0)))
        r, z = rz[:HIDDEN], rz[HIDDEN:]
        v = gi[2 * HIDDEN :] + r * gh[2 * HIDDEN :]
        t = _portable_exp(-2.0 * np.minimum(np.abs(v), 40.0))
        n = np.where(v < 0.0, -1.0, 1.0) * ((1.0 - t) / (1.0 + t))  # tanh
        new = n + z * (h64 - n)
        a = self._affine("layers/2/weights", "layers/2/biases", new)
        return a.astype(np.float32), new.astype(np.float32)


def gru_onnx(weights: dict):
    """The step as an ONNX model (opset 17): inputs obs (1, 22) and h_in (1, 16), outputs action
    (1, 4) and h_out (1, 16); Gemm, Relu, ONNX's GRU (linear_before_reset = 1, gates reordered from
    RLtools' r, z, n to ONNX's z, r, h), Gemm."""
    from onnx import TensorProto, helper, numpy_helper

    w = check_weights(weights)
    h3 = 3 * HIDDEN
    order = np.r_[HIDDEN : 2 * HIDDEN, 0:HIDDEN, 2 * HIDDEN : h3]  # z, r, n rows
    inits = {
        "w0": w["layers/0/weights"],
        "b0": w["layers/0/biases"],
        "W": w["layers/1/weights_input"][order][None],
        "R": w["layers/1/weights_hidden"][order][None],
        "B": np.concatenate([w["layers/1/biases_input"][order], w["layers/1/biases_hidden"][order]])[None],
        "w2": w["layers/2/weights"],
        "b2": w["layers/2/biases"],
        "seq_shape": np.array([1, 1, HIDDEN], np.int64),
        "row_shape": np.array([1, HIDDEN], np.int64),
    }
    nodes = [
        helper.make_node("Gemm", ["obs", "w0", "b0"], ["y0"], transB=1),
        helper.make_node("Relu", ["y0"], ["y1"]),
        helper.make_node("Reshape", ["y1", "seq_shape"], ["x_seq"]),
        helper.make_node("Reshape", ["h_in", "seq_shape"], ["h0"]),
        helper.make_node(
            "GRU", ["x_seq", "W", "R", "B", "", "h0"], ["", "h_last"], hidden_size=HIDDEN, linear_before_reset=1
        ),
        helper.make_node("Reshape", ["h_last", "row_shape"], ["h_out"]),
        helper.make_node("Gemm", ["h_out", "w2", "b2"], ["action"], transB=1),
    ]
    graph = helper.make_graph(
        nodes,
        "raptor_gru",
        [
            helper.make_tensor_value_info("obs", TensorProto.FLOAT, [1, OBS_DIM]),
            helper.make_tensor_value_info("h_in", TensorProto.FLOAT, [1, HIDDEN]),
        ],
        [
            helper.make_tensor_value_info("action", TensorProto.FLOAT, [1, ACTION_DIM]),
            helper.make_tensor_value_info("h_out", TensorProto.FLOAT, [1, HIDDEN]),
        ],
        [numpy_helper.from_array(np.ascontiguousarray(v), k) for k, v in inits.items()],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="quadpilot")
    model.ir_version = 8
    return model


class OnnxGruStep:
    """`GruStep` run by ONNX Runtime on `gru_onnx`'s graph (one session, single-threaded)."""

    def __init__(self, weights: dict) -> None:
        import onnxruntime as ort

        w = check_weights(weights)
        self.initial_state = w["layers/1/initial_hidden_state"]
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        self.session = ort.InferenceSession(gru_onnx(w).SerializeToString(), opts, providers=["CPUExecutionProvider"])

    def __call__(self, x: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a, h_out = self.session.run(None, {"obs": x.reshape(1, OBS_DIM), "h_in": h.reshape(1, HIDDEN)})
        return a[0], h_out[0]


MAX_EXAMPLE_STEPS = 100_000
"""Most example rows (steps × sequences) a checkpoint may carry (RAPTOR's: 1,000)."""


def _example_shape(shape: tuple, width: int) -> bool:
    return len(shape) == 3 and shape[2] == width and shape[0] * shape[1] <= MAX_EXAMPLE_STEPS


def weights_from_h5(path) -> tuple[dict, dict]:
    """(weights, example) from an RLtools HDF5 checkpoint of this shape: the dict above, and the
    example {"input": (T, B, 22), "output": (T, B, 4)} it carries (empty arrays if none).
    ModelContractError, one line, for a file that is not such a checkpoint. Every dataset's shape is
    checked before it is read, so a file cannot make this allocate more than the shapes above."""
    try:
        import h5py
    except ImportError:
        raise ModelContractError(f"{path}: reading an RLtools checkpoint needs h5py: pip install h5py") from None

    def read(node, name: str, shapes) -> np.ndarray:
        ds = node.get(name)
        if not isinstance(ds, h5py.Dataset):
            raise ModelContractError(f"{path}: no dataset {name!r}")
        if not shapes(ds.shape):
            raise ModelContractError(f"{path}: {name} has shape {ds.shape}, not what blob/policy.h's shape needs")
        return np.asarray(ds[()], np.float32)

    try:
        with h5py.File(path, "r") as f:
            layers = f["actor"]["layers"]
            for key, name in ACTIVATIONS.items():
                got = layers[key.split("/")[1]].attrs.get("activation_function")
                got = got.decode() if isinstance(got, bytes) else got
                if got != name:
                    raise ModelContractError(
                        f"{path}: actor/{key} has activation {quote(got)}; blob/policy.h's shape needs {name}"
                    )
            weights = {
                key: read(layers, key.split("/", 1)[1] + "/parameters", lambda s, w=shape: s in (w, (1, *w)))
                for key, shape in GRU_KEYS.items()
            }
            example = {"input": np.zeros((0, 1, OBS_DIM), np.float32)}
            example["output"] = np.zeros((0, 1, ACTION_DIM), np.float32)
            if "example" in f:
                for k, n in (("input", OBS_DIM), ("output", ACTION_DIM)):
                    example[k] = read(f["example"], k, lambda s, n=n: _example_shape(s, n))
    except ModelContractError:
        raise
    except (OSError, KeyError, TypeError, ValueError, AttributeError) as e:
        why = one_line(e, 120)
        raise ModelContractError(f"{path}: not an RLtools GRU checkpoint of blob/policy.h's shape ({why})") from None
    return check_weights(weights, str(path)), example


def sequences(step, xs: np.ndarray) -> np.ndarray:
    """Outputs (T, B, 4) of `step` on inputs (T, B, 22), each sequence started from the initial state
    (RLtools' `evaluate` on a batch); the one forward every replay of an example uses."""
    out = np.empty((xs.shape[0], xs.shape[1], ACTION_DIM), np.float32)
    for b in range(xs.shape[1]):
        h = step.initial_state.copy()
        for t in range(xs.shape[0]):
            out[t, b], h = step(np.ascontiguousarray(xs[t, b], np.float32), h)
    return out


def check_example(step, example: dict) -> float:
    """Mean absolute difference between the step's outputs and the example's, every sequence from
    the initial state (mc_raptor's test_policy: below 1e-5 or it refuses to fly); NaN if there is
    no example or the shapes do not fit."""
    xs, ys = example["input"], example["output"]
    if xs.ndim != 3 or xs.shape[:2] != ys.shape[:2] or xs.shape[2] != OBS_DIM or ys.shape[2] != ACTION_DIM:
        return math.nan
    if xs.shape[0] == 0:
        return math.nan
    return float(np.abs(sequences(step, xs).astype(np.float64) - ys).mean())
