"""A policy file is untrusted input: nothing in it may run code, crash a loader, or make the backends
disagree.

The runtime's rules (modelfile.model, ccode.generate, runtime.backends, runtime.cbackend): metadata
strings never reach generated C; a graph is accepted only if it is exactly the architecture its
metadata declares, so ONNX Runtime, NumPy and C fly one function; every metadata value is checked
where it is read; golden vectors are finite and a NaN in their replay is a mismatch; whatever ONNX
Runtime raises at load is a ModelContractError; a compiled library in the cache is loaded only
from a private directory and only if its bytes are the ones recorded at build time; an observation
that is not an array of real numbers of the right shape is an ObservationShapeError.

Property tests (Hypothesis, derandomised) apply arbitrary metadata and graph edits to copies of the
shipped hover (MLP) and hover_lstm (LSTM) files: each edited file is refused by every backend with a
ModelContractError, or accepted by every backend and flown identically (within 1e-5) by all three.
Then one regression test per attack that worked before.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import os
import subprocess
import traceback
from pathlib import Path

import numpy as np
import onnx
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from onnx import helper, numpy_helper

from quadpilot.core.params import ParamBatch, VehicleParams
from quadpilot.core.randomization import PRESETS as RANDOMIZATION_PRESETS
from quadpilot.core.randomization import preset as randomization_preset
from quadpilot.core.vehicle_file import CRAZYFLIE, PRESETS, SEED_VEHICLE
from quadpilot.modelfile.model import ModelContractError, read_model
from quadpilot.runtime import SafetyMonitor, backends
from quadpilot.runtime.backends import BACKENDS, ObservationShapeError, OnnxRuntimePolicy, load_policy
from quadpilot.runtime.cbackend import LIBRARY_NAME, find_compiler

MODELS = Path(__file__).resolve().parents[2] / "models"
HOVER = MODELS / "hover" / "policy.onnx"
HOVER_LSTM = MODELS / "hover_lstm" / "policy.onnx"
COMPILER = find_compiler()
DIGEST_NAME = LIBRARY_NAME + ".sha256"
"""Beside a cached library: the SHA-256 of its bytes (cbackend.DIGEST_NAME)."""
HAS_CC = COMPILER is not None
LIVE_BACKENDS = tuple(b for b in BACKENDS if b != "c" or HAS_CC)
BACKEND_PARAMS = [
    pytest.param(b, marks=pytest.mark.skipif(not HAS_CC, reason="the c backend needs a C compiler")) if b == "c" else b
    for b in BACKENDS
]
needs_cc = pytest.mark.skipif(not HAS_CC, reason="the c backend needs a C compiler")
PROPERTY = settings(
    derandomize=True,
    database=None,
    deadline=None,
    max_examples=300,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
AGREEMENT = 1e-5


@pytest.fixture(scope="module", autouse=True)
def private_cache(tmp_path_factory):
    """One C build cache for this module (each distinct generated source compiles once), not the
    user's."""
    root = tmp_path_factory.mktemp("c_cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("QUADPILOT_CACHE_DIR", str(root / "cache"))
        yield root / "cache"


# --- helpers ------------------------------------------------------------------------------------


def load(path: Path = HOVER) -> onnx.ModelProto:
    return onnx.load(str(path))


def save(model: onnx.ModelProto, directory: Path, name: str = "policy.onnx") -> Path:
    path = directory / name
    path.write_bytes(model.SerializeToString())
    return path


def get_meta(model: onnx.ModelProto, key: str) -> str:
    return next(p.value for p in model.metadata_props if p.key == key)


def set_meta(model: onnx.ModelProto, key: str, value: str) -> None:
    for p in model.metadata_props:
        if p.key == key:
            p.value = value
            return
    raise KeyError(key)


def edit_json_meta(model: onnx.ModelProto, key: str, edit) -> None:
    value = json.loads(get_meta(model, key))
    edit(value)
    set_meta(model, key, json.dumps(value))


def one_line_refusal(path: Path, backend: str, match: str | None = None) -> str:
    """load_policy refuses with a ModelContractError (a ValueError): one line, naming the file, no
    chained exception from onnx / onnxruntime / protobuf."""
    with pytest.raises(ModelContractError, match=match) as excinfo:
        load_policy(path, backend)
    err = excinfo.value
    message = str(err)
    assert isinstance(err, ValueError) and "\n" not in message and str(path) in message, message
    shown = "".join(traceback.format_exception(type(err), err, err.__traceback__))
    assert "During handling" not in shown and "direct cause" not in shown, shown
    return message


def c_constructor(marker: Path, name: str = "qp_pwn") -> str:
    """C that, once in a loaded library, writes `marker` before any function of it is called."""
    return (
        "#include <stdio.h>\n"
        f"__attribute__((constructor)) static void {name}(void) "
        f'{{ FILE *f = fopen("{marker}", "w"); if (f) fclose(f); }}\n'
    )


# --- the shipped files and the exporter's variants are accepted ---------------------------------


# (a folder with a policy.tar holds a policy of PX4 mc_raptor's contract: its policy.onnx is the bare GRU step,
# held to the file mc_raptor loads by tests/px4/test_trained_policy_tar.py)
@pytest.mark.parametrize(
    "folder",
    sorted(p.name for p in MODELS.iterdir() if (p / "policy.onnx").is_file() and not (p / "policy.tar").is_file()),
)
def test_every_shipped_model_is_exactly_its_declared_architecture(folder):
    _, info = read_model(MODELS / folder / "policy.onnx")
    assert info.architecture["kind"] in ("mlp", "lstm")
    for backend in LIVE_BACKENDS:
        assert load_policy(MODELS / folder / "policy.onnx", backend).verify_golden() <= 1e-5


@pytest.fixture(scope="module")
def exported_elu_mlp(tmp_path_factory):
    """A quad-export file of an architecture the shipped ones do not show (one export, a few
    seconds): a normalised three-layer elu MLP, untrained, so the exporter drops its all-zero
    biases. (The SAC tanh head: tests/train/test_sac.py; an untrained LSTM: tests/export.)"""
    pytest.importorskip("torch")
    from quadpilot.export.onnx_export import export_onnx
    from quadpilot.train.envs import make_config
    from quadpilot.train.ppo import PPOConfig
    from quadpilot.train.ppo.checkpoint import save_untrained_policy

    d = tmp_path_factory.mktemp("variant")
    cfg = PPOConfig(activation="elu", actor_hidden=(32, 32, 16), normalize_obs=True)
    export_onnx(save_untrained_policy(d / "elu.pt", cfg, make_config("hover")), d / "elu.onnx")
    return d / "elu.onnx"


def test_a_normalised_elu_mlp_without_biases_is_accepted_by_every_backend(exported_elu_mlp):
    policies = {b: load_policy(exported_elu_mlp, b) for b in LIVE_BACKENDS}
    assert_same_flight(policies, np.random.default_rng(0))


# --- property tests ----------------------------------------------------------------------------


def assert_same_flight(policies: dict, rng: np.random.Generator, steps: int = 4) -> None:
    """Every backend gives ONNX Runtime's commands (within 1e-5) on a few random observations,
    as a sequence from zero state for a recurrent policy."""
    ref = policies["onnxruntime"]
    obs = rng.normal(0.0, 0.5, (steps, ref.obs_dim)).astype(np.float32)
    ref.reset()
    want = np.stack([ref.act(o) for o in obs])
    assert np.all(np.isfinite(want))
    for name, p in policies.items():
        p.reset()
        got = np.stack([p.act(o) for o in obs])
        assert np.max(np.abs(got - want)) <= AGREEMENT, (name, got, want)


def refused_or_same_flight(model: onnx.ModelProto, directory: Path, seed: int) -> str:
    """Load the edited file with every backend: all refuse with ModelContractError, or all accept
    and fly alike. Any other exception escapes (and fails the property)."""
    try:
        data = model.SerializeToString()
    except Exception:  # the edit made a message protobuf cannot write: no file, nothing to load
        return "unwritable"
    path = directory / "edited.onnx"
    path.write_bytes(data)
    outcome = {}
    for backend in LIVE_BACKENDS:
        try:
            outcome[backend] = load_policy(path, backend)
        except ModelContractError as e:
            assert "\n" not in str(e), str(e)
            outcome[backend] = None
    refused = [b for b, p in outcome.items() if p is None]
    if refused:
        assert len(refused) == len(outcome), f"refused by {refused} only: three backends, two behaviours"
        return "refused"
    assert_same_flight(outcome, np.random.default_rng(seed))
    monitor = SafetyMonitor(outcome["numpy"])  # what quad-sitl builds from the file's vehicle and envelope
    for obs in (outcome["numpy"].info.golden_obs[0], np.full(outcome["numpy"].obs_dim, 9.0, np.float32)):
        motors = monitor.act(obs)
        assert motors.shape == (4,) and np.all((motors >= 0.0) & (motors <= 1.0))
    return "accepted"


JSON_LEAF = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**20), 10**20),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -1.0, 1.0, 0.5, 1e-9, 1e39, 64, 4, 18, 10**400, -(10**400)]),
    st.text(max_size=20),
    st.sampled_from(["tanh", "relu", "elu", "sigmoid", "mlp", "lstm", "actor.0.weight", "head.bias", "val_4"]),
    st.lists(st.floats(-2, 2), max_size=5),
)


