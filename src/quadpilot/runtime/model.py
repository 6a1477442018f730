"""Reading a quad-export ONNX file and checking its contract before anything flies it.

Everything in the file is untrusted: its graph and every metadata string (DESIGN.md, "Trust
boundaries"). The rules this module enforces, in one place, before any backend sees the file:

- Every metadata value is validated where it is read, against what this runtime knows: the schema;
  the observation layout (found by name in `core.observation`, with the same fields); the action
  meaning (the text of the schema, `ACTION_MEANING`); the task (one of `core.mission.TASKS`); the
  source checkpoint's SHA-256 (64 lowercase hex digits); the control period and training steps;
  the vehicle (`VehicleParams` checks its numbers, its name is a plain identifier, its hover command
  is the architecture's u_hover); the envelope; the architecture (known keys only, finite ordered
  clips, bounded sizes); the golden vectors (finite, bounded count). JSON NaN and Infinity are
  refused. Strings read from the file are never executed and never pasted into generated code:
  `cgen` writes only numbers it formats itself and text from this runtime's own tables, and the
  strings it does write are checked here against a fixed set or a strict pattern.
- The graph is exactly the architecture its metadata declares (`_check_graph`): the operators in
  the order `export.onnx_export` writes them, their attributes, the initializers the metadata names
  with the shapes that chain the layers, and scalar constants equal to the metadata's clips and
  u_hover; no other node, initializer, operator set or local function. So ONNX Runtime, which runs
  the graph, and the NumPy and C backends, which compute the architecture from the same
  initializers, compute the same function. The first difference is reported in one line.
- Every weight is float32, finite and inside the file (no external data).

Then the backends replay the golden vectors stored in the file (`backends.load_policy`). Each
failure is a `ModelContractError` (a ValueError) that says what was expected and what was found.

Uses the `onnx` package to parse the file (protobuf), never torch.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from quadpilot.core.dynamics import MOTOR_NAMES
from quadpilot.core.mission import TASKS
from quadpilot.core.observation import ObsLayout, get_layout
from quadpilot.core.params import VehicleParams

SCHEMA = "quadpilot.onnx/1"
"""The metadata schema this runtime reads (written by quad-export)."""
NUM_MOTORS = 4
REQUIRED_KEYS = (
    "quadpilot.schema",
    "quadpilot.obs_layout",
    "quadpilot.action",
    "quadpilot.control_period_s",
    "quadpilot.vehicle",
    "quadpilot.task",
    "quadpilot.training_steps",
    "quadpilot.source_sha256",
    "quadpilot.golden",
    "quadpilot.architecture",
    "quadpilot.envelope",
)
MAX_FILE_BYTES = 64 << 20  # a policy for a 100 Hz controller is kilobytes; refuse to slurp a disk image
ACTION_MEANING = (
    "normalised rotor speed omega/omega_max in [0, 1] per motor (thrust proportional to its square), "
    "PX4 quad-X order: " + ", ".join(f"{i} {name}" for i, name in enumerate(MOTOR_NAMES))
)
"""What the schema's output is (`export.onnx_export` writes this text); a file must say the same."""
SHA256_PATTERN = re.compile(r"[0-9a-f]{64}")
VEHICLE_NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}")
"""A vehicle name is a plain identifier (presets: seed, crazyflie); it is written into generated C."""
OPSETS = range(18, 24)
"""Standard operator set versions whose export of our networks is the graph `_check_graph` expects
(checked for 18 to 23; the ops used did not change meaning between them). 18 is quad-export's
default; below 18, Split has no num_outputs attribute."""
MAX_LAYERS = 16
MAX_HIDDEN = 1024
MAX_GOLDEN = 1024
"""At most this many golden vectors (quad-export writes 8): every backend replays them at load."""
CONTROL_PERIOD_RANGE_S = (1e-4, 1.0)
MAX_TRAINING_STEPS = 2**63 - 1
MAX_DISTANCE_M = 1e6  # any number of metres a float32 (the C header's QP_MAX_DISTANCE_M) holds
MAX_OBS_CLIP = 1e6
ACTIVATIONS = ("tanh", "relu", "elu")
"""Hidden-layer activations every backend computes; the action head has none, or tanh (SAC)."""


class ModelContractError(ValueError):
    """The file is not a policy this runtime may fly; the message says why."""


