"""C99 source for an exported policy: the one generator behind `quad-export --format c` and the
runtime's `c` backend.

    from quadpilot.runtime.cgen import generate, initializers
    model, info = read_model("policy.onnx")
    code = generate(info, initializers(model))   # code.header (policy.h), code.source (policy.c)

The input is what the NumPy backend reads: the file's checked metadata (`ModelInfo`) and its
initializers, named by the architecture metadata. So the C, the NumPy backend and ONNX Runtime all
compute from the same float32 weights of the same file, and `quad-export --format c` feeds this
generator the ONNX file it has just exported: there is no second path from a checkpoint to C.

What the C computes is what the graph computes (`export.onnx_export.DeployablePolicy` /
`DeployableRecurrentPolicy`): optional observation normalisation clip((obs − mean)·inv_std, ±clip),
the dense layers (or the LSTM cell, torch gate order i, f, g, o, then the dense head), the mean
action clipped to the action range, and the motor command u_hover·√(1 + a) clipped to [0, 1]. For
a tanh action head (SAC) the command is computed as the graph does, u_hover·√(2p/(p + q)) with
p = e^(2·min(z, 0)), q = e^(−2·max(z, 0)): the same function as u_hover·√(1 + tanh z) without the
cancellation of 1 + tanh z near a = −1, which the √ would magnify to ~1e-4.

The file is untrusted (DESIGN.md, "Trust boundaries"), and generated code is compiled and loaded,
so nothing from the file reaches the text except numbers this module formats itself (`c_float`,
and integers it computed): no metadata string and no initializer name. The text in the header and
the comments comes from this runtime's own tables (the observation layout of `core.observation`
found by name, `model.ACTION_MEANING`, the generator's fixed text), and the few strings the header
repeats from the metadata are checked again here, as `model.read_model` checks them: the task is
one of `core.mission.TASKS`, the source SHA-256 is 64 lowercase hex digits, the vehicle name a
plain identifier (`model.VEHICLE_NAME_PATTERN`). A ModelInfo that fails any of these (one not made
by `read_model`) is refused with a ModelContractError.

How it is written, and why:
- Weights are `static const float` arrays holding the file's float32 values exactly: each printed
  as the shortest decimal that reads back to the same binary32 value (numpy's "unique" formatting;
  never more than FLT_DECIMAL_DIG = 9 significant digits, C11 §5.2.4.2.2). On a microcontroller
  they land in flash (.rodata); the code keeps no static state and allocates nothing (scratch on
  the stack), so it is reentrant.
- Each dense matrix is stored transposed, [in][out], and y = b + Σᵢ xᵢ·W[i][:] is computed as
  loops `y[j] = y[j] + v0*w[i][j] + … + v3*w[i+3][j]` over contiguous memory (`_matvec`): every
  output keeps its own accumulator, so a compiler vectorises the loop over j without reassociating
  a sum (a dot-product loop would need -ffast-math for that), and the loop bounds are constants.
- Only libm: `expf` (tanh as 1 − 2/(e^2x + 1), `TANH_C`, or libm's `tanhf` with -DQP_USE_TANHF;
  the LSTM's σ(z) = 1/(1 + e^−z)), `sqrtf`, and `expm1f` for an ELU network; `float` throughout
  with `f`-suffixed constants, so no double arithmetic (which a single-precision FPU such as the
  Cortex-M4F's would emulate in software).
- NaN in gives NaN out (the clamps are comparisons that a NaN fails). The kernel checks nothing:
  the runtime's `SafetyMonitor` validates observations and commands around it, and firmware must do
  the same (the header says so).
- The text is ASCII only (the layout's units and meanings are transliterated), for any toolchain.
"""

from __future__ import annotations

import math
import textwrap
import unicodedata
from dataclasses import dataclass, fields

import numpy as np

from quadpilot.core.mission import TASKS
from quadpilot.core.observation import ObsLayout, get_layout

from .model import (
    ACTION_MEANING,
    NUM_MOTORS,
    SHA256_PATTERN,
    VEHICLE_NAME_PATTERN,
    ModelContractError,
    ModelInfo,
    initializer_arrays,
)

GENERATOR = "quadpilot.runtime.cgen/1"
"""Identifies the generated code's conventions; part of the runtime's compile-cache key."""
HEADER_NAME, SOURCE_NAME = "policy.h", "policy.c"
ENTRY, STEP, RESET = "quadpilot_policy", "quadpilot_policy_step", "quadpilot_policy_reset"
ACTIVATIONS = ("tanh", "relu", "elu")
VALUES_PER_LINE = 6
FLT_MAX = float(np.finfo(np.float32).max)
UNROLL = 4
"""Inputs per pass over the accumulators in the matrix-vector loops (see `_matvec`)."""
TANH_C = """\
/* tanh(x) = 1 - 2/(e^(2x) + 1): libm's expf and one division. Absolute error <= 2e-7 (measured
 * over [-10, 10] against double tanh; the command parity bar is 1e-5), and about 3x faster than
 * glibc 2.36's tanhf, which would take most of the time of an MLP step. Saturates to +/-1 (e^(2x)
 * overflows to +Inf or underflows to 0); NaN stays NaN. -DQP_USE_TANHF calls libm's tanhf. */
static float qp_tanh(float x)
{
#ifdef QP_USE_TANHF
    return tanhf(x);
#else
    return 1.0f - 2.0f / (expf(2.0f * x) + 1.0f);
#endif
}"""
SIGMOID_C = """\
/* logistic sigmoid: sigma(z) = 1 / (1 + e^-z) */
static float qp_sigmoid(float z)
{
    return 1.0f / (1.0f + expf(-z));
}"""


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


