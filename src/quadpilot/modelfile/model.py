"""Reading a quad-export ONNX file and checking its contract before anything flies it.

Everything in the file is untrusted: its graph and every metadata string (docs/architecture.md,
"Trust boundaries"). The rules this module enforces, in one place, before any backend sees the file:

- Every metadata value is validated where it is read, against what this runtime knows: the schema;
  the observation layout (found by name in `core.observation`, with the same fields); the action
  meaning (the text of the schema, `ACTION_MEANING`); the task (one of `core.mission.TASKS`); the
  source checkpoint's SHA-256 (64 lowercase hex digits); the control period and training steps;
  the vehicle (`VehicleParams` checks its numbers and its rotor layout, four rotors a multirotor can
  fly with; metadata without a rotor list, as every file written before there were lists, is PX4's
  quad-X of its `arm`; its name is a plain identifier, its hover command is the architecture's
  u_hover); the envelope; the architecture (known keys only, finite ordered
  clips, bounded sizes); the golden vectors (finite, bounded count). JSON NaN and Infinity are
  refused. Strings read from the file are never executed and never pasted into generated code:
  `ccode.generate` writes only numbers it formats itself and text from our own tables, and the
  strings it does write are checked here against a fixed set or a strict pattern.
- The graph is exactly the architecture its metadata declares, operator by operator and
  initializer by initializer (`graph.check_graph`), so that ONNX Runtime, which runs the graph, and
  the NumPy and C backends, which compute the architecture from the same initializers
  (`network.network_from_model`), compute the same function.
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
from dataclasses import replace
from pathlib import Path

import numpy as np

from quadpilot.core.dynamics import MOTOR_NAMES
from quadpilot.core.mission import TASKS
from quadpilot.core.observation import ObsLayout, get_layout
from quadpilot.core.params import VehicleParams
from quadpilot.core.px4_raptor import STUDENT_SCHEMA
from quadpilot.core.vehicle_file import NAME_PATTERN, NAME_RULE

from .contract import NUM_MOTORS, ModelContractError, ModelInfo, fail, one_line, quote
from .graph import OPSETS as OPSETS  # re-exported: quad-export reads the operator sets from here
from .graph import check_graph

SCHEMA = "quadpilot.onnx/1"
"""The metadata schema this runtime reads (written by quad-export)."""
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


def _refuse_constant(name: str):
    raise ValueError(f"it holds {name}, which is not a finite number")


def _json(path, props: dict, key: str):
    try:
        # JSON has no NaN or Infinity; Python's json reads them unless told not to
        return json.loads(props[key], parse_constant=_refuse_constant)
    except (ValueError, TypeError, RecursionError) as e:  # JSONDecodeError is a ValueError
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise fail(path, f"metadata {key} is not valid JSON ({first})") from None


def _number(value) -> float | None:
    """`value` as a float if it is a JSON number (not a bool, not a string), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        return float(value)
    except OverflowError:  # an integer beyond float range
        return None


ZIP_MAGIC = b"PK\x03\x04"
"""How a zip archive starts: what torch.save writes (a checkpoint, never a policy file)."""


def _checkpoint_not_policy(path, data: bytes) -> str:
    """What to do with a torch checkpoint given where a policy file is expected. Read for its bytes
    only, never unpickled: torch stores the pickle uncompressed, so the student's schema string
    appears in the file as it is."""
    if STUDENT_SCHEMA.encode() in data:
        return (
            "a px4-raptor checkpoint (quad-train --contract px4-raptor), not a policy file; export it with "
            f"quad-export --format px4-raptor {path} and fly the policy.tar it writes"
        )
    return f"a PyTorch checkpoint, not a policy file; export it with quad-export {path} and fly the .onnx file"


