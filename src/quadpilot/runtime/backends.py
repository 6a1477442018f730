"""Interchangeable policy backends for one exported file, all batch-1 and torch-free.

    policy = load_policy("models/hover/policy.onnx", backend="numpy")   # or "onnxruntime", "c"
    policy.reset()                       # clears recurrent state (no-op for an MLP)
    motors = policy.act(obs)             # (obs_dim,) float32 → (4,) float32 in [0, 1]

`OnnxRuntimePolicy` runs the graph in an ONNX Runtime session created once, single-threaded, with
its inputs and outputs bound to preallocated buffers (I/O binding saves the per-call conversion
of `session.run`). The NumPy and C backends compute the network the file's architecture metadata
describes, read once from the file's initializers into a `modelfile.network.Network`:
`NumpyPolicy` computes it with NumPy; `cbackend.CPolicy` (backend "c") generates C from it
(`ccode.generate`, what `quad-export --format c` writes), compiles it once with the system C
compiler and calls it through ctypes. All three implement `policy.Policy`. None knows about
safety: wrap them in `safety.SafetyMonitor`.

Rules, so that the three backends fly one function or none flies:
- `load_policy` checks the file's contract first (`model.read_model`: every metadata value, and a
  graph that is exactly the declared architecture, so the graph ONNX Runtime runs is the network the
  NumPy and C backends compute from the same initializers).
- It then replays the golden vectors stored in the file through the chosen backend; a backend that
  does not reproduce them within `GOLDEN_TOLERANCE` is refused, and a NaN anywhere in the replay is a
  mismatch. With the onnxruntime backend the NumPy backend replays them too (about a millisecond),
  so a file cannot pass on the graph alone.
- Whatever ONNX Runtime raises while creating the session or running the golden vectors becomes a
  `ModelContractError`: a bad file never ends in a traceback.
- `Policy.act` takes only a real-number array of the policy's shape; anything else (strings,
  None, dicts, object or complex arrays, a wrong size) raises `ObservationShapeError`, one line
  (`policy.Policy`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np

from quadpilot.modelfile.contract import NUM_MOTORS, ModelContractError, ModelInfo
from quadpilot.modelfile.model import initializer_arrays, read_model
from quadpilot.modelfile.network import Network, network_from_model

from .cbackend import CPolicy
from .policy import ObservationShapeError as ObservationShapeError  # re-exported: callers catch it from here
from .policy import Policy

BACKENDS = ("onnxruntime", "numpy", "c")
GOLDEN_TOLERANCE = 1e-5
"""Max abs difference in motor command allowed on the golden vectors (the export parity bar)."""


class OnnxRuntimePolicy(Policy):
    backend = "onnxruntime"

    def __init__(self, info: ModelInfo, model_bytes: bytes) -> None:
        import onnxruntime as ort

        super().__init__(info)
        try:
            self._open(info, model_bytes, ort)
        except Exception as e:  # ORT raises its own exception types from C++ (Fail, InvalidGraph, ...)
            raise ModelContractError(f"{info.path}: ONNX Runtime cannot load the model ({_first_line(e)})") from None

    def _open(self, info: ModelInfo, model_bytes: bytes, ort) -> None:
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1  # batch-1 control: threads only add wake-up latency
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.log_severity_level = 3
        self.session = ort.InferenceSession(model_bytes, opts, providers=["CPUExecutionProvider"])
        h = max(info.hidden, 1)
        self._obs = np.zeros((1, self.obs_dim), np.float32)
        self._out = np.zeros((1, NUM_MOTORS), np.float32)
        self._binding = b = self.session.io_binding()
        b.bind_cpu_input("obs", self._obs)
        b.bind_output("action", "cpu", 0, np.float32, list(self._out.shape), self._out.ctypes.data)
        if info.recurrent:
            self._h, self._c = np.zeros((1, h), np.float32), np.zeros((1, h), np.float32)
            self._h_out, self._c_out = np.zeros_like(self._h), np.zeros_like(self._c)
            b.bind_cpu_input("h_in", self._h)
            b.bind_cpu_input("c_in", self._c)
            for name, buf in (("h_out", self._h_out), ("c_out", self._c_out)):
                b.bind_output(name, "cpu", 0, np.float32, list(buf.shape), buf.ctypes.data)
        self._run = self.session.run_with_iobinding

    def act_unchecked(self, x: np.ndarray) -> np.ndarray:
        self._obs[0] = x
        self._run(self._binding)
        if self.info.recurrent:
            self._h[...] = self._h_out
            self._c[...] = self._c_out
        return self._out[0].copy()

    def reset(self) -> None:
        if self.info.recurrent:
            self._h.fill(0.0)
            self._c.fill(0.0)


def _activation(name: str | None):
    """In-place activation on a float32 vector."""
    if name is None:
        return None
    if name == "tanh":
        return lambda v: np.tanh(v, out=v)
    if name == "relu":
        return lambda v: np.maximum(v, 0.0, out=v)
    if name == "elu":

        def elu(v):
            neg = np.expm1(np.minimum(v, 0.0))
            np.maximum(v, 0.0, out=v)
            v += neg

        return elu
    raise ModelContractError(f"activation {name!r} is not one the NumPy backend computes (tanh, relu, elu)")


class NumpyPolicy(Policy):
    """The network of the file computed with NumPy, batch-1, with preallocated buffers.

    The map from the action head's output a to the motor command, u_hover·√(1 + clip(a, −1, 1)),
    is folded into the head's weights and bias as √(clip(u²·(a + 1), 0, 2u²)): the same function,
    three vector operations instead of five (rounding differs by ~1e-7, checked by the golden
    vectors and the export parity test). When the last layer's activation is tanh (a SAC policy's
    action is tanh of its Gaussian mean z, train.sac) there is nothing to fold: u²·(1 + tanh z) is
    computed as 2u²·p/(p + q), p = e^(2·min(z, 0)), q = e^(−2·max(z, 0)), as the exported graph
    does (1 + tanh z cancels in float32 near a = −1, and the √ would magnify that), then clip and √.

    Each dense layer y = W·x + b is one `np.dot` with the bias folded in: the input vector
    carries a trailing 1 and the matrix is [Wᵀ; b]. The LSTM step (torch gate order i, f, g, o)
    is one `np.dot` of [x, h, 1] with [W_ihᵀ; W_hhᵀ; b_ih + b_hh], columns reordered to
    (i, f, o, g) so that one tanh serves all four gates: σ(z) = ½·tanh(z/2) + ½, with the halving
    folded into the i, f, o columns (a power of two, so exact)."""

    backend = "numpy"

    def __init__(self, info: ModelInfo, network: Network | Mapping[str, np.ndarray]) -> None:
        """`network`: the file's `Network`, or its initializers by name (read here with
        `network.network_from_model`). Raises ModelContractError for a network this backend does
        not compute."""
        super().__init__(info)
        net = network if isinstance(network, Network) else network_from_model(info, network)
        self.network = net
        self._norm = None
        if net.norm is not None:
            mean, inv_std, clip = net.norm
            self._norm = (np.array(mean, np.float32), np.array(inv_std, np.float32), float(clip))
        self._u_hover = net.u_hover
        self._a_lo, self._a_hi = net.action_clip
        self._c_lo, self._c_hi = net.command_clip
        d = self.obs_dim
        # the matrices are assembled in float64 from the file's float32 weights and rounded once
        if net.lstm is not None:
            hsz = net.hidden
            w_ih, w_hh, b_ih, b_hh = (np.asarray(a, np.float64) for a in net.lstm)
            a = np.vstack([w_ih.T, w_hh.T, (b_ih + b_hh)[None, :]])  # (d + H + 1, 4H), gates i, f, g, o
            i, f, g, o = (a[:, k * hsz : (k + 1) * hsz] for k in range(4))
            self._A_lstm = np.ascontiguousarray(np.hstack([0.5 * i, 0.5 * f, 0.5 * o, g]), np.float32)
            self._z = np.zeros(d + hsz + 1, np.float32)  # [x, h, 1]
            self._z[-1] = 1.0
            self._gates = np.zeros(4 * hsz, np.float32)
            self._c = np.zeros(hsz, np.float32)
            self._tmp = np.zeros(hsz, np.float32)
            self._x = self._z[:d]
            self._h_view = self._z[d : d + hsz]
            self._hidden = hsz
            prev = np.zeros(hsz + 1, np.float32)  # [h, 1] feeds the head
            prev[-1] = 1.0
            self._h_aug = prev
        else:
            prev = np.zeros(d + 1, np.float32)
            prev[-1] = 1.0
            self._x = prev[:d]
        self._dense = []
        head = net.layers[-1].activation
        if head not in (None, "tanh"):
            raise ModelContractError(
                f"{info.path}: the action head's activation {head!r} is not one the NumPy "
                "backend maps to motor commands (none, or tanh)"
            )
        squashed = net.squashed
        for k, layer in enumerate(net.layers):
            wt, b = np.asarray(layer.weight, np.float64), np.asarray(layer.bias, np.float64)
            last = k == len(net.layers) - 1
            out = np.zeros(wt.shape[0] + (0 if last else 1), np.float32)
            if not last:
                out[-1] = 1.0
            view = out if last else out[:-1]
            mat = np.vstack([wt.T, b[None, :]])
            if last and not squashed:
                # the command map folded into the action head (float64, then rounded once):
                # u·√(1 + clip(a, lo, hi)) = √(clip(u²·(a + 1), u²·(lo + 1), u²·(hi + 1)))
                mat[-1] += 1.0
                mat *= self._u_hover**2
            mat = np.ascontiguousarray(mat, np.float32)
            act = None if last and squashed else _activation(layer.activation)
            self._dense.append((prev, mat, view, act))
            prev = out
        self._y = prev
        # constants as float32 arrays: a ufunc converts a Python scalar on every call (~0.2 µs)
        full = lambda v, n=NUM_MOTORS: np.full(n, v, np.float32)  # noqa: E731
        u2 = self._u_hover**2
        # a tanh head (SAC) comes before the command map, so it is not folded (see the docstring)
        scratch = np.zeros(NUM_MOTORS, np.float32)
        self._post = (full(0.0), full(2.0), full(-2.0), full(2.0 * u2), scratch) if squashed else None
        self._k = (full(u2 * (self._a_lo + 1.0)), full(u2 * (self._a_hi + 1.0)), full(self._c_lo), full(self._c_hi))
        if net.lstm is not None:
            self._half = full(0.5, 3 * self._hidden)
        # with a in [−1, 1], u_hover·√(1 + a) lies in [0, u_hover·√2]: the command clip can only act
        # when u_hover·√2 may exceed its upper bound (the graph keeps it; here it costs 0.5 µs)
        self._final_clip = not (self._c_lo <= 0.0 and float(np.float32(self._u_hover)) * 1.41421357 < self._c_hi - 1e-6)

    def act_unchecked(self, x: np.ndarray) -> np.ndarray:
        if self._norm is None:
            self._x[...] = x
        else:
            mean, inv_std, clip = self._norm
            t = self._x
            np.subtract(x, mean, out=t)
            t *= inv_std
            np.clip(t, -clip, clip, out=t)
        if self.info.recurrent:
            self._lstm_step()
        for inp, mat, out, act in self._dense:
            np.dot(inp, mat, out=out)
            if act is not None:
                act(out)
        y = self._y
        if self._post is not None:  # y = z, the head's output: u²·(1 + tanh z) = 2u²·p/(p + q)
            zero, two, minus_two, two_u2, p = self._post
            np.minimum(y, zero, out=p)
            p *= two
            np.exp(p, out=p)  # p = e^(2·min(z, 0)) ≤ 1
            np.maximum(y, zero, out=y)
            y *= minus_two
            np.exp(y, out=y)  # q = e^(−2·max(z, 0)) ≤ 1
            y += p
            np.divide(p, y, out=y)
            y *= two_u2
        lo, hi, c_lo, c_hi = self._k
        np.maximum(y, lo, out=y)  # np.clip costs 4× two ufuncs at this size
        np.minimum(y, hi, out=y)  # u²·(1 + a), a the clipped mean action
        np.sqrt(y, out=y)  # u·√(1 + a): core.dynamics.action_to_command
        if self._final_clip:
            np.maximum(y, c_lo, out=y)
            np.minimum(y, c_hi, out=y)
        return y.copy()

    def _lstm_step(self) -> None:
        hsz = self._hidden
        g = self._gates
        np.dot(self._z, self._A_lstm, out=g)
        np.tanh(g, out=g)
        s = g[: 3 * hsz]
        np.multiply(s, self._half, out=s)
        np.add(s, self._half, out=s)  # σ of the halved i, f, o pre-activations
        i, f, o, cand = g[:hsz], g[hsz : 2 * hsz], g[2 * hsz : 3 * hsz], g[3 * hsz :]
        c, t = self._c, self._tmp
        c *= f
        np.multiply(i, cand, out=t)
        c += t  # c' = f·c + i·g
        np.tanh(c, out=t)
        h = self._h_aug[:hsz]
        np.multiply(o, t, out=h)  # h' = o·tanh(c')
        self._h_view[...] = h

    def reset(self) -> None:
        if self.info.recurrent:
            self._c.fill(0.0)
            self._h_view.fill(0.0)
            self._h_aug[: self._hidden] = 0.0

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(h, c) copies for a recurrent policy, else None."""
        if not self.info.recurrent:
            return None
        return self._h_view.copy(), self._c.copy()