def _json_paths(value, prefix=()):
    """Every (path) to a node of a JSON value, the root included."""
    yield prefix
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _json_paths(v, (*prefix, k))
    elif isinstance(value, list) and len(value) <= 32:
        for i, v in enumerate(value):
            yield from _json_paths(v, (*prefix, i))


def _json_edit(data, value):
    """Replace, delete or add at a path of a JSON value (drawn from `data`)."""
    paths = list(_json_paths(value))
    path = data.draw(st.sampled_from(paths), label="json path")
    action = data.draw(st.sampled_from(["replace", "delete", "add", "nudge"]), label="json action")
    if not path:
        return data.draw(JSON_LEAF, label="new root")
    parent = value
    for p in path[:-1]:
        parent = parent[p]
    last = path[-1]
    if action == "delete":
        del parent[last]
    elif action == "add" and isinstance(parent, dict):
        parent[data.draw(st.text(max_size=12), label="new key")] = data.draw(JSON_LEAF, label="new value")
    elif action == "nudge" and isinstance(parent[last], float):
        parent[last] = parent[last] * (1.0 + data.draw(st.sampled_from([1e-9, 1e-6, 1e-3, -0.5]), label="nudge"))
    else:
        parent[last] = data.draw(JSON_LEAF, label="new value")
    return value