def read_model(path: str | os.PathLike):
    """Parse and check an exported policy file. Returns (onnx.ModelProto, ModelInfo)."""
    import onnx
    from google.protobuf.message import DecodeError

    path = Path(path)
    try:
        if not path.is_file():
            raise fail(path, "no such file (expected an .onnx file written by quad-export)")
        size = path.stat().st_size
        if size == 0:
            raise fail(path, "the file is empty (expected an ONNX model written by quad-export)")
        if size > MAX_FILE_BYTES:
            raise fail(
                path, f"{size / 2**20:.0f} MiB is far larger than any policy file (limit {MAX_FILE_BYTES >> 20} MiB)"
            )
        data = path.read_bytes()
    except OSError as e:  # a name too long, no permission to read, ...
        raise fail(path, f"cannot read it: {e.strerror or e}") from None
    if data.startswith(ZIP_MAGIC):
        raise fail(path, _checkpoint_not_policy(path, data))
    try:
        model = onnx.ModelProto()
        model.ParseFromString(data)
    except (DecodeError, RuntimeError, ValueError) as e:
        reason = f"not an ONNX model: protobuf could not parse it ({e}); truncated, or not a quad-export file?"
        raise fail(path, reason) from None
    if not model.HasField("graph") or not model.graph.node:
        raise fail(path, "parses, but holds no graph (truncated, or not an ONNX model)")
    external = [t.name for t in model.graph.initializer if t.data_location == onnx.TensorProto.EXTERNAL]
    if external:
        raise fail(
            path,
            f"weights stored as external data ({', '.join(quote(n, 40) for n in external[:3])}…); quadpilot models "
            "keep every weight "
            "inside the .onnx file so that the file that was checked is the file that flies",
        )
    try:
        onnx.checker.check_model(model, full_check=True)
    except (onnx.checker.ValidationError, onnx.shape_inference.InferenceError, RuntimeError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise fail(path, f"onnx.checker rejects the model: {one_line(first)}") from None
    except Exception as e:  # the checker is C++ behind pybind: anything else it raises is still a bad file
        raise fail(path, f"onnx.checker cannot check the model ({type(e).__name__})") from None
    props = {}
    for p in model.metadata_props:
        if not isinstance(p.key, str) or not isinstance(p.value, str):  # upb hands back bytes for bad UTF-8
            raise fail(path, f"metadata entry {one_line(repr(p.key), 80)} is not valid UTF-8 text (a corrupted file)")
        props[p.key] = p.value
    info = _read_metadata(path, props)
    _check_io(path, model, info)
    arch = _read_architecture(path, info.architecture)
    _check_hover_command(path, info.vehicle, arch)
    info = replace(info, architecture=arch)
    check_graph(path, model, info, initializer_arrays(model, path))
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
            raise fail(path, f"initializer {quote(t.name)} is {kind}; every weight of a quadpilot policy is float32")
        try:
            a = numpy_helper.to_array(t)
        except Exception as e:  # a tensor whose data does not fill its dims, and the like
            raise fail(path, f"initializer {quote(t.name)} cannot be read ({type(e).__name__})") from None
        if a.dtype != np.float32 or a.shape != tuple(t.dims):
            raise fail(path, f"initializer {quote(t.name)} does not hold float32 data of shape {list(t.dims)}")
        if not np.all(np.isfinite(a)):
            raise fail(path, f"initializer {quote(t.name)} holds non-finite values (NaN or infinity)")
        if t.name in out:
            raise fail(path, f"initializer {quote(t.name)} is defined twice")
        out[t.name] = a
    return out


def _read_metadata(path, props: dict) -> ModelInfo:
    schema = props.get("quadpilot.schema")
    if schema != SCHEMA:
        found = "no quadpilot.schema entry (not written by quad-export)" if schema is None else quote(schema)
        raise fail(path, f"metadata schema: expected {SCHEMA!r}, found {found}")
    missing = [k for k in REQUIRED_KEYS if k not in props]
    if missing:
        raise fail(path, f"metadata lacks {', '.join(missing)} (schema {SCHEMA} requires {', '.join(REQUIRED_KEYS)})")
    layout_json = _json(path, props, "quadpilot.obs_layout")
    try:
        layout = get_layout(layout_json["name"])
    except (ValueError, KeyError, TypeError) as e:
        raise fail(path, f"observation layout: {one_line(e)}") from None
    if layout_json != json.loads(json.dumps(layout.to_json())):
        fields = layout_json.get("fields") if isinstance(layout_json.get("fields"), list) else []
        listed = [(f.get("name"), f.get("size")) if isinstance(f, dict) else f for f in fields]
        raise fail(
            path,
            f"observation layout {layout.name!r}: the file lists fields (name, size) "
            f"{quote(listed, 300)[1:-1]}, "
            f"this runtime's has {[(f.name, f.size) for f in layout.fields]} (units and meanings must match too)",
        )
    if props["quadpilot.action"] != ACTION_MEANING:
        raise fail(
            path, f"metadata quadpilot.action: expected {ACTION_MEANING!r}, found {quote(props['quadpilot.action'])}"
        )
    task = props["quadpilot.task"]
    if task not in TASKS:
        raise fail(path, f"metadata quadpilot.task: expected one of {', '.join(TASKS)}, found {quote(task)}")
    sha = props["quadpilot.source_sha256"]
    if not SHA256_PATTERN.fullmatch(sha):
        raise fail(path, f"metadata quadpilot.source_sha256: expected 64 lowercase hex digits, found {quote(sha)}")
    try:
        period = float(props["quadpilot.control_period_s"])
        steps = int(props["quadpilot.training_steps"])
    except ValueError as e:
        raise fail(path, f"metadata: {quote(e, 120)[1:-1]}") from None
    lo, hi = CONTROL_PERIOD_RANGE_S
    if not (math.isfinite(period) and lo <= period <= hi):
        raise fail(path, f"control period {period} s: expected a finite period in [{lo:g}, {hi:g}] s")
    if not 0 <= steps <= MAX_TRAINING_STEPS:
        raise fail(path, f"training steps {steps}: expected a count >= 0")
    vehicle = _read_vehicle(path, _json(path, props, "quadpilot.vehicle"))
    arch = _json(path, props, "quadpilot.architecture")  # its kind here; the rest after the I/O check
    if not isinstance(arch, dict) or arch.get("kind") not in _ARCH_KEYS:
        kind = arch.get("kind") if isinstance(arch, dict) else arch
        raise fail(path, f"architecture kind: expected 'mlp' or 'lstm', found {quote(kind)}")
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
        raise fail(path, f"vehicle metadata: expected an object of VehicleParams fields, found {quote(vehicle_json)}")
    try:
        vehicle = VehicleParams(**vehicle_json)
    except TypeError as e:
        raise fail(path, f"vehicle metadata does not describe a VehicleParams ({one_line(e)})") from None
    except ValueError as e:  # VehicleParams names the field and what it expected
        raise fail(path, f"vehicle metadata: {one_line(e)}") from None
    if not NAME_PATTERN.fullmatch(vehicle.name):  # a plain name: it is written into generated C
        raise fail(path, f"vehicle name {quote(vehicle.name)}: expected a plain name ({NAME_RULE})")
    return vehicle


def _check_hover_command(path, vehicle: VehicleParams, arch: dict) -> None:
    """The action map's hover command is the vehicle's (export.onnx_export writes both from the
    training configuration's one vehicle, `EnvConfig.params`)."""
    hover = vehicle.hover_command
    if not math.isclose(hover, arch["u_hover"], rel_tol=1e-9):
        raise fail(
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
        raise fail(
            path,
            f"envelope: expected max_distance_m in (0, {MAX_DISTANCE_M:g}] and max_tilt_deg in (0, 90) as finite "
            f"numbers, found {quote(envelope, 120)}",
        )
    return {"max_distance_m": dist, "max_tilt_deg": tilt}


def _read_golden(path, golden, layout: ObsLayout) -> tuple[np.ndarray, np.ndarray]:
    def rows(key: str) -> np.ndarray:
        try:
            a = np.asarray(golden[key])
        except (KeyError, TypeError, ValueError, IndexError) as e:
            raise fail(path, f"golden vectors unreadable ({type(e).__name__}: {quote(e, 80)[1:-1]})") from None
        if a.dtype.kind not in "iuf":  # strings, bools, objects (ragged lists give ValueError above)
            raise fail(path, f"golden vectors: {key} holds {a.dtype} values, expected numbers")
        with np.errstate(over="ignore"):  # beyond float32: infinity, refused below
            return a.astype(np.float32)

    if not isinstance(golden, dict):
        raise fail(path, f"golden vectors: expected an object with obs and action, found {type(golden).__name__}")
    g_obs, g_act = rows("obs"), rows("action")
    if g_obs.ndim != 2 or g_obs.shape[1] != layout.dim or g_act.shape != (g_obs.shape[0], NUM_MOTORS) or not len(g_obs):
        raise fail(
            path,
            f"golden vectors: expected obs (K, {layout.dim}) and action (K, {NUM_MOTORS}), "
            f"found {g_obs.shape} and {g_act.shape}",
        )
    if len(g_obs) > MAX_GOLDEN:
        raise fail(path, f"golden vectors: {len(g_obs)} of them, expected at most {MAX_GOLDEN}")
    for key, a in (("obs", g_obs), ("action", g_act)):
        bad = ~np.isfinite(a)
        if bad.any():  # NaN would make any comparison pass or fail by accident; ±Inf proves nothing
            k = int(np.argwhere(bad)[0][0])
            raise fail(path, f"golden vectors: {key} {k} holds non-finite values (as float32); expected finite numbers")
    return g_obs, g_act


_ARCH_KEYS = {
    "mlp": {"kind", "normalize", "action_clip", "u_hover", "command_clip", "layers"},
    "lstm": {"kind", "hidden", "normalize", "action_clip", "u_hover", "command_clip", "lstm", "layers"},
}


def _read_architecture(path, arch) -> dict:
    """The architecture metadata checked and normalised (numbers as floats); names are checked
    against the graph by `graph.check_graph`."""

    def bad(what: str) -> ModelContractError:
        return fail(path, f"architecture: {what}")

    def name(value, what: str, optional: bool = False) -> str | None:
        if value is None and optional:
            return None
        if not isinstance(value, str) or not value or len(value) > 256:
            raise bad(f"{what}: expected an initializer name, found {quote(value)}")
        return value

    def pair(value, what: str, lo: float, hi: float) -> list[float]:
        nums = [_number(v) for v in value] if isinstance(value, list) and len(value) == 2 else [None]
        if None in nums or not (lo <= nums[0] < nums[1] <= hi):
            raise bad(f"{what}: expected [low, high] with {lo:g} <= low < high <= {hi:g}, found {quote(value)}")
        return nums

    kind = arch["kind"]  # checked by _read_metadata
    unknown = sorted(set(arch) - _ARCH_KEYS[kind])
    missing = sorted(_ARCH_KEYS[kind] - set(arch))
    if unknown or missing:
        extra = ", ".join(quote(k, 30) for k in unknown[:5]) or "none"
        raise bad(f"{kind} expects keys {sorted(_ARCH_KEYS[kind])}; unknown {extra}, missing {missing or 'none'}")
    out: dict = {"kind": kind}
    if kind == "lstm":
        hidden = arch["hidden"]
        if isinstance(hidden, bool) or not isinstance(hidden, int) or not 1 <= hidden <= MAX_HIDDEN:
            raise bad(f"hidden: expected an integer in [1, {MAX_HIDDEN}], found {quote(hidden)}")
        out["hidden"] = hidden
    norm = arch["normalize"]
    if norm is None:
        out["normalize"] = None
    else:
        clip = _number(norm.get("clip")) if isinstance(norm, dict) else None
        if not isinstance(norm, dict) or set(norm) != {"mean", "inv_std", "clip"} or clip is None:
            raise bad(f"normalize: expected null or {{mean, inv_std, clip}}, found {quote(norm)}")
        if not 0.0 < clip <= MAX_OBS_CLIP:
            raise bad(f"normalize clip {clip!r}: expected a finite number in (0, {MAX_OBS_CLIP:g}]")
        out["normalize"] = {"mean": name(norm["mean"], "normalize mean"), "inv_std": name(norm["inv_std"], "inv_std")}
        out["normalize"]["clip"] = clip
    out["action_clip"] = pair(arch["action_clip"], "action_clip", -1.0, 1.0)  # √(1 + a) needs a >= -1
    u_hover = _number(arch["u_hover"])
    if u_hover is None or not 0.0 < u_hover <= 1.0:
        raise bad(f"u_hover: expected a number in (0, 1], found {quote(arch['u_hover'])}")
    out["u_hover"] = u_hover
    out["command_clip"] = pair(arch["command_clip"], "command_clip", 0.0, 1.0)
    if kind == "lstm":
        spec = arch["lstm"]
        keys = {"weight_ih", "weight_hh", "bias_ih", "bias_hh"}
        if not isinstance(spec, dict) or set(spec) != keys:
            raise bad(f"lstm: expected {{{', '.join(sorted(keys))}}}, found {quote(spec)}")
        out["lstm"] = {k: name(spec[k], f"lstm {k}", optional=k.startswith("bias")) for k in sorted(keys)}
    layers = arch["layers"]
    if not isinstance(layers, list) or not 1 <= len(layers) <= MAX_LAYERS:
        raise bad(f"layers: expected a list of 1 to {MAX_LAYERS} layers, found {quote(layers)}")
    out["layers"] = []
    for k, layer in enumerate(layers):
        if not isinstance(layer, dict) or set(layer) != {"weight", "bias", "activation"}:
            raise bad(f"layer {k}: expected {{weight, bias, activation}}, found {quote(layer)}")
        act = layer["activation"]
        last = k == len(layers) - 1
        allowed = (None, "tanh") if last else (None, *ACTIVATIONS)
        if act not in allowed:
            raise bad(f"layer {k} activation: expected one of {list(allowed)}, found {quote(act)}")
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
    shown = ", ".join(quote(n, 40) for n in names[:limit])
    return f"[{shown}{', ...' if len(names) > limit else ''}]"


def _check_io(path, model, info: ModelInfo) -> None:
    import onnx

    # every graph input counts: an initializer listed as an input is one a caller could override
    inputs, outputs = list(model.graph.input), list(model.graph.output)
    want_in, want_out = info.input_names(), info.output_names()
    got_in, got_out = tuple(i.name for i in inputs), tuple(o.name for o in outputs)
    if got_in != want_in or got_out != want_out:
        want = f"{list(want_in)} → {list(want_out)}"
        raise fail(path, f"graph inputs/outputs: expected {want}, found {_names(inputs)} → {_names(outputs)}")
    h = info.architecture.get("hidden")
    h = h if isinstance(h, int) and not isinstance(h, bool) and 1 <= h <= MAX_HIDDEN else None  # else refused next
    widths = {"obs": info.obs_dim, "action": NUM_MOTORS, "h_in": h, "c_in": h, "h_out": h, "c_out": h}
    for v in (*inputs, *outputs):
        dtype = v.type.tensor_type.elem_type
        if dtype != onnx.TensorProto.FLOAT:
            known = dtype in onnx.TensorProto.DataType.values()
            found = onnx.TensorProto.DataType.Name(dtype).lower() if known else f"type {dtype}"
            raise fail(path, f"{v.name}: expected float32, found {found}")
        dims = _dims(v)
        if len(dims) != 2 or (widths[v.name] is not None and dims[1] != widths[v.name]):
            raise fail(path, f"{v.name}: expected shape [batch, {widths[v.name]}], found {quote(dims, 80)[1:-1]}")