def initializers(model) -> dict[str, np.ndarray]:
    """The initializers of an `onnx.ModelProto` by name (what the architecture metadata names), as
    checked float32 arrays (`model.initializer_arrays`; ModelContractError for a bad one)."""
    return initializer_arrays(model)


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
                    f"{path}: activation {act!r} is not one the C generator writes ({', '.join(ACTIVATIONS)})"
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


# --- text helpers ------------------------------------------------------------------------------

_ASCII = {
    "ᵀ": "^T",
    "·": "*",
    "−": "-",
    "→": "->",
    "←": "<-",
    "≤": "<=",
    "≥": ">=",
    "±": "+/-",
    "×": "x",
    "…": "...",
    "°": " deg",
    "²": "^2",
    "³": "^3",
    "√": "sqrt",
    "ω": "omega",
    "π": "pi",
    "σ": "sigma",
    "–": "-",
    "—": "-",
    "’": "'",
}


def ascii_text(text: str) -> str:
    """`text` in ASCII for a C comment: known symbols spelled out, accents dropped, `*/` broken."""
    out = []
    for ch in text:
        if ord(ch) < 128:
            out.append(ch)
        elif ch in _ASCII:
            out.append(_ASCII[ch])
        else:
            plain = unicodedata.normalize("NFKD", ch).encode("ascii", "ignore").decode()
            out.append(plain or "?")
    return "".join(out).replace("*/", "* /").replace("/*", "/ *")


def c_float(value) -> str:
    """A float32 value as a C float constant that reads back to the same bits."""
    v = np.float32(value)
    if not math.isfinite(v):
        raise ValueError(f"{v} has no C float constant")
    s = np.format_float_scientific(v, unique=True, trim="-") if v and not 1e-4 <= abs(v) < 1e7 else str(v)
    if not any(c in s for c in ".e"):
        s += ".0"
    return s + "f"


def _c_array(name: str, a: np.ndarray, comment: str) -> str:
    a = np.asarray(a, np.float32)
    dims = "".join(f"[{n}]" for n in a.shape)
    lines = [f"/* {ascii_text(comment)} */", f"static const float {name}{dims} = {{"]
    rows = a.reshape(-1, a.shape[-1]) if a.ndim == 2 else a.reshape(1, -1)
    for r, row in enumerate(rows):
        values = [c_float(v) for v in row]
        chunks = [", ".join(values[k : k + VALUES_PER_LINE]) for k in range(0, len(values), VALUES_PER_LINE)]
        if a.ndim == 2:
            body = ",\n      ".join(chunks)
            lines.append(f"    {{ {body} }}{',' if r < len(rows) - 1 else ''}")
        else:
            lines.extend(f"    {c}{',' if k < len(chunks) - 1 else ''}" for k, c in enumerate(chunks))
    lines.append("};")
    return "\n".join(lines)


def _wrap(text: str, width: int = 100) -> str:
    """A paragraph for a ` * ` comment block (the first line's ` * ` is the caller's)."""
    return "\n * ".join(textwrap.wrap(text, width - 3, break_on_hyphens=False, break_long_words=False))


def _clamp(var: str, lo: str, hi: str) -> str:
    """`var` clamped to [lo, hi] as comparisons, so that a NaN passes through (as in the graph)."""
    return f"{var} < {lo} ? {lo} : ({var} > {hi} ? {hi} : {var})"


# --- the generator ----------------------------------------------------------------------------


@dataclass(frozen=True)
class CCode:
    header: str
    """policy.h"""
    source: str
    """policy.c (includes "policy.h")"""
    network: Network

    def write(self, directory) -> tuple:
        """Write policy.h and policy.c into `directory` (created), atomically; returns both paths."""
        import os
        import tempfile
        from pathlib import Path

        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        paths = []
        for name, text in ((HEADER_NAME, self.header), (SOURCE_NAME, self.source)):
            fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=directory)
            try:
                with os.fdopen(fd, "w", encoding="ascii", newline="\n") as f:
                    f.write(text)
                    f.flush()
                    os.fsync(f.fileno())
                os.chmod(tmp, 0o644)
                os.replace(tmp, directory / name)
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
            paths.append(directory / name)
        return tuple(paths)


def generate(info: ModelInfo, weights: dict[str, np.ndarray]) -> CCode:
    """policy.h and policy.c for the file `info` and `weights` come from (see the module doc).

    Raises ModelContractError if the architecture metadata and the weights do not fit."""
    net = network_from_model(info, weights)
    return CCode(_header(info, net), _source(info, net), net)