def edit_metadata(model: onnx.ModelProto, data) -> None:
    keys = [p.key for p in model.metadata_props]
    key = data.draw(st.sampled_from([*keys, "quadpilot.extra"]), label="metadata key")
    if key == "quadpilot.extra":
        entry = model.metadata_props.add()
        entry.key, entry.value = key, data.draw(st.text(max_size=30), label="extra value")
        return
    old = get_meta(model, key)
    try:
        value = json.loads(old)
    except json.JSONDecodeError:
        value = None
    if isinstance(value, (dict, list)) and data.draw(st.booleans(), label="structured edit"):
        new = json.dumps(_json_edit(data, value))
    else:
        new = data.draw(
            st.one_of(
                st.text(max_size=40),
                st.sampled_from(
                    ["", "nan", "inf", "-1", "0", "1e-5", "2", "waypoint", "circle", "0" * 64, old.upper()]
                ),
                st.just(old + " "),
            ),
            label="metadata value",
        )
    if data.draw(st.booleans(), label="delete key") and data.draw(st.booleans(), label="really"):
        keep = [p for p in model.metadata_props if p.key != key]
        del model.metadata_props[:]
        model.metadata_props.extend(keep)
    else:
        set_meta(model, key, new)


UNARY = ["Identity", "Neg", "Abs", "Relu", "Tanh", "Sigmoid", "Exp", "Sqrt", "Elu", "Softsign"]
BINARY = ["Add", "Sub", "Mul", "Div", "Max", "Min"]


def _value_names(model: onnx.ModelProto) -> list[str]:
    names = [i.name for i in model.graph.input] + [t.name for t in model.graph.initializer]
    return names + [o for n in model.graph.node for o in n.output]


