"""Reading a quad-export ONNX file and checking its contract before anything flies it.

A file is accepted only if every check passes, in this order: it exists and parses as an ONNX
model; its weights are inside the file (no external data); `onnx.checker` (full check) passes;
the metadata names the schema this runtime speaks, an observation layout `core` knows with the
same fields, a control period, a vehicle, a flight envelope and a network architecture; the
graph's inputs and outputs have the names, dtypes and shapes that architecture implies. The
backends then replay the golden vectors stored in the file (`backends.load_policy`). Each failure
is a `ModelContractError` that says what was expected and what was found.

Uses the `onnx` package to parse the file (protobuf), never torch.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

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


class ModelContractError(ValueError):
    """The file is not a policy this runtime may fly; the message says why."""


@dataclass(frozen=True)
class ModelInfo:
    """What the file's metadata says about the policy inside it."""

    path: str
    layout: ObsLayout
    task: str
    control_period_s: float
    vehicle: VehicleParams
    training_steps: int
    source_sha256: str
    action_meaning: str
    architecture: dict
    """kind (mlp or lstm), layers and their initializer names, normalisation, action mapping."""
    envelope: dict
    """max_distance_m and max_tilt_deg: the states the policy was trained in (beyond them it
    never learned to act; training episodes ended there)."""
    golden_obs: np.ndarray
    """(K, obs_dim) float32, a sequence from zero recurrent state."""
    golden_action: np.ndarray
    """(K, 4) float32, what the exporting torch module answered."""

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


def _json(path, props: dict, key: str):
    try:
        return json.loads(props[key])
    except (json.JSONDecodeError, TypeError) as e:
        raise _fail(path, f"metadata {key} is not valid JSON ({e})") from None


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
            f"weights stored as external data ({', '.join(external[:3])}…); quadpilot models keep every weight "
            "inside the .onnx file so that the file that was checked is the file that flies",
        )
    try:
        onnx.checker.check_model(model, full_check=True)
    except (onnx.checker.ValidationError, onnx.shape_inference.InferenceError, RuntimeError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise _fail(path, f"onnx.checker rejects the model: {first}") from None
    props = {}
    for p in model.metadata_props:
        if not isinstance(p.key, str) or not isinstance(p.value, str):  # upb hands back bytes for bad UTF-8
            raise _fail(path, f"metadata entry {p.key!r} is not valid UTF-8 text (a corrupted file)")
        props[p.key] = p.value
    info = _read_metadata(path, props)
    _check_io(path, model, info)
    return model, info


def _read_metadata(path, props: dict) -> ModelInfo:
    schema = props.get("quadpilot.schema")
    if schema != SCHEMA:
        found = "no quadpilot.schema entry (not written by quad-export)" if schema is None else repr(schema)
        raise _fail(path, f"metadata schema: expected {SCHEMA!r}, found {found}")
    missing = [k for k in REQUIRED_KEYS if k not in props]
    if missing:
        raise _fail(path, f"metadata lacks {', '.join(missing)} (schema {SCHEMA} requires {', '.join(REQUIRED_KEYS)})")
    layout_json = _json(path, props, "quadpilot.obs_layout")
    try:
        layout = get_layout(layout_json["name"])
    except (ValueError, KeyError, TypeError) as e:
        raise _fail(path, f"observation layout: {e}") from None
    if layout_json != json.loads(json.dumps(layout.to_json())):
        raise _fail(
            path,
            f"observation layout {layout.name!r}: the file lists fields (name, size) "
            f"{[(f.get('name'), f.get('size')) for f in layout_json.get('fields', [])]}, "
            f"this runtime's has {[(f.name, f.size) for f in layout.fields]} (units and meanings must match too)",
        )
    try:
        period = float(props["quadpilot.control_period_s"])
        steps = int(props["quadpilot.training_steps"])
    except ValueError as e:
        raise _fail(path, f"metadata: {e}") from None
    if not (math.isfinite(period) and 0.0 < period <= 1.0):
        raise _fail(path, f"control period {period} s: expected a finite period in (0, 1] s")
    vehicle_json = _json(path, props, "quadpilot.vehicle")
    try:
        vehicle = VehicleParams(**vehicle_json)
    except TypeError as e:
        raise _fail(path, f"vehicle metadata does not describe a VehicleParams ({e})") from None
    arch = _json(path, props, "quadpilot.architecture")
    if not isinstance(arch, dict) or arch.get("kind") not in ("mlp", "lstm"):
        kind = arch.get("kind") if isinstance(arch, dict) else arch
        raise _fail(path, f"architecture kind: expected 'mlp' or 'lstm', found {kind!r}")
    envelope = _json(path, props, "quadpilot.envelope")
    try:
        dist, tilt = float(envelope["max_distance_m"]), float(envelope["max_tilt_deg"])
        ok = 0.0 < dist < math.inf and 0.0 < tilt < 90.0
    except (KeyError, TypeError, ValueError):
        ok = False
    if not ok:
        raise _fail(
            path, f"envelope: expected max_distance_m > 0 and max_tilt_deg in (0, 90) as numbers, found {envelope!r}"
        )
    golden = _json(path, props, "quadpilot.golden")
    try:
        g_obs = np.asarray(golden["obs"], np.float32)
        g_act = np.asarray(golden["action"], np.float32)
    except (KeyError, TypeError, ValueError) as e:
        raise _fail(path, f"golden vectors unreadable ({e})") from None
    if g_obs.ndim != 2 or g_obs.shape[1] != layout.dim or g_act.shape != (g_obs.shape[0], NUM_MOTORS) or not len(g_obs):
        raise _fail(
            path,
            f"golden vectors: expected obs (K, {layout.dim}) and action (K, {NUM_MOTORS}), "
            f"found {g_obs.shape} and {g_act.shape}",
        )
    return ModelInfo(
        path=str(path),
        layout=layout,
        task=props["quadpilot.task"],
        control_period_s=period,
        vehicle=vehicle,
        training_steps=steps,
        source_sha256=props["quadpilot.source_sha256"],
        action_meaning=props["quadpilot.action"],
        architecture=arch,
        envelope=envelope,
        golden_obs=g_obs,
        golden_action=g_act,
    )


def _dims(value_info) -> list:
    dims = value_info.type.tensor_type.shape.dim
    return [d.dim_param or (d.dim_value if d.HasField("dim_value") else "?") for d in dims]


def _check_io(path, model, info: ModelInfo) -> None:
    import onnx

    initializers = {t.name for t in model.graph.initializer}
    inputs = [i for i in model.graph.input if i.name not in initializers]
    want_in, want_out = info.input_names(), info.output_names()
    got_in, got_out = tuple(i.name for i in inputs), tuple(o.name for o in model.graph.output)
    if got_in != want_in or got_out != want_out:
        want = f"{list(want_in)} → {list(want_out)}"
        raise _fail(path, f"graph inputs/outputs: expected {want}, found {list(got_in)} → {list(got_out)}")
    h = info.hidden
    widths = {"obs": info.obs_dim, "action": NUM_MOTORS, "h_in": h, "c_in": h, "h_out": h, "c_out": h}
    for v in (*inputs, *model.graph.output):
        dtype = v.type.tensor_type.elem_type
        if dtype != onnx.TensorProto.FLOAT:
            raise _fail(path, f"{v.name}: expected float32, found {onnx.TensorProto.DataType.Name(dtype).lower()}")
        dims = _dims(v)
        if len(dims) != 2 or dims[1] != widths[v.name]:
            raise _fail(path, f"{v.name}: expected shape [batch, {widths[v.name]}], found {dims}")
