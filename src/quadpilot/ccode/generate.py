"""C99 source for an exported policy: the one generator behind `quad-export --format c` and the
runtime's `c` backend.

    from quadpilot.ccode.generate import generate, initializers
    model, info = read_model("policy.onnx")
    code = generate(info, initializers(model))   # code.header (policy.h), code.source (policy.c)

The input is what the NumPy backend reads: the file's checked metadata (`ModelInfo`) and the
network its architecture metadata describes (`network.Network`, read from its initializers by
`network.network_from_model`). So the C, the NumPy backend and ONNX Runtime all compute from the same
float32 weights of the same file, and `quad-export --format c` feeds this
generator the ONNX file it has just exported: there is no second path from a checkpoint to C.

What the C computes is what the graph computes (`export.onnx_export.DeployablePolicy` /
`DeployableRecurrentPolicy`): optional observation normalisation clip((obs − mean)·inv_std, ±clip),
the dense layers (or the LSTM cell, torch gate order i, f, g, o, then the dense head), the mean
action clipped to the action range, and the motor command u_hover·√(1 + a) clipped to [0, 1]. For
a tanh action head (SAC) the command is computed as the graph does, u_hover·√(2p/(p + q)) with
p = e^(2·min(z, 0)), q = e^(−2·max(z, 0)): the same function as u_hover·√(1 + tanh z) without the
cancellation of 1 + tanh z near a = −1, which the √ would magnify to ~1e-4.

The file is untrusted (docs/architecture.md, "Trust boundaries"), and generated code is compiled and loaded,
so nothing from the file reaches the text except numbers the generator formats itself
(`ctext.c_float`, and integers it computed): no metadata string and no initializer name. The text in
the header and the comments comes from this runtime's own tables (the observation layout of
`core.observation` found by name, `model.ACTION_MEANING`, the generator's fixed text), and the few
strings the header repeats from the metadata are checked again here, as `model.read_model` checks
them: the task is one of `core.mission.TASKS`, the source SHA-256 is 64 lowercase hex digits, the
vehicle name a plain one (`core.vehicle_file.NAME_PATTERN`). A ModelInfo that fails any of these
(one not made by `read_model`) is refused with a ModelContractError.

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
- Only libm: `expf` (tanh as 1 − 2/(e^2x + 1), `TANH_C`, the form parity is checked for, or libm's
  `tanhf` with -DQP_USE_TANHF, which rounds differently: within 2e-5 of ONNX where `expf` is within 1e-5;
  the LSTM's σ(z) = 1/(1 + e^−z)), `sqrtf`, and `expm1f` for an ELU network; `float` throughout
  with `f`-suffixed constants, so no double arithmetic (which a single-precision FPU such as the
  Cortex-M4F's would emulate in software).
- NaN in gives NaN out (the clamps are comparisons that a NaN fails). The kernel checks nothing:
  the runtime's `SafetyMonitor` validates observations and commands around it, and firmware must do
  the same (the header says so).
- The text is ASCII only (the layout's units and meanings are transliterated), for any toolchain.

The names and text primitives every generated file shares are in `ccode.text`; the timing program
and the operation count and Cortex-M4F estimate of a generated kernel are in `ccode.bench`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from quadpilot.core.mission import TASKS
from quadpilot.core.observation import ObsLayout, get_layout
from quadpilot.core.vehicle_file import NAME_PATTERN
from quadpilot.modelfile.model import (
    ACTION_MEANING,
    NUM_MOTORS,
    SHA256_PATTERN,
    ModelContractError,
    ModelInfo,
    initializer_arrays,
)
from quadpilot.modelfile.network import FLT_MAX, Dense, Network, network_from_model

from .text import ENTRY, GENERATOR, HEADER_NAME, RESET, SOURCE_NAME, STEP, ascii_text, c_array, c_float, clamp, wrap

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


def initializers(model) -> dict[str, np.ndarray]:
    """The initializers of an `onnx.ModelProto` by name (what the architecture metadata names), as
    checked float32 arrays (`model.initializer_arrays`; ModelContractError for a bad one)."""
    return initializer_arrays(model)


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
        from pathlib import Path

        from quadpilot.atomic_files import atomic_write

        directory = Path(directory)
        paths = []
        for name, text in ((HEADER_NAME, self.header), (SOURCE_NAME, self.source)):
            paths.append(atomic_write(directory / name, lambda f, text=text: f.write(text.encode("ascii"))))
        return tuple(paths)


def generate(info: ModelInfo, weights: dict[str, np.ndarray]) -> CCode:
    """policy.h and policy.c for the file `info` and `weights` come from (see the module doc).

    Raises ModelContractError if the architecture metadata and the weights do not fit."""
    return generate_network(info, network_from_model(info, weights))


def generate_network(info: ModelInfo, net: Network) -> CCode:
    """policy.h and policy.c for the network `net` of the file `info` describes (`generate`, for a
    caller that has read the network already). Raises ModelContractError for a ModelInfo whose
    facts the header may not repeat (see the module doc)."""
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
    if not (isinstance(vehicle.name, str) and NAME_PATTERN.fullmatch(vehicle.name)):
        raise refuse("the vehicle name is not a plain identifier")
    values = {f.name: float(getattr(vehicle, f.name)) for f in fields(vehicle) if f.name not in ("name", "rotors")}
    rotors = [(float(r.x), float(r.y), "ccw" if r.spin == "ccw" else "cw") for r in vehicle.rotors]
    numbers = [*values.values(), *(c for x, y, _ in rotors for c in (x, y)), float(info.control_period_s)]
    numbers += [float(info.envelope["max_distance_m"]), float(info.envelope["max_tilt_deg"])]
    if not all(math.isfinite(v) and abs(v) <= FLT_MAX for v in numbers) or not numbers[-3] > 0:
        raise refuse("a vehicle, control period or envelope number is not finite")
    # the field names are VehicleParams' own; a float's repr is digits, '.', 'e', '+' and '-'
    # a rotor's spin is one of two fixed strings (core.params.Rotor checks it; written from this table)
    rotor_text = ", ".join(f'{{"x": {x!r}, "y": {y!r}, "spin": "{s}"}}' for x, y, s in rotors)
    text = ", ".join(
        [f'"name": "{vehicle.name}"', *(f'"{k}": {v!r}' for k, v in values.items()), f'"rotors": [{rotor_text}]']
    )
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
 * {wrap("Vehicle: " + facts.vehicle)}
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
 * {wrap(output)}
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


def stages(net: Network) -> list[str]:
    """The stages of one step in the order the code runs them, as `QP_PROBE(k)` closes stage k
    (k = 1, 2, ...): normalisation, the recurrent cell, each dense layer, the command map."""
    out = ["normalisation"] if net.norm is not None else []
    if net.lstm is not None:
        out.append(f"LSTM cell {net.obs_dim}+{net.hidden} -> 4x{net.hidden}")
    for k, layer in enumerate(net.layers):
        n_out, n_in = layer.weight.shape
        out.append(f"layer {k} {n_in} -> {n_out}{' ' + layer.activation if layer.activation else ''}")
    return [*out, "command map"]


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
        arrays.append(c_array("qp_obs_mean", net.norm[0], "observation mean"))
        arrays.append(c_array("qp_obs_inv_std", net.norm[1], "1/std of the observation"))
    if net.lstm is not None:
        w_ih, w_hh, b_ih, b_hh = net.lstm
        arrays += [
            c_array("qp_lstm_w_ih", w_ih.T, "LSTM input weights transposed: [input][gate], gates i, f, g, o"),
            c_array("qp_lstm_w_hh", w_hh.T, "LSTM recurrent weights transposed: [h][gate], gates i, f, g, o"),
            c_array("qp_lstm_b_ih", b_ih, "LSTM input bias (zeros where the exporter dropped an all-zero one)"),
            c_array("qp_lstm_b_hh", b_hh, "LSTM recurrent bias (zeros where the exporter dropped an all-zero one)"),
        ]
    for k, layer in enumerate(net.layers):
        arrays.append(c_array(f"qp_w{k}", layer.weight.T, f"layer {k}: weight transposed, [in][out]"))
        arrays.append(c_array(f"qp_b{k}", layer.bias, f"layer {k}: bias (zeros where the exporter dropped it)"))
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
    probe = iter(range(1, len(stages(net)) + 1))
    body.append("    QP_PROBE(0);")
    if net.norm is not None:
        body += [
            "    /* observation normalisation */",
            f"    for (i = 0; i < {d}; ++i) {{",
            "        const float v = (obs[i] - qp_obs_mean[i]) * qp_obs_inv_std[i];",
            f"        x[i] = {clamp('v', '-qp_obs_clip', 'qp_obs_clip')};",
            "    }",
        ]
        x = "x"
        body.append(f"    QP_PROBE({next(probe)});")
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
            f"    QP_PROBE({next(probe)});",
        ]
        x = "h"
    for k, layer in enumerate(net.layers):
        body += _dense(k, layer, x, names[k], head=net.squashed and k == len(net.layers) - 1)
        body.append(f"    QP_PROBE({next(probe)});")
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
            f"        motors[j] = {clamp('m', 'qp_command_lo', 'qp_command_hi')};",
            "    }",
        ]
    else:
        body += [
            "    /* mean action -> motor command (core.dynamics.action_to_command) */",
            f"    for (j = 0; j < {NUM_MOTORS}; ++j) {{",
            f"        const float a = {clamp(f'{x}[j]', 'qp_action_lo', 'qp_action_hi')};",
            "        const float m = qp_u_hover * sqrtf(1.0f + a);",
            f"        motors[j] = {clamp('m', 'qp_command_lo', 'qp_command_hi')};",
            "    }",
        ]
    body.append(f"    QP_PROBE({next(probe)});")
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
        "/* QP_PROBE(k): a hook after each stage of the step (k = 0 at entry; the stages are listed in",
        " * cgen.stages), empty unless the build defines it: the emulator's per-stage instruction count. */",
        "#ifndef QP_PROBE",
        "#define QP_PROBE(stage)",
        "#endif",
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