@dataclass(frozen=True)
class _Facts:
    """What the header repeats from the metadata, as text this module vouches for (module doc)."""

    layout: ObsLayout
    """This runtime's ObsLayout of that name (core.observation), not the file's description."""
    task: str
    source_sha256: str
    training_steps: int
    vehicle: str
    control_period_s: float
    max_distance_m: float
    max_tilt_deg: float


def _facts(info: ModelInfo) -> _Facts:
    """The metadata facts the header states, each checked again (module doc): numbers finite, the
    layout ours, the strings from a fixed set or matching a strict pattern. Raises ModelContractError."""

    def refuse(what: str) -> ModelContractError:
        return ModelContractError(f"{info.path}: {what}; generated C takes no text from a file")

    try:
        layout = get_layout(info.layout.name)
    except (ValueError, AttributeError, TypeError):
        raise refuse("the observation layout is not one this runtime knows") from None
    if layout != info.layout:
        raise refuse(f"the observation layout differs from this runtime's {layout.name}")
    if info.task not in TASKS:
        raise refuse(f"the task is not one of {', '.join(TASKS)}")
    sha = info.source_sha256
    if not (isinstance(sha, str) and SHA256_PATTERN.fullmatch(sha)):
        raise refuse("the source SHA-256 is not 64 lowercase hex digits")
    if info.action_meaning != ACTION_MEANING:
        raise refuse("the action meaning is not the schema's")
    steps = info.training_steps
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        raise refuse("the training step count is not a count")
    vehicle = info.vehicle
    if not (isinstance(vehicle.name, str) and VEHICLE_NAME_PATTERN.fullmatch(vehicle.name)):
        raise refuse("the vehicle name is not a plain identifier")
    values = {f.name: float(getattr(vehicle, f.name)) for f in fields(vehicle) if f.name != "name"}
    numbers = [*values.values(), float(info.control_period_s)]
    numbers += [float(info.envelope["max_distance_m"]), float(info.envelope["max_tilt_deg"])]
    if not all(math.isfinite(v) and abs(v) <= FLT_MAX for v in numbers) or not numbers[-3] > 0:
        raise refuse("a vehicle, control period or envelope number is not finite")
    # the field names are VehicleParams' own; a float's repr is digits, '.', 'e', '+' and '-'
    text = ", ".join([f'"name": "{vehicle.name}"', *(f'"{k}": {v!r}' for k, v in values.items())])
    return _Facts(
        layout=layout,
        task=TASKS[TASKS.index(info.task)],
        source_sha256=sha,
        training_steps=int(steps),
        vehicle="{" + text + "}",
        control_period_s=numbers[-3],
        max_distance_m=numbers[-2],
        max_tilt_deg=numbers[-1],
    )


def _network_summary(net: Network) -> str:
    parts = ["obs"]
    if net.norm is not None:
        parts.append(f"normalise (clip +/-{net.norm[2]:g})")
    if net.lstm is not None:
        parts.append(f"LSTM {net.hidden} (state h, c)")
    for layer in net.layers:
        parts.append(f"{layer.weight.shape[0]}{' ' + layer.activation if layer.activation else ''}")
    lo, hi = net.action_clip
    if net.squashed:
        parts.append(f"u_hover*sqrt(1 + a) as u_hover*sqrt(2p/(p + q)), u_hover = {net.u_hover:.6g}")
    else:
        parts.append(f"clip [{lo:g}, {hi:g}]")
        parts.append(f"u_hover*sqrt(1 + a), u_hover = {net.u_hover:.6g}")
    parts.append(f"clip [{net.command_clip[0]:g}, {net.command_clip[1]:g}]")
    return " -> ".join(parts)