@dataclass(frozen=True)
class ModelInfo:
    """What the file's metadata says about the policy inside it (every value checked)."""

    path: str
    layout: ObsLayout
    """This runtime's own layout of that name (the file's fields were compared with it)."""
    task: str
    """One of `core.mission.TASKS`."""
    control_period_s: float
    vehicle: VehicleParams
    training_steps: int
    source_sha256: str
    """64 lowercase hex digits."""
    action_meaning: str
    """Equal to `ACTION_MEANING`."""
    architecture: dict
    """kind (mlp or lstm), layers and their initializer names, normalisation, action mapping:
    checked, numbers as floats, and matched against the graph (`_check_graph`)."""
    envelope: dict
    """max_distance_m and max_tilt_deg (floats): the states the policy was trained in (beyond them
    it never learned to act; training episodes ended there)."""
    golden_obs: np.ndarray
    """(K, obs_dim) float32, finite, a sequence from zero recurrent state."""
    golden_action: np.ndarray
    """(K, 4) float32, finite, what the exporting torch module answered."""

    @property
    def obs_dim(self) -> int:
        return self.layout.dim

    @property
    def recurrent(self) -> bool:
        return self.architecture["kind"] == "lstm"

    @property
    def hidden(self) -> int:
        return int(self.architecture.get("hidden", 0))

    def input_names(self) -> tuple[str, ...]:
        return ("obs", "h_in", "c_in") if self.recurrent else ("obs",)

    def output_names(self) -> tuple[str, ...]:
        return ("action", "h_out", "c_out") if self.recurrent else ("action",)


def _fail(path, what: str) -> ModelContractError:
    return ModelContractError(f"{path}: {what}")


def _short(text, limit: int = 60) -> str:
    """A file's string for a message: repr (one line, escapes shown), cut to `limit` characters."""
    text = str(text)
    return repr(text if len(text) <= limit else text[:limit] + "...")


def _cut(text, limit: int = 300) -> str:
    """An exception's message for ours: one line, at most `limit` characters."""
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[:limit] + "..."


def _refuse_constant(name: str):
    raise ValueError(f"it holds {name}, which is not a finite number")


def _json(path, props: dict, key: str):
    try:
        # JSON has no NaN or Infinity; Python's json reads them unless told not to
        return json.loads(props[key], parse_constant=_refuse_constant)
    except (ValueError, TypeError, RecursionError) as e:  # JSONDecodeError is a ValueError
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise _fail(path, f"metadata {key} is not valid JSON ({first})") from None


