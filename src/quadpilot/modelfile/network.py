"""The network of one exported file, read once from its checked metadata and initializers: what
every backend that computes the architecture itself builds from (the NumPy backend's `NumpyPolicy`,
and the C generator `ccode.generate` behind the c backend and `quad-export --format c`).

    model, info = model.read_model("policy.onnx")
    net = network_from_model(info, model.initializer_arrays(model, info.path))

`network_from_model` turns the architecture metadata (initializer names, activations, the action
map's numbers) into arrays and numbers, the float32 weights exactly as stored in the file, and checks
that their shapes chain from the observation to the four motor commands. ONNX Runtime runs the graph
itself; `graph.check_graph` has made sure that graph is this network.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .contract import NUM_MOTORS, ModelContractError, ModelInfo
from .model import ACTIVATIONS

FLT_MAX = float(np.finfo(np.float32).max)


@dataclass(frozen=True)
class Dense:
    weight: np.ndarray
    """(out, in) float32, as in the file (torch's nn.Linear layout)."""
    bias: np.ndarray
    """(out,) float32 (zeros where the exporter dropped an all-zero bias)."""
    activation: str | None
    """None, tanh, relu or elu; tanh on the last layer is the SAC head (see the module doc)."""


@dataclass(frozen=True)
class Network:
    """The network of one exported file, float32 weights exactly as stored in it."""

    obs_dim: int
    norm: tuple[np.ndarray, np.ndarray, float] | None
    """(mean (obs_dim,), inv_std (obs_dim,), clip) or None."""
    lstm: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None
    """(w_ih (4H, obs_dim), w_hh (4H, H), b_ih (4H,), b_hh (4H,)), gate order i, f, g, o; or None."""
    hidden: int
    layers: tuple[Dense, ...]
    u_hover: float
    action_clip: tuple[float, float]
    command_clip: tuple[float, float]

    @property
    def recurrent(self) -> bool:
        return self.lstm is not None

    @property
    def squashed(self) -> bool:
        """The action head ends in tanh (a SAC policy): the command map is the p/q form."""
        return self.layers[-1].activation == "tanh"

    def arrays(self) -> dict[str, np.ndarray]:
        """Every constant array, by the name the C source gives it."""
        out: dict[str, np.ndarray] = {}
        if self.norm is not None:
            out["qp_obs_mean"], out["qp_obs_inv_std"] = self.norm[0], self.norm[1]
        if self.lstm is not None:
            w_ih, w_hh, b_ih, b_hh = self.lstm
            out |= {"qp_lstm_w_ih": w_ih.T, "qp_lstm_w_hh": w_hh.T, "qp_lstm_b_ih": b_ih, "qp_lstm_b_hh": b_hh}
        for k, layer in enumerate(self.layers):
            out[f"qp_w{k}"], out[f"qp_b{k}"] = layer.weight.T, layer.bias
        return out


def network_from_model(info: ModelInfo, weights: dict[str, np.ndarray]) -> Network:
    """The network the architecture metadata describes, its shapes checked against each other.

    Raises ModelContractError naming what does not fit."""
    arch, path = info.architecture, info.path

    def w(name: str | None, shape: tuple[int, ...] | None = None) -> np.ndarray:
        if name is None and shape is not None:  # the exporter drops an all-zero bias
            return np.zeros(shape, np.float32)
        if name not in weights:
            raise ModelContractError(f"{path}: architecture names weight {name!r}, which the graph lacks")
        a = np.asarray(weights[name])
        if a.dtype != np.float32:
            raise ModelContractError(f"{path}: weight {name!r} is {a.dtype}, expected float32")
        if not np.all(np.isfinite(a)):
            raise ModelContractError(f"{path}: weight {name!r} holds non-finite values")
        return a

    try:
        norm = None
        if arch.get("normalize"):
            spec = arch["normalize"]
            mean, inv_std = w(spec["mean"]), w(spec["inv_std"])
            clip = float(spec["clip"])
            if mean.shape != (info.obs_dim,) or inv_std.shape != (info.obs_dim,) or not clip > 0:
                raise ModelContractError(
                    f"{path}: normalisation mean {mean.shape}, inv_std {inv_std.shape}, clip {clip}: "
                    f"expected ({info.obs_dim},), ({info.obs_dim},) and a clip > 0"
                )
            norm = (mean, inv_std, clip)
        d, lstm, hsz = info.obs_dim, None, 0
        if info.recurrent:
            spec, hsz = arch["lstm"], info.hidden
            w_ih, w_hh = w(spec["weight_ih"]), w(spec["weight_hh"])
            b_ih, b_hh = w(spec["bias_ih"], (4 * hsz,)), w(spec["bias_hh"], (4 * hsz,))
            if (
                w_ih.shape != (4 * hsz, d)
                or w_hh.shape != (4 * hsz, hsz)
                or b_ih.shape != (4 * hsz,)
                or b_hh.shape != (4 * hsz,)
            ):
                raise ModelContractError(
                    f"{path}: LSTM weights {w_ih.shape}, {w_hh.shape}, biases {b_ih.shape}, {b_hh.shape} "
                    f"do not fit hidden {hsz} and input {d}"
                )
            lstm, d = (w_ih, w_hh, b_ih, b_hh), hsz
        layers = []
        for k, layer in enumerate(arch["layers"]):
            wt = w(layer["weight"])
            b = w(layer["bias"], wt.shape[:1])
            act = layer.get("activation")
            if wt.ndim != 2 or wt.shape[1] != d or b.shape != (wt.shape[0],):
                raise ModelContractError(
                    f"{path}: layer {k} weights {wt.shape}/{b.shape} do not follow a {d}-wide input"
                )
            if act is not None and act not in ACTIVATIONS:
                raise ModelContractError(
                    f"{path}: activation {act!r} is not one the backends compute ({', '.join(ACTIVATIONS)})"
                )
            layers.append(Dense(wt, b, act))
            d = wt.shape[0]
        if not layers or d != NUM_MOTORS:
            raise ModelContractError(f"{path}: the last layer has {d} outputs, expected {NUM_MOTORS}")
        a_lo, a_hi = (float(v) for v in arch["action_clip"])
        c_lo, c_hi = (float(v) for v in arch["command_clip"])
        u_hover = float(arch["u_hover"])
    except (KeyError, TypeError, ValueError) as e:
        if isinstance(e, ModelContractError):
            raise
        raise ModelContractError(f"{path}: architecture metadata incomplete ({e!r})") from None
    numbers = [("u_hover", u_hover), ("action_clip", a_lo), ("action_clip", a_hi)]
    numbers += [("command_clip", c_lo), ("command_clip", c_hi)] + ([("normalize clip", norm[2])] if norm else [])
    for name, v in numbers:
        if not (math.isfinite(v) and abs(v) <= FLT_MAX):  # c_float writes every one of them as a float
            raise ModelContractError(f"{path}: architecture {name} is {v}, expected a finite float32 number")
    if layers[-1].activation == "tanh" and (a_lo, a_hi) != (-1.0, 1.0):
        raise ModelContractError(f"{path}: a tanh action head needs action_clip [-1, 1] (the graph has no clip)")
    return Network(info.obs_dim, norm, lstm, hsz, tuple(layers), u_hover, (a_lo, a_hi), (c_lo, c_hi))