def _header(info: ModelInfo, net: Network) -> str:
    facts = _facts(info)
    layout = facts.layout
    stack = _stack_bytes(net)
    rows = []
    for f, sl in zip(layout.fields, layout.slices().values(), strict=True):
        idx = f"[{sl.start}..{sl.stop - 1}]" if f.size > 1 else f"[{sl.start}]"
        rows.append(f" *   {idx:9s} {f.name:11s} {ascii_text(f.unit):6s} {ascii_text(f.meaning)}")
    libm = _libm(net)
    output = (
        f"Output: float motors[QP_NUM_MOTORS], {ascii_text(ACTION_MEANING)}: the values PX4's "
        "HIL_ACTUATOR_CONTROLS carries in controls[0..3]."
    )
    if net.recurrent:
        api = f"""\
/* One control step. Reads obs, updates the recurrent state h and c in place, writes the motor
 * commands. obs, h, c and motors must not overlap. Zero h and c at the start of every episode
 * ({RESET}), as training, the ONNX file and the runtime do. */
void {STEP}(const float obs[QP_OBS_DIM], float h[QP_HIDDEN], float c[QP_HIDDEN],
    float motors[QP_NUM_MOTORS]);

/* The state at the start of an episode: h = c = 0. */
void {RESET}(float h[QP_HIDDEN], float c[QP_HIDDEN]);"""
        usage = f""" *     float h[QP_HIDDEN], c[QP_HIDDEN];         kept between calls
 *     {RESET}(h, c);             at the start of every episode (arming)
 *     {STEP}(obs, h, c, motors); every control period"""
        state_macro = f"#define QP_HIDDEN {net.hidden}\n"
    else:
        api = f"""\
/* One control step: motor commands for one observation. obs and motors must not overlap. */
void {ENTRY}(const float obs[QP_OBS_DIM], float motors[QP_NUM_MOTORS]);"""
        usage = f" *     {ENTRY}(obs, motors);   every control period"
        state_macro = ""
    offsets = "\n".join(
        f"#define QP_OBS_{f.name.upper()} {sl.start} /* {f.size} value{'s' if f.size > 1 else ''}, "
        f"{ascii_text(f.unit)} */"
        for f, sl in zip(layout.fields, layout.slices().values(), strict=True)
    )
    text = f"""\
/* {HEADER_NAME}: a quadpilot policy as dependency-free C99 (libm only), generated by {GENERATOR}
 * (quad-export --format c, or the runtime's c backend). Do not edit; regenerate from the checkpoint.
 *
 * Source checkpoint SHA-256: {facts.source_sha256}
 * Task: {facts.task}; training steps: {facts.training_steps:d}
 * {_wrap("Vehicle: " + facts.vehicle)}
 * Control period: {facts.control_period_s:g} s ({1.0 / facts.control_period_s:g} Hz): one call per control step.
 * Network: {_network_summary(net)}
 *
 * Usage:
{usage}
 *
 * Observation: float obs[QP_OBS_DIM], layout {layout.name}; SI units, world frame ENU (z up),
 * body frame FLU; R rotates body FLU into world ENU. Build it as quadpilot.core.observation does.
 *   index     field       unit   meaning
{chr(10).join(rows)}
 *
 * {_wrap(output)}
 *
 * Safety: this code checks nothing. NaN in gives NaN out, and +Inf saturates to full thrust
 * without any error. Before calling it, check every observation is finite and physically
 * possible; fly it only inside the envelope it was trained in (distance to the target
 * <= QP_MAX_DISTANCE_M, roll and pitch <= QP_MAX_TILT_DEG), and check the commands are
 * finite before sending them (to PX4, NaN means stop the motors). quadpilot.runtime's
 * SafetyMonitor does this around the same kernel.
 *
 * Memory: weights are static const (flash on a microcontroller); no static or global state, no
 * heap; about {stack} bytes of scratch on the stack. Reentrant. Needs libm ({", ".join(libm)};
 * tanhf too if built with -DQP_USE_TANHF). Build with C99 or later, e.g.
 *     cc -std=c99 -O2 -c {SOURCE_NAME}                                   (link with -lm)
 *     arm-none-eabi-gcc -std=c99 -O2 -mcpu=cortex-m4 -mfpu=fpv4-sp-d16 -mfloat-abi=hard -mthumb -c {SOURCE_NAME}
 * and without -ffast-math (it may reorder the sums and break the parity with the ONNX file).
 */
#ifndef QUADPILOT_POLICY_H
#define QUADPILOT_POLICY_H

#define QP_OBS_DIM {layout.dim}
#define QP_NUM_MOTORS {NUM_MOTORS}
#define QP_RECURRENT {int(net.recurrent)}
{state_macro}#define QP_CONTROL_PERIOD_S {c_float(facts.control_period_s)}
#define QP_MAX_DISTANCE_M {c_float(facts.max_distance_m)}
#define QP_MAX_TILT_DEG {c_float(facts.max_tilt_deg)}
#define QP_OBS_LAYOUT "{layout.name}"
#define QP_TASK "{facts.task}"
#define QP_SOURCE_SHA256 "{facts.source_sha256}"

/* First index of each observation field (see the table above). */
{offsets}

#ifdef __cplusplus
extern "C" {{
#endif

{api}

#ifdef __cplusplus
}}
#endif

#endif /* QUADPILOT_POLICY_H */
"""
    return text


def _uses_tanh(net: Network) -> bool:
    """Whether the code calls qp_tanh (a tanh head is computed with expf, see the module doc)."""
    return net.recurrent or any(layer.activation == "tanh" for layer in net.layers[:-1])


def _libm(net: Network) -> list[str]:
    """The libm functions the generated code calls (with the default, expf-based tanh)."""
    names = {"sqrtf"}
    if _uses_tanh(net) or net.squashed:
        names.add("expf")
    if any(layer.activation == "elu" for layer in net.layers):
        names.add("expm1f")
    return sorted(names)


def _stack_bytes(net: Network) -> int:
    """Scratch floats the generated function keeps on the stack, in bytes (the compiler adds a little)."""
    floats = net.obs_dim if net.norm is not None else 0
    if net.recurrent:
        floats += 4 * net.hidden
    floats += sum(layer.weight.shape[0] for layer in net.layers)
    return 4 * floats