def edit_graph(model: onnx.ModelProto, data) -> None:
    g = model.graph
    kind = data.draw(
        st.sampled_from(
            [
                "remove",
                "duplicate",
                "swap",
                "op",
                "insert",
                "rewire",
                "value",
                "tiny_value",
                "shape",
                "dtype",
                "attribute",
                "scalar",
                "extra_initializer",
            ]
        ),
        label="graph edit",
    )
    event(f"graph edit: {kind}")
    nodes = list(g.node)
    k = data.draw(st.integers(0, len(nodes) - 1), label="node")
    inits = list(g.initializer)
    t_index = data.draw(st.integers(0, len(inits) - 1), label="initializer")
    if kind == "remove":
        del g.node[k]
    elif kind == "duplicate":
        g.node.insert(k, copy.deepcopy(nodes[k]))
    elif kind == "swap" and k + 1 < len(nodes):
        a, b = copy.deepcopy(nodes[k]), copy.deepcopy(nodes[k + 1])
        g.node[k].CopyFrom(b)
        g.node[k + 1].CopyFrom(a)
    elif kind == "op":
        g.node[k].op_type = data.draw(st.sampled_from(UNARY + BINARY + ["Gemm", "Clip", "MatMul"]), label="op")
    elif kind == "insert":
        # a unary node reading node k's first output; the other nodes read the planted node instead
        out = nodes[k].output[0]
        new = f"{out}_planted"
        op = data.draw(st.sampled_from(UNARY), label="planted op")
        for n in g.node:
            for i, name in enumerate(n.input):
                if name == out:
                    n.input[i] = new
        g.node.insert(k + 1, helper.make_node(op, [out], [new]))
    elif kind == "rewire" and nodes[k].input:
        i = data.draw(st.integers(0, len(nodes[k].input) - 1), label="input")
        g.node[k].input[i] = data.draw(st.sampled_from([*_value_names(model), ""]), label="rewired to")
    elif kind in ("value", "tiny_value"):
        t = inits[t_index]
        a = numpy_helper.to_array(t).copy()
        if a.size:
            j = data.draw(st.integers(0, a.size - 1), label="element")
            flat = a.reshape(-1)
            if kind == "tiny_value":  # one ulp: the golden vectors cannot tell, the backends must agree
                flat[j] = np.nextafter(flat[j], np.float32(np.inf))
            else:
                flat[j] = data.draw(st.floats(width=32, allow_nan=True, allow_infinity=True), label="value")
            t.CopyFrom(numpy_helper.from_array(a, t.name))
    elif kind == "shape":
        t = inits[t_index]
        a = numpy_helper.to_array(t)
        shape = data.draw(st.sampled_from([(), (1,), (a.size,), (4, 64), (64, 4), (64, 18), (256,), (2, 2)]))
        new = np.resize(a, shape).astype(np.float32)
        t.CopyFrom(numpy_helper.from_array(new, t.name))
    elif kind == "dtype":
        t = inits[t_index]
        dtype = data.draw(st.sampled_from([np.float64, np.float16, np.int32, np.int64]), label="dtype")
        t.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(t).astype(dtype), t.name))
    elif kind == "attribute":
        name = data.draw(st.sampled_from(["alpha", "beta", "transA", "transB", "axis", "num_outputs", "extra"]))
        value = data.draw(st.sampled_from([0, 1, 2, -1, 0.5, 1.0, 2.0]), label="attribute value")
        keep = [a for a in nodes[k].attribute if a.name != name]
        del g.node[k].attribute[:]
        g.node[k].attribute.extend([*keep, helper.make_attribute(name, value)])
    elif kind == "scalar":  # the constants of the command map (clips, 1, u_hover)
        scalars = [t for t in inits if not t.dims]
        t = data.draw(st.sampled_from(scalars), label="scalar")
        value = data.draw(st.sampled_from([0.0, 1.0, -1.0, 0.5, 2.0, 0.6768467]), label="scalar value")
        t.CopyFrom(numpy_helper.from_array(np.array(value, np.float32), t.name))
    elif kind == "extra_initializer":
        g.initializer.append(numpy_helper.from_array(np.ones(3, np.float32), "planted"))


def _property(base: Path, data, workdir: Path) -> None:
    model = onnx.ModelProto()
    model.CopyFrom(BASES[base])
    for _ in range(data.draw(st.integers(1, 2), label="edits")):
        if data.draw(st.booleans(), label="metadata or graph"):
            edit_metadata(model, data)
        else:
            edit_graph(model, data)
    event(refused_or_same_flight(model, workdir, data.draw(st.integers(0, 2**16), label="seed")))


BASES = {HOVER: load(HOVER), HOVER_LSTM: load(HOVER_LSTM)}


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("edited")


@PROPERTY
@given(data=st.data())
def test_an_edited_mlp_file_is_refused_or_flown_identically_by_every_backend(workdir, data):
    _property(HOVER, data, workdir)


@PROPERTY
@given(data=st.data())
def test_an_edited_lstm_file_is_refused_or_flown_identically_by_every_backend(workdir, data):
    _property(HOVER_LSTM, data, workdir)


def test_one_ulp_of_weight_change_is_accepted_and_flown_alike(workdir):
    """Not every edit is refused: one the golden vectors cannot see is accepted, and then every
    backend flies the same (edited) weights."""
    model = load()
    t = next(t for t in model.graph.initializer if t.name == "actor.2.weight")
    a = numpy_helper.to_array(t).copy()
    a[3, 5] = np.nextafter(a[3, 5], np.float32(1.0))
    t.CopyFrom(numpy_helper.from_array(a, t.name))
    assert refused_or_same_flight(model, workdir, 0) == "accepted"


# --- metadata strings never reach generated C -------------------------------------------------


def _inject_task(model, marker):
    payload = 'hover"\n' + c_constructor(marker) + '#define QP_INJECTED "'
    set_meta(model, "quadpilot.task", payload)
    return payload