def _number(value) -> float | None:
    """`value` as a float if it is a JSON number (not a bool, not a string), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        return float(value)
    except OverflowError:  # an integer beyond float range
        return None


def read_model(path: str | os.PathLike):
    """Parse and check an exported policy file. Returns (onnx.ModelProto, ModelInfo)."""
    import onnx
    from google.protobuf.message import DecodeError

    path = Path(path)
    if not path.is_file():
        raise _fail(path, "no such file (expected an .onnx file written by quad-export)")
    size = path.stat().st_size
    if size == 0:
        raise _fail(path, "the file is empty (expected an ONNX model written by quad-export)")
    if size > MAX_FILE_BYTES:
        raise _fail(
            path, f"{size / 2**20:.0f} MiB is far larger than any policy file (limit {MAX_FILE_BYTES >> 20} MiB)"
        )
    data = path.read_bytes()
    try:
        model = onnx.ModelProto()
        model.ParseFromString(data)
    except (DecodeError, RuntimeError, ValueError) as e:
        reason = f"not an ONNX model: protobuf could not parse it ({e}); truncated, or not a quad-export file?"
        raise _fail(path, reason) from None
    if not model.HasField("graph") or not model.graph.node:
        raise _fail(path, "parses, but holds no graph (truncated, or not an ONNX model)")
    external = [t.name for t in model.graph.initializer if t.data_location == onnx.TensorProto.EXTERNAL]
    if external:
        raise _fail(
            path,
            f"weights stored as external data ({', '.join(_short(n, 40) for n in external[:3])}…); quadpilot models "
            "keep every weight "
            "inside the .onnx file so that the file that was checked is the file that flies",
        )
    try:
        onnx.checker.check_model(model, full_check=True)
    except (onnx.checker.ValidationError, onnx.shape_inference.InferenceError, RuntimeError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise _fail(path, f"onnx.checker rejects the model: {_cut(first)}") from None
    except Exception as e:  # the checker is C++ behind pybind: anything else it raises is still a bad file
        raise _fail(path, f"onnx.checker cannot check the model ({type(e).__name__})") from None
    props = {}
    for p in model.metadata_props:
        if not isinstance(p.key, str) or not isinstance(p.value, str):  # upb hands back bytes for bad UTF-8
            raise _fail(path, f"metadata entry {_cut(repr(p.key), 80)} is not valid UTF-8 text (a corrupted file)")
        props[p.key] = p.value
    info = _read_metadata(path, props)
    _check_io(path, model, info)
    arch = _read_architecture(path, info.architecture)
    _check_hover_command(path, info.vehicle, arch)
    info = replace(info, architecture=arch)
    _check_graph(path, model, info, initializer_arrays(model, path))
    return model, info


def initializer_arrays(model, path="model") -> dict[str, np.ndarray]:
    """The graph's initializers by name as float32 arrays (what the architecture metadata names).

    Raises ModelContractError for a weight that is not float32, not finite or not readable: the
    NumPy and C backends read these arrays, ONNX Runtime the same tensors in the graph."""
    import onnx
    from onnx import numpy_helper

    out: dict[str, np.ndarray] = {}
    for t in model.graph.initializer:
        if t.data_type != onnx.TensorProto.FLOAT:
            kind = (
                onnx.TensorProto.DataType.Name(t.data_type).lower()
                if t.data_type in (onnx.TensorProto.DataType.values())
                else str(t.data_type)
            )
            raise _fail(path, f"initializer {_short(t.name)} is {kind}; every weight of a quadpilot policy is float32")
        try:
            a = numpy_helper.to_array(t)
        except Exception as e:  # a tensor whose data does not fill its dims, and the like
            raise _fail(path, f"initializer {_short(t.name)} cannot be read ({type(e).__name__})") from None
        if a.dtype != np.float32 or a.shape != tuple(t.dims):
            raise _fail(path, f"initializer {_short(t.name)} does not hold float32 data of shape {list(t.dims)}")
        if not np.all(np.isfinite(a)):
            raise _fail(path, f"initializer {_short(t.name)} holds non-finite values (NaN or infinity)")
        if t.name in out:
            raise _fail(path, f"initializer {_short(t.name)} is defined twice")
        out[t.name] = a
    return out


def _read_metadata(path, props: dict) -> ModelInfo:
    schema = props.get("quadpilot.schema")
    if schema != SCHEMA:
        found = "no quadpilot.schema entry (not written by quad-export)" if schema is None else _short(schema)
        raise _fail(path, f"metadata schema: expected {SCHEMA!r}, found {found}")
    missing = [k for k in REQUIRED_KEYS if k not in props]
    if missing:
        raise _fail(path, f"metadata lacks {', '.join(missing)} (schema {SCHEMA} requires {', '.join(REQUIRED_KEYS)})")
    layout_json = _json(path, props, "quadpilot.obs_layout")
    try:
        layout = get_layout(layout_json["name"])
    except (ValueError, KeyError, TypeError) as e:
        raise _fail(path, f"observation layout: {_cut(e)}") from None
    if layout_json != json.loads(json.dumps(layout.to_json())):
        fields = layout_json.get("fields") if isinstance(layout_json.get("fields"), list) else []
        listed = [(f.get("name"), f.get("size")) if isinstance(f, dict) else f for f in fields]
        raise _fail(
            path,
            f"observation layout {layout.name!r}: the file lists fields (name, size) "
            f"{_short(listed, 300)[1:-1]}, "
            f"this runtime's has {[(f.name, f.size) for f in layout.fields]} (units and meanings must match too)",
        )
    if props["quadpilot.action"] != ACTION_MEANING:
        raise _fail(
            path, f"metadata quadpilot.action: expected {ACTION_MEANING!r}, found {_short(props['quadpilot.action'])}"
        )
    task = props["quadpilot.task"]
    if task not in TASKS:
        raise _fail(path, f"metadata quadpilot.task: expected one of {', '.join(TASKS)}, found {_short(task)}")
    sha = props["quadpilot.source_sha256"]
    if not SHA256_PATTERN.fullmatch(sha):
        raise _fail(path, f"metadata quadpilot.source_sha256: expected 64 lowercase hex digits, found {_short(sha)}")
    try:
        period = float(props["quadpilot.control_period_s"])
        steps = int(props["quadpilot.training_steps"])
    except ValueError as e:
        raise _fail(path, f"metadata: {_short(e, 120)[1:-1]}") from None
    lo, hi = CONTROL_PERIOD_RANGE_S
    if not (math.isfinite(period) and lo <= period <= hi):
        raise _fail(path, f"control period {period} s: expected a finite period in [{lo:g}, {hi:g}] s")
    if not 0 <= steps <= MAX_TRAINING_STEPS:
        raise _fail(path, f"training steps {steps}: expected a count >= 0")
    vehicle = _read_vehicle(path, _json(path, props, "quadpilot.vehicle"))
    arch = _json(path, props, "quadpilot.architecture")  # its kind here; the rest after the I/O check
    if not isinstance(arch, dict) or arch.get("kind") not in _ARCH_KEYS:
        kind = arch.get("kind") if isinstance(arch, dict) else arch
        raise _fail(path, f"architecture kind: expected 'mlp' or 'lstm', found {_short(kind)}")
    envelope = _read_envelope(path, _json(path, props, "quadpilot.envelope"))
    g_obs, g_act = _read_golden(path, _json(path, props, "quadpilot.golden"), layout)
    return ModelInfo(
        path=str(path),
        layout=layout,
        task=task,
        control_period_s=period,
        vehicle=vehicle,
        training_steps=steps,
        source_sha256=sha,
        action_meaning=ACTION_MEANING,
        architecture=arch,
        envelope=envelope,
        golden_obs=g_obs,
        golden_action=g_act,
    )


def _read_vehicle(path, vehicle_json) -> VehicleParams:
    if not isinstance(vehicle_json, dict):
        raise _fail(path, f"vehicle metadata: expected an object of VehicleParams fields, found {_short(vehicle_json)}")
    try:
        vehicle = VehicleParams(**vehicle_json)
    except TypeError as e:
        raise _fail(path, f"vehicle metadata does not describe a VehicleParams ({_cut(e)})") from None
    except ValueError as e:  # VehicleParams names the field and what it expected
        raise _fail(path, f"vehicle metadata: {_cut(e)}") from None
    if not VEHICLE_NAME_PATTERN.fullmatch(vehicle.name):
        raise _fail(
            path,
            f"vehicle name {_short(vehicle.name)}: expected a plain name (letters, digits, _ . + -, at most 64)",
        )
    return vehicle


def _check_hover_command(path, vehicle: VehicleParams, arch: dict) -> None:
    """The action map's hover command is the vehicle's (export.onnx_export writes both from the
    training configuration's one vehicle, `EnvConfig.params`)."""
    hover = vehicle.hover_command
    if not math.isclose(hover, arch["u_hover"], rel_tol=1e-9):
        raise _fail(
            path,
            f"vehicle {vehicle.name!r} hovers at command {hover:.9g}, the architecture's u_hover is "
            f"{arch['u_hover']:.9g}: the metadata describes two different vehicles",
        )


def _read_envelope(path, envelope) -> dict:
    dist = tilt = None
    if isinstance(envelope, dict):
        dist, tilt = _number(envelope.get("max_distance_m")), _number(envelope.get("max_tilt_deg"))
    ok = dist is not None and tilt is not None and 0.0 < dist <= MAX_DISTANCE_M and 0.0 < tilt < 90.0
    if not ok:
        raise _fail(
            path,
            f"envelope: expected max_distance_m in (0, {MAX_DISTANCE_M:g}] and max_tilt_deg in (0, 90) as finite "
            f"numbers, found {_short(envelope, 120)}",
        )
    return {"max_distance_m": dist, "max_tilt_deg": tilt}


def _read_golden(path, golden, layout: ObsLayout) -> tuple[np.ndarray, np.ndarray]:
    def rows(key: str) -> np.ndarray:
        try:
            a = np.asarray(golden[key])
        except (KeyError, TypeError, ValueError, IndexError) as e:
            raise _fail(path, f"golden vectors unreadable ({type(e).__name__}: {_short(e, 80)[1:-1]})") from None
        if a.dtype.kind not in "iuf":  # strings, bools, objects (ragged lists give ValueError above)
            raise _fail(path, f"golden vectors: {key} holds {a.dtype} values, expected numbers")
        with np.errstate(over="ignore"):  # beyond float32: infinity, refused below
            return a.astype(np.float32)

    if not isinstance(golden, dict):
        raise _fail(path, f"golden vectors: expected an object with obs and action, found {type(golden).__name__}")
    g_obs, g_act = rows("obs"), rows("action")
    if g_obs.ndim != 2 or g_obs.shape[1] != layout.dim or g_act.shape != (g_obs.shape[0], NUM_MOTORS) or not len(g_obs):
        raise _fail(
            path,
            f"golden vectors: expected obs (K, {layout.dim}) and action (K, {NUM_MOTORS}), "
            f"found {g_obs.shape} and {g_act.shape}",
        )
    if len(g_obs) > MAX_GOLDEN:
        raise _fail(path, f"golden vectors: {len(g_obs)} of them, expected at most {MAX_GOLDEN}")
    for key, a in (("obs", g_obs), ("action", g_act)):
        bad = ~np.isfinite(a)
        if bad.any():  # NaN would make any comparison pass or fail by accident; ±Inf proves nothing
            k = int(np.argwhere(bad)[0][0])
            raise _fail(
                path, f"golden vectors: {key} {k} holds non-finite values (as float32); expected finite numbers"
            )
    return g_obs, g_act


_ARCH_KEYS = {
    "mlp": {"kind", "normalize", "action_clip", "u_hover", "command_clip", "layers"},
    "lstm": {"kind", "hidden", "normalize", "action_clip", "u_hover", "command_clip", "lstm", "layers"},
}


def _read_architecture(path, arch) -> dict:
    """The architecture metadata checked and normalised (numbers as floats); names are checked
    against the graph by `_check_graph`."""

    def bad(what: str) -> ModelContractError:
        return _fail(path, f"architecture: {what}")

    def name(value, what: str, optional: bool = False) -> str | None:
        if value is None and optional:
            return None
        if not isinstance(value, str) or not value or len(value) > 256:
            raise bad(f"{what}: expected an initializer name, found {_short(value)}")
        return value

    def pair(value, what: str, lo: float, hi: float) -> list[float]:
        nums = [_number(v) for v in value] if isinstance(value, list) and len(value) == 2 else [None]
        if None in nums or not (lo <= nums[0] < nums[1] <= hi):
            raise bad(f"{what}: expected [low, high] with {lo:g} <= low < high <= {hi:g}, found {_short(value)}")
        return nums

    kind = arch["kind"]  # checked by _read_metadata
    unknown = sorted(set(arch) - _ARCH_KEYS[kind])
    missing = sorted(_ARCH_KEYS[kind] - set(arch))
    if unknown or missing:
        extra = ", ".join(_short(k, 30) for k in unknown[:5]) or "none"
        raise bad(f"{kind} expects keys {sorted(_ARCH_KEYS[kind])}; unknown {extra}, missing {missing or 'none'}")
    out: dict = {"kind": kind}
    if kind == "lstm":
        hidden = arch["hidden"]
        if isinstance(hidden, bool) or not isinstance(hidden, int) or not 1 <= hidden <= MAX_HIDDEN:
            raise bad(f"hidden: expected an integer in [1, {MAX_HIDDEN}], found {_short(hidden)}")
        out["hidden"] = hidden
    norm = arch["normalize"]
    if norm is None:
        out["normalize"] = None
    else:
        clip = _number(norm.get("clip")) if isinstance(norm, dict) else None
        if not isinstance(norm, dict) or set(norm) != {"mean", "inv_std", "clip"} or clip is None:
            raise bad(f"normalize: expected null or {{mean, inv_std, clip}}, found {_short(norm)}")
        if not 0.0 < clip <= MAX_OBS_CLIP:
            raise bad(f"normalize clip {clip!r}: expected a finite number in (0, {MAX_OBS_CLIP:g}]")
        out["normalize"] = {"mean": name(norm["mean"], "normalize mean"), "inv_std": name(norm["inv_std"], "inv_std")}
        out["normalize"]["clip"] = clip
    out["action_clip"] = pair(arch["action_clip"], "action_clip", -1.0, 1.0)  # √(1 + a) needs a >= -1
    u_hover = _number(arch["u_hover"])
    if u_hover is None or not 0.0 < u_hover <= 1.0:
        raise bad(f"u_hover: expected a number in (0, 1], found {_short(arch['u_hover'])}")
    out["u_hover"] = u_hover
    out["command_clip"] = pair(arch["command_clip"], "command_clip", 0.0, 1.0)
    if kind == "lstm":
        spec = arch["lstm"]
        keys = {"weight_ih", "weight_hh", "bias_ih", "bias_hh"}
        if not isinstance(spec, dict) or set(spec) != keys:
            raise bad(f"lstm: expected {{{', '.join(sorted(keys))}}}, found {_short(spec)}")
        out["lstm"] = {k: name(spec[k], f"lstm {k}", optional=k.startswith("bias")) for k in sorted(keys)}
    layers = arch["layers"]
    if not isinstance(layers, list) or not 1 <= len(layers) <= MAX_LAYERS:
        raise bad(f"layers: expected a list of 1 to {MAX_LAYERS} layers, found {_short(layers)}")
    out["layers"] = []
    for k, layer in enumerate(layers):
        if not isinstance(layer, dict) or set(layer) != {"weight", "bias", "activation"}:
            raise bad(f"layer {k}: expected {{weight, bias, activation}}, found {_short(layer)}")
        act = layer["activation"]
        last = k == len(layers) - 1
        allowed = (None, "tanh") if last else (None, *ACTIVATIONS)
        if act not in allowed:
            raise bad(f"layer {k} activation: expected one of {list(allowed)}, found {_short(act)}")
        out["layers"].append(
            {"weight": name(layer["weight"], f"layer {k} weight"), "bias": name(layer["bias"], "bias", True)}
            | {"activation": act}
        )
    if out["layers"][-1]["activation"] == "tanh" and out["action_clip"] != [-1.0, 1.0]:
        # a tanh head's graph has no action clip (export.onnx_export.DeployablePolicy): only
        # [-1, 1], which tanh never leaves, describes it
        raise bad(f"a tanh action head needs action_clip [-1, 1], found {out['action_clip']}")
    return out


def _dims(value_info) -> list:
    dims = value_info.type.tensor_type.shape.dim
    return [d.dim_param or (d.dim_value if d.HasField("dim_value") else "?") for d in dims]


def _names(values, limit: int = 6) -> str:
    names = [v.name for v in values]
    shown = ", ".join(_short(n, 40) for n in names[:limit])
    return f"[{shown}{', ...' if len(names) > limit else ''}]"


def _check_io(path, model, info: ModelInfo) -> None:
    import onnx

    # every graph input counts: an initializer listed as an input is one a caller could override
    inputs, outputs = list(model.graph.input), list(model.graph.output)
    want_in, want_out = info.input_names(), info.output_names()
    got_in, got_out = tuple(i.name for i in inputs), tuple(o.name for o in outputs)
    if got_in != want_in or got_out != want_out:
        want = f"{list(want_in)} → {list(want_out)}"
        raise _fail(path, f"graph inputs/outputs: expected {want}, found {_names(inputs)} → {_names(outputs)}")
    h = info.architecture.get("hidden")
    h = h if isinstance(h, int) and not isinstance(h, bool) and 1 <= h <= MAX_HIDDEN else None  # else refused next
    widths = {"obs": info.obs_dim, "action": NUM_MOTORS, "h_in": h, "c_in": h, "h_out": h, "c_out": h}
    for v in (*inputs, *outputs):
        dtype = v.type.tensor_type.elem_type
        if dtype != onnx.TensorProto.FLOAT:
            known = dtype in onnx.TensorProto.DataType.values()
            found = onnx.TensorProto.DataType.Name(dtype).lower() if known else f"type {dtype}"
            raise _fail(path, f"{v.name}: expected float32, found {found}")
        dims = _dims(v)
        if len(dims) != 2 or (widths[v.name] is not None and dims[1] != widths[v.name]):
            raise _fail(path, f"{v.name}: expected shape [batch, {widths[v.name]}], found {_short(dims, 80)[1:-1]}")


# --- the graph is the declared architecture ----------------------------------------------------

_ATTRIBUTE_DEFAULTS = {
    # ONNX operator specs (onnx/docs/Operators.md): the attributes each op we use may carry, and
    # their defaults; any other attribute is refused
    "Gemm": {"alpha": 1.0, "beta": 1.0, "transA": 0, "transB": 0},
    "Split": {"axis": 0, "num_outputs": None},
    "Elu": {"alpha": 1.0},
}
_GEMM = {"alpha": 1.0, "beta": 1.0, "transA": 0, "transB": 1}  # y = x·Wᵀ + b, torch's nn.Linear


@dataclass(frozen=True)
class _Ref:
    """What one node input must be: a graph input, an earlier node's output, an initializer the
    architecture names (with its shape), a scalar float32 constant, or absent (an optional input)."""

    kind: str
    name: str = ""
    node: int = -1
    output: int = 0
    shape: tuple = ()
    value: float = 0.0

    def describe(self, ops: list[str]) -> str:
        if self.kind == "input":
            return f"graph input {self.name!r}"
        if self.kind == "node":
            return f"output {self.output} of node {self.node} ({ops[self.node]})"
        if self.kind == "weight":
            return f"initializer {_short(self.name, 40)} {list(self.shape)}"
        if self.kind == "const":
            return f"the constant {self.value:.9g}"
        return "no input"


@dataclass(frozen=True)
class _Node:
    op: str
    inputs: tuple[_Ref, ...]
    outputs: tuple[str | None, ...]
    """Graph output names this node must produce (None: an intermediate value)."""
    attributes: dict


class _Template:
    """The node sequence `export.onnx_export` writes for an architecture (see `_expected_graph`)."""

    def __init__(self) -> None:
        self.nodes: list[_Node] = []

    def add(self, op: str, *inputs: _Ref, outputs=(None,), **attributes) -> list[_Ref]:
        self.nodes.append(_Node(op, inputs, tuple(outputs), attributes))
        k = len(self.nodes) - 1
        return [_Ref("node", node=k, output=j) for j in range(len(outputs))]

    def describe(self, k: int) -> str:
        node = self.nodes[k]
        ops = [n.op for n in self.nodes]
        return f"{node.op}({', '.join(r.describe(ops) for r in node.inputs)})"


def _const(value: float) -> _Ref:
    return _Ref("const", value=float(np.float32(value)))


def _expected_graph(path, info: ModelInfo, arrays: dict[str, np.ndarray]) -> _Template:
    """The graph the architecture metadata declares, built from what `export.onnx_export` writes:
    `_Deployable._normalized` (Sub, Mul, Clip), the LSTM cell of `DeployableRecurrentPolicy.forward`
    (two Gemm, Add, Split into i, f, g, o, then the gate arithmetic in torch's order), each
    nn.Linear as Gemm(x, W, b) with transB = 1 (no bias input when the exporter dropped an all-zero
    bias) and its activation, then `_Deployable._command` (Clip, Add 1, Sqrt, Mul u_hover, Clip) or,
    for a tanh head, `DeployablePolicy.forward`'s 2u²·p/(p + q) form. The widths come from the
    initializers' shapes, which must chain from obs_dim to 4."""
    arch = info.architecture
    t = _Template()

    def weight(name: str, shape: tuple[int, ...], what: str) -> _Ref:
        if name not in arrays:
            raise _fail(path, f"architecture names {what} {_short(name)}, which is not an initializer of the graph")
        if arrays[name].shape != shape:
            raise _fail(
                path,
                f"initializer {_short(name)} ({what}) has shape {list(arrays[name].shape)}, "
                f"the declared architecture needs {list(shape)}",
            )
        return _Ref("weight", name=name, shape=shape)

    def gemm(x: _Ref, w: str, b: str | None, rows: int, cols: int, what: str, outputs=(None,)) -> _Ref:
        refs = [x, weight(w, (rows, cols), f"{what} weight")]
        if b is not None:
            refs.append(weight(b, (rows,), f"{what} bias"))
        return t.add("Gemm", *refs, outputs=outputs, **_GEMM)[0]

    d = info.obs_dim
    x = _Ref("input", name="obs")
    norm = arch["normalize"]
    if norm is not None:
        x = t.add("Sub", x, weight(norm["mean"], (d,), "normalize mean"))[0]
        x = t.add("Mul", x, weight(norm["inv_std"], (d,), "normalize inv_std"))[0]
        x = t.add("Clip", x, _const(-norm["clip"]), _const(norm["clip"]))[0]
    if info.recurrent:
        spec, hsz = arch["lstm"], arch["hidden"]
        a = gemm(x, spec["weight_ih"], spec["bias_ih"], 4 * hsz, d, "lstm input")
        b = gemm(_Ref("input", name="h_in"), spec["weight_hh"], spec["bias_hh"], 4 * hsz, hsz, "lstm recurrent")
        gates = t.add("Add", a, b)[0]
        i, f, g, o = t.add("Split", gates, outputs=(None,) * 4, axis=1, num_outputs=4)
        forget = t.add("Mul", t.add("Sigmoid", f)[0], _Ref("input", name="c_in"))[0]
        update = t.add("Mul", t.add("Sigmoid", i)[0], t.add("Tanh", g)[0])[0]
        c = t.add("Add", forget, update, outputs=("c_out",))[0]
        out_gate = t.add("Sigmoid", o)[0]
        x = t.add("Mul", out_gate, t.add("Tanh", c)[0], outputs=("h_out",))[0]
        d = hsz
    layers = arch["layers"]
    for k, layer in enumerate(layers):
        w = layer["weight"]
        if w not in arrays:
            raise _fail(
                path, f"architecture names layer {k} weight {_short(w)}, which is not an initializer of the graph"
            )
        shape = arrays[w].shape
        rows = shape[0] if len(shape) == 2 else -1
        last = k == len(layers) - 1
        if rows < 1 or (last and rows != NUM_MOTORS):
            want = f"[{NUM_MOTORS}, {d}]" if last else f"[width, {d}]"
            raise _fail(path, f"initializer {_short(w)} (layer {k} weight) has shape {list(shape)}, expected {want}")
        x = gemm(x, w, layer["bias"], rows, d, f"layer {k}")
        act = layer["activation"]
        if act == "tanh" and not last:
            x = t.add("Tanh", x)[0]
        elif act == "relu":
            x = t.add("Relu", x)[0]
        elif act == "elu":
            x = t.add("Elu", x, alpha=1.0)[0]
        d = rows
    u, (c_lo, c_hi) = arch["u_hover"], arch["command_clip"]
    if layers[-1]["activation"] == "tanh":  # u²·(1 + tanh z) = 2u²·p/(p + q), p = e^(2·min(z, 0)), q = e^(−2·max(z, 0))
        z = x
        p = t.add("Exp", t.add("Mul", t.add("Clip", z, _Ref("absent"), _const(0.0))[0], _const(2.0))[0])[0]
        q = t.add("Exp", t.add("Mul", t.add("Clip", z, _const(0.0))[0], _const(-2.0))[0])[0]
        two_p = t.add("Mul", p, _const(2.0))[0]
        y = t.add("Div", two_p, t.add("Add", p, q)[0])[0]
    else:
        lo, hi = arch["action_clip"]
        y = t.add("Add", t.add("Clip", x, _const(lo), _const(hi))[0], _const(1.0))[0]
    y = t.add("Mul", t.add("Sqrt", y)[0], _const(u))[0]
    t.add("Clip", y, _const(c_lo), _const(c_hi), outputs=("action",))
    return t


def _check_graph(path, model, info: ModelInfo, arrays: dict[str, np.ndarray]) -> None:
    """Refuse any graph that is not exactly the declared architecture; one line names the first
    difference (see `_expected_graph` for what is expected)."""
    import onnx

    opsets = {o.domain: o.version for o in model.opset_import}
    version = opsets.pop("", opsets.pop("ai.onnx", None))
    if opsets:
        raise _fail(
            path, f"imports operator sets {_short(sorted(opsets))}; a quadpilot policy uses the standard one only"
        )
    if version not in OPSETS:
        raise _fail(path, f"standard operator set {version}: expected {OPSETS.start} to {OPSETS.stop - 1}")
    if len(model.functions) or len(model.training_info):
        raise _fail(path, "defines model-local functions or training graphs; a quadpilot policy has neither")
    graph = model.graph
    if len(graph.sparse_initializer):
        raise _fail(path, "holds sparse initializers; a quadpilot policy's weights are dense float32")
    inputs = {v.name for v in graph.input}
    shadowed = sorted(inputs & set(arrays))
    if shadowed:
        raise _fail(path, f"graph input {_short(shadowed[0])} is also an initializer")
    want = _expected_graph(path, info, arrays)
    kind = info.architecture["kind"]
    ops = [n.op for n in want.nodes]
    produced: dict[str, tuple[int, int]] = {}
    used: set[str] = set()

    def found(name: str) -> str:
        if name == "":
            return "no input"
        if name in produced:
            k, j = produced[name]
            return f"output {j} of node {k} ({graph.node[k].op_type})"
        if name in inputs:
            return f"graph input {_short(name, 40)}"
        if name in arrays:
            a = arrays[name]
            return f"initializer {_short(name, 40)} {list(a.shape)}" + (f" = {float(a):.9g}" if a.shape == () else "")
        return f"the undefined value {_short(name, 40)}"

    def matches(name: str, ref: _Ref) -> bool:
        if ref.kind == "input":
            return name == ref.name
        if ref.kind == "node":
            return produced.get(name) == (ref.node, ref.output)
        if ref.kind == "weight":
            return name == ref.name
        if ref.kind == "const":
            a = arrays.get(name)
            return a is not None and a.shape == () and float(a) == ref.value
        return name == ""

    def differ(k: int, what: str) -> ModelContractError:
        return _fail(path, f"the graph is not the declared {kind} architecture: node {k} {what}")

    for k, expected in enumerate(want.nodes):
        if k >= len(graph.node):
            raise differ(k, f"is missing (expected {want.describe(k)}; the graph ends after {len(graph.node)} nodes)")
        node = graph.node[k]
        got = f"{_short(node.op_type, 30)[1:-1]}({', '.join(found(n) for n in node.input)})"
        if node.domain not in ("", "ai.onnx") or node.op_type != expected.op or len(node.input) != len(expected.inputs):
            raise differ(k, f"is {got}, expected {want.describe(k)}")
        for j, (name, ref) in enumerate(zip(node.input, expected.inputs, strict=True)):
            if not matches(name, ref):
                raise differ(k, f"({expected.op}) input {j} is {found(name)}, expected {ref.describe(ops)}")
            if ref.kind in ("weight", "const"):
                used.add(name)
        attributes = dict(_ATTRIBUTE_DEFAULTS.get(expected.op, {}))
        for a in node.attribute:
            default = attributes.get(a.name, KeyError)
            value = onnx.helper.get_attribute_value(a) if not a.ref_attr_name else KeyError
            kind_ok = a.type == (onnx.AttributeProto.FLOAT if isinstance(default, float) else onnx.AttributeProto.INT)
            if default is KeyError or value is KeyError or not kind_ok:
                raise differ(
                    k, f"({expected.op}) has the attribute {_short(a.name, 30)}, which the architecture does not"
                )
            attributes[a.name] = value
        wanted = dict(_ATTRIBUTE_DEFAULTS.get(expected.op, {})) | expected.attributes
        if attributes != wanted:
            diff = {n: v for n, v in attributes.items() if wanted.get(n) != v}
            raise differ(k, f"({expected.op}) has attributes {diff}, expected { ({n: wanted[n] for n in diff}) }")
        if len(node.output) != len(expected.outputs):
            raise differ(k, f"({expected.op}) has {len(node.output)} outputs, expected {len(expected.outputs)}")
        for j, (name, graph_output) in enumerate(zip(node.output, expected.outputs, strict=True)):
            if graph_output is not None and name != graph_output:
                raise differ(
                    k, f"({expected.op}) output {j} is {_short(name, 40)}, expected the graph output {graph_output!r}"
                )
            if not name or name in produced or name in inputs or name in arrays:
                raise differ(k, f"({expected.op}) output {j} {_short(name, 40)} is empty or already defined")
            produced[name] = (k, j)
    if len(graph.node) > len(want.nodes):
        k = len(want.nodes)
        extra = graph.node[k]
        raise differ(k, f"({_short(extra.op_type, 30)[1:-1]}) is one more than the architecture's {k} nodes")
    unused = [name for name in arrays if name not in used]
    if unused:
        raise _fail(path, f"initializer {_short(unused[0])} is not used by the declared {kind} architecture")