def _matvec(out: str, n_out: int, bias: list[str], rows: list[tuple[str, str, int]], unroll: int) -> list[str]:
    """out[j] = bias + Σ inp[i]·w[i][j] over every (inp, w, n_in) of `rows`, added in order.

    Written as `out[j] = out[j] + v0*w[i][j] + v1*w[i+1][j] + …` over `unroll` inputs at a time:
    C's left-to-right + keeps the exact order of the one-at-a-time sum (the same rounding), while
    each pass over out[] loads and stores it once per `unroll` products instead of once per product.
    The first pass starts from the bias, so there is no separate bias loop (which a compiler may
    turn into a memcpy call)."""
    lines: list[str] = []

    def block(inp: str, w: str, start: int, count: int, head: str) -> None:
        loads = ", ".join(f"v{u} = {inp}[{start + u}]" for u in range(count))
        terms = " + ".join(f"v{u} * {w}[{start + u}][j]" for u in range(count))
        lines.extend(
            [
                "    {",
                f"        const float {loads};",
                f"        for (j = 0; j < {n_out}; ++j) {out}[j] = {head} + {terms};",
                "    }",
            ]
        )

    first = True
    for inp, w, n_in in rows:
        start = 0
        if first:
            count = min(unroll, n_in)
            block(inp, w, 0, count, " + ".join(bias))
            start, first = count, False
        full = (n_in - start) // unroll
        if full >= 2:
            stop = start + full * unroll
            loads = ", ".join(f"v{u} = {inp}[i + {u}]" if u else f"v0 = {inp}[i]" for u in range(unroll))
            terms = " + ".join(f"v{u} * {w}[i + {u}][j]" if u else f"v0 * {w}[i][j]" for u in range(unroll))
            lines += [
                f"    for (i = {start}; i < {stop}; i += {unroll}) {{",
                f"        const float {loads};",
                f"        for (j = 0; j < {n_out}; ++j) {out}[j] = {out}[j] + {terms};",
                "    }",
            ]
            start = stop
        while start < n_in:
            count = min(unroll, n_in - start)
            block(inp, w, start, count, f"{out}[j]")
            start += count
    return lines


def _dense(k: int, layer: Dense, inp: str, out: str, head: bool = False) -> list[str]:
    """One dense layer; `head`: a tanh action head, whose tanh the command map computes (module doc)."""
    n_out, n_in = layer.weight.shape
    act = None if head else layer.activation
    note = ", tanh in the command map below" if head else (", " + act if act else "")
    lines = [f"    /* layer {k}: {n_in} -> {n_out}{note} */"]
    lines += _matvec(out, n_out, [f"qp_b{k}[j]"], [(inp, f"qp_w{k}", n_in)], UNROLL)
    if act == "tanh":
        lines.append(f"    for (j = 0; j < {n_out}; ++j) {out}[j] = qp_tanh({out}[j]);")
    elif act == "relu":
        lines.append(f"    for (j = 0; j < {n_out}; ++j) {out}[j] = {out}[j] < 0.0f ? 0.0f : {out}[j];")
    elif act == "elu":  # torch's ELU, alpha 1: x if x > 0 else e^x - 1
        lines.append(f"    for (j = 0; j < {n_out}; ++j) {out}[j] = {out}[j] > 0.0f ? {out}[j] : expm1f({out}[j]);")
    return lines