def _inject_sha(model, marker):
    payload = "0" * 64 + '"\n' + c_constructor(marker) + '#define QP_INJECTED "'
    set_meta(model, "quadpilot.source_sha256", payload)
    return payload


def _inject_initializer_name(model, marker):
    """The name ends a C comment by a backslash-newline splice (translation phase 2: `*\\` newline
    `/` is `*/`), which a filter for the text `*/` does not see, and reopens one the same way."""
    payload = "w*\\\n/\n" + c_constructor(marker) + "/\\\n*"
    old = "actor.0.weight"
    next(t for t in model.graph.initializer if t.name == old).name = payload
    for node in model.graph.node:
        for i, name in enumerate(node.input):
            if name == old:
                node.input[i] = payload
    edit_json_meta(model, "quadpilot.architecture", lambda a: a["layers"][0].update(weight=payload))
    return payload


INJECTIONS = {"task": _inject_task, "source-sha256": _inject_sha, "initializer-name": _inject_initializer_name}


@needs_cc
@pytest.mark.parametrize("field", list(INJECTIONS))
def test_metadata_strings_never_reach_generated_c(tmp_path, field):
    """A crafted file whose metadata carries C (a constructor that writes a marker file when the
    compiled library is loaded, before any golden vector is checked): the c backend and quad-export
    --format c must refuse the file, or generate code (the kernel, and the bare-metal harness that
    --target builds around it) that holds none of the text."""
    from quadpilot.ccode.generate import generate, initializers
    from quadpilot.ccode.harness import harness_source
    from quadpilot.export.c_export import c_from_onnx

    marker = tmp_path / "constructor_ran"
    model = load()
    payload = INJECTIONS[field](model, marker)
    path = save(model, tmp_path)
    outputs = []
    try:
        policy = load_policy(path, "c")
        outputs += [policy.code.header, policy.code.source]
    except ModelContractError as e:
        assert "\n" not in str(e)
    assert not marker.exists(), "code from the file ran"
    try:
        exported = c_from_onnx(path, tmp_path / "policy_c")
        outputs += [exported.code.header, exported.code.source]
        outputs += [p.read_text() for p in (exported.header, exported.source)]
    except ModelContractError:
        pass
    try:
        model_checked, info = read_model(path)
        code = generate(info, initializers(model_checked))
        outputs += [code.header, code.source, harness_source(info, code.network), harness_source(info, code.network, 3)]
    except ModelContractError:
        pass
    for text in outputs:
        assert "qp_pwn" not in text and str(marker) not in text and payload not in text
    assert not marker.exists()


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("quadpilot.task", "hover; rm -rf /", r"quadpilot\.task: expected one of hover, waypoint, circle"),
        ("quadpilot.source_sha256", "ABC", r"source_sha256: expected 64 lowercase hex digits"),
        ("quadpilot.action", "anything else", r"quadpilot\.action: expected"),
    ],
)
def test_metadata_strings_are_checked_where_they_are_read(tmp_path, key, value, match):
    model = load()
    set_meta(model, key, value)
    for backend in BACKENDS:  # refused in read_model, before any backend (or compiler) runs
        one_line_refusal(save(model, tmp_path), backend, match)


def test_a_vehicle_name_that_is_not_a_plain_identifier_is_refused(tmp_path):
    model = load()
    edit_json_meta(model, "quadpilot.vehicle", lambda v: v.update(name='seed", "x": "*/'))
    one_line_refusal(save(model, tmp_path), "numpy", r"vehicle name .*expected a plain name")


# --- the graph is the declared architecture ----------------------------------------------------


def _plant_input_clip(model: onnx.ModelProto) -> None:
    """Clip(obs, -50, 50) in front of the network: the golden observations are well inside, so the
    golden vectors still replay on every backend, while ONNX Runtime flies a different function
    from the one the NumPy and C backends compute from the weights."""
    g = model.graph
    g.initializer.extend(
        [numpy_helper.from_array(np.array(v, np.float32), n) for n, v in (("lo_planted", -50.0), ("hi_planted", 50.0))]
    )
    for node in g.node:
        for i, name in enumerate(node.input):
            if name == "obs":
                node.input[i] = "obs_planted"
    g.node.insert(0, helper.make_node("Clip", ["obs", "lo_planted", "hi_planted"], ["obs_planted"]))
    onnx.checker.check_model(model, full_check=True)  # a valid ONNX model


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_a_graph_with_a_planted_operator_is_refused_before_any_backend_runs(tmp_path, backend):
    model = load()
    _plant_input_clip(model)
    path = save(model, tmp_path)
    message = one_line_refusal(path, backend, r"not the declared mlp architecture: node 0 is Clip\(")
    assert "expected Gemm(graph input 'obs'" in message