def _first_line(e: BaseException, limit: int = 300) -> str:
    text = str(e).strip()
    line = text.splitlines()[0] if text else type(e).__name__
    return line if len(line) <= limit else line[:limit] + "..."


def _replay_golden(policy: Policy) -> float:
    """`policy.verify_golden()`, with whatever ONNX Runtime raises on the way (a graph it can load
    but not run) turned into a ModelContractError: at load, a file's failure is the file's."""
    if not isinstance(policy, OnnxRuntimePolicy):
        return policy.verify_golden()
    try:
        return policy.verify_golden()
    except Exception as e:
        raise ModelContractError(
            f"{policy.info.path}: ONNX Runtime fails on the file's golden vectors ({_first_line(e)})"
        ) from None


def _refuse_golden(info: ModelInfo, backend: str, worst: float, why: str = "") -> ModelContractError:
    return ModelContractError(
        f"{info.path}: the {backend} backend{f' ({why})' if why else ''} does not reproduce the file's golden vectors "
        f"(max abs difference {worst:.3g}, allowed {GOLDEN_TOLERANCE:g}); the weights or the graph were altered"
    )


def load_policy(path: str | os.PathLike, backend: str = "onnxruntime") -> Policy:
    """Check the file's contract, build the backend, and replay the golden vectors.

    Raises ModelContractError (a ValueError) naming what is wrong; never returns a policy that
    failed a check. The "c" backend also raises `cbackend.CCompilerError` (a RuntimeError and a
    ValueError) when there is no working C compiler."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; expected one of {', '.join(BACKENDS)}")
    if str(path).startswith("raptor:") or str(path).lower().endswith((".h5", ".tar")):  # PX4 mc_raptor's policy
        from .raptor import load_raptor

        return load_raptor(path, backend)
    model, info = read_model(path)
    weights = initializer_arrays(model, info.path)
    if backend == "onnxruntime":
        policy: Policy = OnnxRuntimePolicy(info, model.SerializeToString())
    else:
        net = network_from_model(info, weights)
        policy = CPolicy.from_network(info, net) if backend == "c" else NumpyPolicy(info, net)
    worst = _replay_golden(policy)
    if not worst <= GOLDEN_TOLERANCE:
        raise _refuse_golden(info, backend, worst)
    if backend == "onnxruntime":
        # the graph passed the structural check; the network the NumPy and C backends compute from
        # the same initializers must reproduce the same vectors, so that no file passes on its graph alone
        worst = NumpyPolicy(info, network_from_model(info, weights)).verify_golden()
        if not worst <= GOLDEN_TOLERANCE:
            raise _refuse_golden(info, "numpy", worst, "cross-checking the onnxruntime backend")
    return policy