def _source(info: ModelInfo, net: Network) -> str:
    d = net.obs_dim
    arrays = []
    facts = _facts(info)
    # comments name the arrays by their role and this code's own names, never by the file's
    # initializer names (text from the file; see the module doc)
    if net.norm is not None:
        arrays.append(_c_array("qp_obs_mean", net.norm[0], "observation mean"))
        arrays.append(_c_array("qp_obs_inv_std", net.norm[1], "1/std of the observation"))
    if net.lstm is not None:
        w_ih, w_hh, b_ih, b_hh = net.lstm
        arrays += [
            _c_array("qp_lstm_w_ih", w_ih.T, "LSTM input weights transposed: [input][gate], gates i, f, g, o"),
            _c_array("qp_lstm_w_hh", w_hh.T, "LSTM recurrent weights transposed: [h][gate], gates i, f, g, o"),
            _c_array("qp_lstm_b_ih", b_ih, "LSTM input bias (zeros where the exporter dropped an all-zero one)"),
            _c_array("qp_lstm_b_hh", b_hh, "LSTM recurrent bias (zeros where the exporter dropped an all-zero one)"),
        ]
    for k, layer in enumerate(net.layers):
        arrays.append(_c_array(f"qp_w{k}", layer.weight.T, f"layer {k}: weight transposed, [in][out]"))
        arrays.append(_c_array(f"qp_b{k}", layer.bias, f"layer {k}: bias (zeros where the exporter dropped it)"))
    lo, hi = net.action_clip
    c_lo, c_hi = net.command_clip
    consts = [
        f"static const float qp_u_hover = {c_float(net.u_hover)}; /* hover command: omega_hover/omega_max */",
        f"static const float qp_action_lo = {c_float(lo)}, qp_action_hi = {c_float(hi)};",
        f"static const float qp_command_lo = {c_float(c_lo)}, qp_command_hi = {c_float(c_hi)};",
    ]
    if net.squashed:  # tanh never leaves [-1, 1], the only action clip a tanh head may declare
        del consts[1]
    if net.norm is not None:
        consts.append(f"static const float qp_obs_clip = {c_float(net.norm[2])};")

    body: list[str] = []
    if net.norm is not None:
        body += [
            f"    float x[{d}];",
        ]
    widths = [layer.weight.shape[0] for layer in net.layers]
    names = [f"y{k}" for k in range(len(net.layers))]
    if net.recurrent:
        body.append(f"    float g[{4 * net.hidden}];")
    body += [f"    float {n}[{w}];" for n, w in zip(names, widths, strict=True)]
    body.append("    int i, j;")
    x = "obs"
    if net.norm is not None:
        body += [
            "    /* observation normalisation */",
            f"    for (i = 0; i < {d}; ++i) {{",
            "        const float v = (obs[i] - qp_obs_mean[i]) * qp_obs_inv_std[i];",
            f"        x[i] = {_clamp('v', '-qp_obs_clip', 'qp_obs_clip')};",
            "    }",
        ]
        x = "x"
    if net.recurrent:
        hs, g4 = net.hidden, 4 * net.hidden
        body += [
            "    /* LSTM cell: gates = b_ih + b_hh + W_ih*x + W_hh*h, gate order i, f, g, o (torch nn.LSTM) */",
            *_matvec(
                "g",
                g4,
                ["qp_lstm_b_ih[j]", "qp_lstm_b_hh[j]"],
                [(x, "qp_lstm_w_ih", d), ("h", "qp_lstm_w_hh", hs)],
                UNROLL,
            ),
            f"    for (j = 0; j < {hs}; ++j) {{",
            "        const float in_gate = qp_sigmoid(g[j]);",
            f"        const float forget_gate = qp_sigmoid(g[{hs} + j]);",
            f"        const float cell = qp_tanh(g[{2 * hs} + j]);",
            f"        const float out_gate = qp_sigmoid(g[{3 * hs} + j]);",
            "        c[j] = forget_gate * c[j] + in_gate * cell;",
            "        h[j] = out_gate * qp_tanh(c[j]);",
            "    }",
        ]
        x = "h"
    for k, layer in enumerate(net.layers):
        body += _dense(k, layer, x, names[k], head=net.squashed and k == len(net.layers) - 1)
        x = names[k]
    if net.squashed:
        # the graph's form (export.onnx_export.DeployablePolicy): the min and max are comparisons
        # that pass a NaN through, as the graph's Clip does
        body += [
            "    /* tanh head -> motor command: u_hover*sqrt(1 + tanh z) = u_hover*sqrt(2p/(p + q)),",
            "     * p = e^(2 min(z, 0)), q = e^(-2 max(z, 0)): no cancellation of 1 + tanh z near -1 */",
            f"    for (j = 0; j < {NUM_MOTORS}; ++j) {{",
            f"        const float z = {x}[j];",
            "        const float p = expf((z > 0.0f ? 0.0f : z) * 2.0f);",
            "        const float q = expf((z < 0.0f ? 0.0f : z) * -2.0f);",
            "        const float m = sqrtf(p * 2.0f / (p + q)) * qp_u_hover;",
            f"        motors[j] = {_clamp('m', 'qp_command_lo', 'qp_command_hi')};",
            "    }",
        ]
    else:
        body += [
            "    /* mean action -> motor command (core.dynamics.action_to_command) */",
            f"    for (j = 0; j < {NUM_MOTORS}; ++j) {{",
            f"        const float a = {_clamp(f'{x}[j]', 'qp_action_lo', 'qp_action_hi')};",
            "        const float m = qp_u_hover * sqrtf(1.0f + a);",
            f"        motors[j] = {_clamp('m', 'qp_command_lo', 'qp_command_hi')};",
            "    }",
        ]
    if net.recurrent:
        signature = (
            f"void {STEP}(const float obs[restrict QP_OBS_DIM], float h[restrict QP_HIDDEN], "
            "float c[restrict QP_HIDDEN], float motors[restrict QP_NUM_MOTORS])"
        )
        tail = [
            "",
            f"void {RESET}(float h[restrict QP_HIDDEN], float c[restrict QP_HIDDEN])",
            "{",
            "    int j;",
            f"    for (j = 0; j < {net.hidden}; ++j) {{",
            "        h[j] = 0.0f;",
            "        c[j] = 0.0f;",
            "    }",
            "}",
        ]
    else:
        signature = f"void {ENTRY}(const float obs[restrict QP_OBS_DIM], float motors[restrict QP_NUM_MOTORS])"
        tail = []
    helpers: list[str] = []
    if _uses_tanh(net):
        helpers += [*TANH_C.splitlines(), ""]
    if net.recurrent:
        helpers += [*SIGMOID_C.splitlines(), ""]
    lines = [
        f"/* {SOURCE_NAME}: generated by {GENERATOR} from the policy exported from the checkpoint with SHA-256",
        f" * {facts.source_sha256}. Do not edit. The interface and the conventions are in {HEADER_NAME}. */",
        f'#include "{HEADER_NAME}"',
        "",
        "#include <math.h>",
        "",
        *consts,
        "",
        "\n\n".join(arrays),
        "",
        *helpers,
        signature,
        "{",
        *body,
        "}",
        *tail,
        "",
    ]
    return "\n".join(lines)