def test_a_changed_command_map_constant_is_refused(tmp_path):
    """u_hover lives twice: in the metadata (NumPy, C) and as a graph constant (ONNX Runtime)."""
    model = load()
    for t in model.graph.initializer:
        if not t.dims and abs(float(numpy_helper.to_array(t)) - 0.6768467) < 1e-6:
            t.CopyFrom(numpy_helper.from_array(np.array(0.7, np.float32), t.name))
    one_line_refusal(save(model, tmp_path), "onnxruntime", r"node 8 \(Mul\) input 1 is initializer .* = 0\.69999")


# --- golden vectors ------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_a_nan_in_the_golden_replay_counts_as_a_mismatch(backend):
    """A command that is NaN reproduces nothing; a later finite difference must not hide it."""
    policy = load_policy(HOVER, backend)
    obs = policy.info.golden_obs.copy()
    obs[0] = np.nan  # NaN in gives NaN out on every backend
    policy.info = dataclasses.replace(policy.info, golden_obs=obs)
    assert np.isnan(policy.verify_golden())


@pytest.mark.parametrize("value", ["NaN", "Infinity", "-Infinity", "1e39"])
@pytest.mark.parametrize("key", ["obs", "action"])
def test_non_finite_golden_vectors_are_refused_at_read(tmp_path, key, value):
    model = load()
    golden = get_meta(model, "quadpilot.golden")
    data = json.loads(golden)
    data[key][0][0] = "@@"  # placeholder replaced by raw JSON text (json.dumps writes NaN as NaN)
    set_meta(model, "quadpilot.golden", json.dumps(data).replace('"@@"', value))
    path = save(model, tmp_path)
    for backend in BACKENDS:
        one_line_refusal(path, backend, r"quadpilot\.golden|golden vectors")


# --- every metadata value is checked -------------------------------------------------------------


def _vehicle(**fields):
    return lambda m: edit_json_meta(m, "quadpilot.vehicle", lambda v: v.update(**fields))


def _envelope(**fields):
    return lambda m: edit_json_meta(m, "quadpilot.envelope", lambda v: v.update(**fields))


def _architecture(**fields):
    return lambda m: edit_json_meta(m, "quadpilot.architecture", lambda v: v.update(**fields))


def _raw(key, value):
    return lambda m: set_meta(m, key, value)


BAD_VALUES = {
    "negative-mass": (_vehicle(mass=-0.665), r"vehicle metadata: vehicle 'seed': mass = -0\.665: expected a finite"),
    "zero-k_f": (_vehicle(k_f=0.0), r"k_f = 0\.0: expected a finite number > 0"),
    "nan-arm": (_raw("quadpilot.vehicle", json.dumps(dataclasses.asdict(SEED_VEHICLE)).replace("0.105", "NaN")), "NaN"),
    "inertia-array": (_vehicle(ixx=[0.0023, 0.0023]), r"ixx: expected one number, found a sequence of 2"),
    "mass-as-text": (_vehicle(mass="0.665"), r"mass: expected one number, found str"),
    "mass-beyond-float": (_vehicle(mass=10**400), r"mass = inf: expected a finite number > 0"),
    "unknown-vehicle-field": (_vehicle(propellers=6), r"does not describe a VehicleParams"),
    "vehicle-not-the-u_hover-one": (_vehicle(mass=0.7), r"hovers at command .* u_hover"),
    "tilt-90": (_envelope(max_tilt_deg=90.0), r"envelope: expected"),
    "distance-infinite": (_raw("quadpilot.envelope", '{"max_distance_m": 1e999, "max_tilt_deg": 60}'), "envelope"),
    "distance-as-text": (_envelope(max_distance_m="5"), r"envelope: expected"),
    "period-nan": (_raw("quadpilot.control_period_s", "nan"), r"control period nan s"),
    "period-tiny": (_raw("quadpilot.control_period_s", "1e-300"), r"control period"),
    "steps-negative": (_raw("quadpilot.training_steps", "-1"), r"training steps -1"),
    "u_hover-above-1": (_architecture(u_hover=1.5), r"u_hover: expected a number in \(0, 1\]"),
    "action-clip-reversed": (_architecture(action_clip=[1.0, -1.0]), r"action_clip: expected \[low, high\]"),
    "command-clip-nan-like": (_architecture(command_clip=[0.0, "x"]), r"command_clip"),
    "too-many-layers": (_architecture(layers=[{"weight": "w", "bias": None, "activation": None}] * 100), "layers"),
    "unknown-architecture-key": (_architecture(dropout=0.5), r"unknown 'dropout'"),
    "hidden-activation-sigmoid": (
        lambda m: edit_json_meta(m, "quadpilot.architecture", lambda a: a["layers"][0].update(activation="sigmoid")),
        r"layer 0 activation",
    ),
}