# --- a timing and self-test program ------------------------------------------------------------


def bench_source(info: ModelInfo, iterations: int = 2_000, repeats: int = 101) -> str:
    """bench.c: replays the file's golden vectors through the kernel (exit status 1 if any command
    differs by more than 1e-5), then times `repeats` × `iterations` back-to-back calls with
    clock_gettime(CLOCK_MONOTONIC) and prints one line per repeat: `ns_per_inference <value>`.
    Arguments override both: `bench [iterations [repeats]]`. Many short repeats (about a
    millisecond each) and their median, rather than one long run, because a long run on a shared
    machine includes the time other processes held the core.

    The observation changes by one ulp-scale step per call and the commands feed a volatile sum, so
    the compiler can neither hoist the call out of the loop nor drop it. POSIX (clock_gettime)."""
    golden_obs = ",\n    ".join("{ " + ", ".join(c_float(v) for v in row) + " }" for row in info.golden_obs)
    golden_act = ",\n    ".join("{ " + ", ".join(c_float(v) for v in row) + " }" for row in info.golden_action)
    k = len(info.golden_obs)
    recurrent = info.recurrent
    call = f"{STEP}(obs, h, c, motors)" if recurrent else f"{ENTRY}(obs, motors)"
    state = "static float h[QP_HIDDEN], c[QP_HIDDEN];\n" if recurrent else ""
    reset = f"    {RESET}(h, c);\n" if recurrent else ""
    return f"""\
/* bench.c: golden-vector check and timing loop for {HEADER_NAME}, generated by {GENERATOR}. */
#define _POSIX_C_SOURCE 199309L
#include "{HEADER_NAME}"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static const float golden_obs[{k}][QP_OBS_DIM] = {{
    {golden_obs}
}};
static const float golden_action[{k}][QP_NUM_MOTORS] = {{
    {golden_act}
}};
{state}static volatile float sink;

static double now_ns(void)
{{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec * 1e9 + (double)t.tv_nsec;
}}

int main(int argc, char **argv)
{{
    long iterations = argc > 1 ? atol(argv[1]) : {iterations}L;
    int repeats = argc > 2 ? atoi(argv[2]) : {repeats};
    float obs[QP_OBS_DIM], motors[QP_NUM_MOTORS];
    float worst = 0.0f;
    int r, k, i;
    long n;
{reset}    for (k = 0; k < {k}; ++k) {{
        for (i = 0; i < QP_OBS_DIM; ++i) obs[i] = golden_obs[k][i];
        {call};
        for (i = 0; i < QP_NUM_MOTORS; ++i) {{
            float diff = fabsf(motors[i] - golden_action[k][i]);
            if (!(diff <= worst)) worst = diff;
        }}
    }}
    printf("golden_max_abs_diff %.3g\\n", (double)worst);
    if (!(worst <= 1e-5f)) return 1;
    for (r = 0; r < repeats; ++r) {{
        double t0, t1;
        float acc = 0.0f;
{reset}        for (i = 0; i < QP_OBS_DIM; ++i) obs[i] = golden_obs[0][i];
        t0 = now_ns();
        for (n = 0; n < iterations; ++n) {{
            obs[n % QP_OBS_DIM] += 1e-6f;
            {call};
            acc += motors[0] + motors[3];
        }}
        t1 = now_ns();
        sink = acc;
        printf("ns_per_inference %.2f\\n", (t1 - t0) / (double)iterations);
    }}
    return 0;
}}
"""


# --- operation count and a Cortex-M4F estimate -------------------------------------------------