@pytest.mark.parametrize("case", list(BAD_VALUES))
def test_bad_metadata_values_are_refused_with_one_line(tmp_path, case):
    """Each of these reached quad-sitl before (a negative mass, a NaN limit): it crashed later with
    a traceback, or flew with nonsense limits. Now read_model refuses it, naming the field."""
    edit, match = BAD_VALUES[case]
    model = load()
    edit(model)
    one_line_refusal(save(model, tmp_path), "numpy", match)


def test_an_lstm_hidden_size_beyond_the_bound_is_refused(tmp_path):
    model = load(HOVER_LSTM)
    edit_json_meta(model, "quadpilot.architecture", lambda a: a.update(hidden=10**9))
    one_line_refusal(save(model, tmp_path), "numpy", r"hidden: expected an integer in \[1, 1024\]")


def test_vehicle_params_check_every_field():
    for preset in PRESETS.values():  # the presets, scaled copies and randomised batches still build
        assert VehicleParams(**dataclasses.asdict(preset)) == preset
        preset.scaled(mass=1.3, ixx=0.7, k_f=1.1)
    for name in RANDOMIZATION_PRESETS:
        randomization_preset(name, CRAZYFLIE)
    ParamBatch.from_preset(SEED_VEHICLE, 3)
    for field, value, reason in [
        ("mass", -1.0, r"mass = -1\.0: expected a finite number > 0"),
        ("izz", float("inf"), r"izz = inf"),
        ("motor_tau", -0.01, r"motor_tau = -0\.01: expected a finite number >= 0"),
        ("omega_max", [2000.0], r"omega_max: expected one number, found a sequence of 1"),
        ("drag", np.zeros(2), r"drag: expected one number, found an array of shape \(2,\)"),
        ("gravity", True, r"gravity: expected one number, found bool"),
    ]:
        with pytest.raises(ValueError, match=reason):
            dataclasses.replace(SEED_VEHICLE, **{field: value})


# --- ONNX Runtime's own errors -------------------------------------------------------------------


def _unrunnable_graph(model: onnx.ModelProto) -> None:
    """Reshape obs to [4, -1] and back: ONNX Runtime loads the graph, and fails when it runs (18
    values do not split into 4 rows)."""
    g = model.graph
    g.initializer.extend(
        [
            numpy_helper.from_array(np.array([4, -1], np.int64), "shape_bad"),
            numpy_helper.from_array(np.array([-1, 18], np.int64), "shape_back"),
        ]
    )
    for node in g.node:
        for i, name in enumerate(node.input):
            if name == "obs":
                node.input[i] = "obs_back"
    g.node.insert(0, helper.make_node("Reshape", ["obs_reshaped", "shape_back"], ["obs_back"]))
    g.node.insert(0, helper.make_node("Reshape", ["obs", "shape_bad"], ["obs_reshaped"]))


def test_a_graph_onnxruntime_cannot_run_is_a_contract_error(tmp_path):
    model = load()
    _unrunnable_graph(model)
    one_line_refusal(save(model, tmp_path), "onnxruntime")


def test_onnxruntime_errors_at_load_and_at_the_golden_replay_are_contract_errors():
    """Below the structural check: the session on bytes ONNX Runtime refuses, and the golden replay
    on a graph it loads but cannot run, each give a ModelContractError."""
    _, info = read_model(HOVER)
    with pytest.raises(ModelContractError, match=r"ONNX Runtime cannot load the model"):
        OnnxRuntimePolicy(info, b"\x08\x07not a model")
    model = load()
    _unrunnable_graph(model)
    policy = OnnxRuntimePolicy(info, model.SerializeToString())
    with pytest.raises(ModelContractError, match=r"ONNX Runtime fails on the file's golden vectors") as e:
        backends._replay_golden(policy)
    assert "\n" not in str(e.value)


# --- the C build cache ---------------------------------------------------------------------------


def _planted_library(tmp_path: Path, marker: Path) -> bytes:
    """A shared library exporting the kernel's entry point whose constructor writes `marker`."""
    src = tmp_path / "planted.c"
    src.write_text(
        c_constructor(marker) + "void quadpilot_policy(const float *obs, float *motors) { (void)obs; "
        "motors[0] = motors[1] = motors[2] = motors[3] = 0.5f; }\n"
    )
    out = tmp_path / "planted.so"
    subprocess.run([*COMPILER, "-shared", "-fPIC", "-o", str(out), str(src)], check=True, capture_output=True)
    return out.read_bytes()


def build_hover_library() -> Path:
    """The hover kernel built into the cache but not loaded: glibc's dlopen returns an already
    loaded library of the same path without reading the file again, which would hide a plant."""
    from quadpilot.ccode.generate import generate, initializers
    from quadpilot.runtime.cbackend import build_library

    model, info = read_model(HOVER)
    return build_library(generate(info, initializers(model)))


def plant(lib: Path, data: bytes) -> None:
    """Replace `lib` by a new file (as an attacker's rename would), never rewriting it in place."""
    tmp = lib.with_name(lib.name + ".planted")
    tmp.write_bytes(data)
    os.replace(tmp, lib)


@pytest.fixture
def own_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("QUADPILOT_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


@needs_cc
def test_a_library_planted_under_the_cache_key_is_not_loaded(tmp_path, own_cache):
    """Someone replaces the cached library (its source left beside it, as it was): it is rebuilt,
    never loaded."""
    marker = tmp_path / "constructor_ran"
    lib = build_hover_library()
    assert own_cache in lib.parents
    planted = _planted_library(tmp_path, marker)
    plant(lib, planted)
    try:
        second = load_policy(HOVER, "c")
    finally:
        assert not marker.exists(), "the planted library was loaded"
    assert second.library == lib and lib.read_bytes() != planted  # rebuilt in place
    assert (lib.parent / DIGEST_NAME).read_text().strip() == hashlib.sha256(lib.read_bytes()).hexdigest()
    assert second.verify_golden() <= 1e-5


@needs_cc
@pytest.mark.parametrize("who", ["world-writable", "group-writable", "someone else's"])
def test_a_cache_directory_others_can_write_is_not_used(tmp_path, own_cache, who):
    """A library planted with a matching digest in a cache others can write proves nothing: such a
    cache is not used at all, the library is built in a private temporary directory."""
    if who == "someone else's" and os.geteuid() != 0:
        pytest.skip("giving a directory to another user needs root")
    marker = tmp_path / "constructor_ran"
    lib = build_hover_library()
    planted = _planted_library(tmp_path, marker)
    plant(lib, planted)
    (lib.parent / DIGEST_NAME).write_text(hashlib.sha256(planted).hexdigest() + "\n")
    if who == "world-writable":
        own_cache.chmod(0o777)
    elif who == "group-writable":
        (own_cache / "c").chmod(0o770)
    else:
        os.chown(lib.parent, 65534, 65534)
    try:
        policy = load_policy(HOVER, "c")
    finally:
        assert not marker.exists(), "the planted library was loaded"
    assert own_cache not in policy.library.parents
    assert policy.library.name == LIBRARY_NAME and policy.verify_golden() <= 1e-5


# --- observations ----------------------------------------------------------------------------------


@pytest.fixture(scope="module", params=BACKEND_PARAMS)
def hover_policy(request):
    return load_policy(HOVER, request.param)


NOT_REAL_NUMBERS = {
    "str": "0.1, 0.2",
    "None": None,
    "dict": {"pos_error": [0.0, 0.0, 0.0]},
    "bytes": b"\x00" * 72,
    "list-with-None": [0.0] * 17 + [None],
    "list-of-str": ["0.0"] * 18,
    "ragged": [[0.0] * 18, [0.0]],
    "object-array": np.array([0.0] * 17 + [object()], dtype=object),
    "complex-array": np.zeros(18, np.complex64),
    "bool-array": np.zeros(18, bool),
    "datetime-array": np.zeros(18, "datetime64[s]"),
    "generator": (0.0 for _ in range(18)),
    "set": {0.0},
}


@pytest.mark.parametrize("case", list(NOT_REAL_NUMBERS))
def test_an_observation_that_is_not_real_numbers_is_an_observation_shape_error(hover_policy, case):
    with pytest.raises(ObservationShapeError, match=r"expects \(18,\)") as excinfo:
        hover_policy.act(NOT_REAL_NUMBERS[case])
    assert isinstance(excinfo.value, ValueError) and "\n" not in str(excinfo.value)


def test_the_control_loops_observation_passes_through_unchanged(hover_policy):
    obs = hover_policy.info.golden_obs[0].copy()
    assert hover_policy.observation(obs) is obs  # the fast path: no copy, no conversion
    ints = np.zeros(18, np.int64)
    assert hover_policy.observation(ints).dtype == np.float32