def operation_count(net: Network) -> dict[str, int]:
    """Floating-point work of one inference, as the generated code does it.

    mac: multiply-accumulates (bias included as the first add); tanh: `qp_tanh` calls (one expf
    and one division each); expf: the LSTM's sigmoids (each one expf, one add and one division,
    the divisions counted in `div`) and a tanh head's p and q; expm1f: ELU; sqrtf: the motor map;
    other: adds, multiplies and compares outside the matrix products; weights: float constants read
    (each once)."""
    mac = sum(layer.weight.size for layer in net.layers)
    hidden_layers = net.layers[:-1] if net.squashed else net.layers
    tanh = sum(layer.weight.shape[0] for layer in hidden_layers if layer.activation == "tanh")
    expm1 = sum(layer.weight.shape[0] for layer in net.layers if layer.activation == "elu")
    other = sum(layer.weight.shape[0] for layer in net.layers)  # the bias add
    exp = div = 0
    if net.norm is not None:
        other += 4 * net.obs_dim  # subtract, multiply, two compares
    if net.lstm is not None:
        hs = net.hidden
        mac += 4 * hs * (net.obs_dim + hs)
        other += 2 * 4 * hs  # b_ih + b_hh, then the first add
        exp += 3 * hs  # sigmoid of the i, f, o gates
        div += 3 * hs
        tanh += 2 * hs  # the cell candidate and tanh(c)
        other += 3 * hs + 3 * hs  # 1 + e^-z; c = f*c + i*g (two multiplies, one add) and h = o*tanh(c)
    if net.squashed:  # per motor: p and q (two expf), 2p/(p + q), one clamp fewer
        exp += 2 * NUM_MOTORS
        div += NUM_MOTORS
        other += NUM_MOTORS * 6  # min, max, two multiplies by +/-2, 2p and p + q
        other -= NUM_MOTORS * 3  # no action clamp and no 1 + a
    other += NUM_MOTORS * 6  # two clamps (four compares), 1 + a, the multiply by u_hover
    weights = sum(a.size for a in net.arrays().values())
    return {
        "mac": mac,
        "tanh": tanh,
        "expf": exp,
        "expm1f": expm1,
        "div": div,
        "sqrtf": NUM_MOTORS,
        "other": other,
        "weights": weights,
    }


CORTEX_M4_CYCLES = {
    "mac": (4, 6),
    "tanh": (110, 160),
    "expf": (90, 130),
    "expm1f": (110, 170),
    "div": (14, 14),
    "sqrtf": (14, 20),
    "other": (1, 3),
}
"""Cycles per operation on a Cortex-M4F (single-precision FPU) at zero wait states, (low, high).

Instruction timings: ARM Cortex-M4 Technical Reference Manual r0p1 (DDI 0439B), table 7-1 "FPU
instruction set" (also TI SWCU192, table 3-27): VADD/VSUB/VMUL 1 cycle, VMLA/VFMA 3, VDIV 14,
VSQRT 14, VLDR 2 (neighbouring loads pipeline to 1), VLDM 1 + N, VSTR 2, VMOV/VCMP/VMRS 1; a taken
branch 1 + 1..3 (pipeline refill). How they add up, from `arm-none-eabi-objdump -d` of this
generator's code built by arm-none-eabi-gcc 12.2 at -O2 -mcpu=cortex-m4 -mfpu=fpv4-sp-d16
-mfloat-abi=hard, linked with Debian's newlib 3.3 (the v7e-m+fp hard-float multilib):

- mac: the inner loop does 4 products per pass: 4 weight loads and 1 accumulator load (VLDM/VLDR),
  4 VMUL + 4 VADD (ISO C does not contract them into VFMA, 3 cycles anyway), 1 store, compare and
  branch: 16 instructions, about 18-22 cycles, so 4-6 cycles per multiply-accumulate. There is no
  SIMD for floats on the M4.
- expf: newlib's `expf` wrapper (overflow/underflow checks, finitef) around fdlibm's
  `__ieee754_expf` (single precision, no double arithmetic): about 45 + 20 instructions on the
  common path, with one VDIV, five VFMA and about twelve VLDR of constants: 90-130 cycles.
- tanh: `qp_tanh` is expf plus one VDIV, two adds and the call: 110-160 cycles.
- expm1f (ELU only): fdlibm's `expm1f`, one VDIV and a longer polynomial path: 110-170.
- div 14 (VDIV); sqrtf 14 (inline VSQRT; 20 with the errno check's compare and branch).
- Flash: at 168 MHz an STM32F4 reads flash with 5 wait states (RM0090, table 10, 2.7-3.6 V); the
  ART accelerator's prefetch and instruction cache hide most of it for code, but each weight is
  read once per inference, so a 128-bit flash line (4 floats) missing the 8-line data cache costs
  ~6 cycles: up to +1.5 cycles per weight (`FLASH_CYCLES_PER_WEIGHT`), avoidable by copying the
  weights to RAM (e.g. the 64 KiB CCM) if they fit.

These are estimates from instruction counts, not a measurement on hardware (none here)."""
FLASH_CYCLES_PER_WEIGHT = (0.0, 1.5)


def cortex_m4_estimate(counts: dict[str, int], mhz: float = 168.0) -> dict[str, float]:
    """Cycles (low, high) and µs at `mhz` for one inference on a Cortex-M4F, from `operation_count`
    and the per-operation figures of `CORTEX_M4_CYCLES` (read its doc for where they come from)."""
    low = sum(counts[k] * CORTEX_M4_CYCLES[k][0] for k in CORTEX_M4_CYCLES)
    high = sum(counts[k] * CORTEX_M4_CYCLES[k][1] for k in CORTEX_M4_CYCLES)
    low += counts["weights"] * FLASH_CYCLES_PER_WEIGHT[0]
    high += counts["weights"] * FLASH_CYCLES_PER_WEIGHT[1]
    return {
        "cycles_low": float(low),
        "cycles_high": float(high),
        "us_low": low / mhz,
        "us_high": high / mhz,
        "mhz": mhz,
    }
