"""The runtime's model contract: every bad file is refused with a `ModelContractError`.

A policy file is a flight-critical input from someone else's disk. Whatever is wrong with it
(missing, empty, random bytes, truncated, weights stored beside it, metadata from another schema or
layout, golden vectors that do not replay, a graph whose inputs are not the contract's), `load_policy`
must raise `ModelContractError` (a ValueError) naming what was expected and what was found: never an
exception from inside onnx / onnxruntime / protobuf, never a policy that flies anyway. Every backend
is checked wherever a file is loaded (the c backend where a C compiler is installed). At `act()`,
an observation of the wrong size raises `ObservationShapeError` naming the expected shape.
"""

import json
import re
import traceback
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import numpy_helper

from quadpilot.modelfile.model import SCHEMA, ModelContractError
from quadpilot.runtime.backends import BACKENDS, ObservationShapeError, load_policy
from quadpilot.runtime.cbackend import find_compiler

HOVER = Path(__file__).resolve().parents[2] / "models" / "hover" / "policy.onnx"
OBS_DIM = 18  # hover layout
# the c backend compiles the file's C with the system C compiler: skipped where there is none
HAS_CC = find_compiler() is not None
BACKEND_PARAMS = [
    pytest.param(b, marks=pytest.mark.skipif(not HAS_CC, reason="the c backend needs a C compiler")) if b == "c" else b
    for b in BACKENDS
]


# --- helpers ------------------------------------------------------------------------------


def hover_model() -> onnx.ModelProto:
    return onnx.load(str(HOVER))


def save(model: onnx.ModelProto, tmp_path: Path, name: str = "policy.onnx") -> Path:
    path = tmp_path / name
    onnx.save_model(model, str(path))
    return path


def get_meta(model: onnx.ModelProto, key: str) -> str:
    return next(p.value for p in model.metadata_props if p.key == key)


def set_meta(model: onnx.ModelProto, key: str, value: str) -> None:
    for p in model.metadata_props:
        if p.key == key:
            p.value = value
            return
    raise KeyError(key)


def del_meta(model: onnx.ModelProto, key: str) -> None:
    keep = [p for p in model.metadata_props if p.key != key]
    assert len(keep) == len(model.metadata_props) - 1, key
    del model.metadata_props[:]
    model.metadata_props.extend(keep)


def edit_json_meta(model: onnx.ModelProto, key: str, edit) -> None:
    value = json.loads(get_meta(model, key))
    edit(value)
    set_meta(model, key, json.dumps(value))


def initializer(model: onnx.ModelProto, name: str) -> np.ndarray:
    return numpy_helper.to_array(next(t for t in model.graph.initializer if t.name == name))


def set_initializer(model: onnx.ModelProto, name: str, array: np.ndarray) -> None:
    """Replace a weight; its declared shape (value_info, optional in ONNX) goes with the old one."""
    for t in model.graph.initializer:
        if t.name == name:
            t.CopyFrom(numpy_helper.from_array(np.asarray(array, np.float32), name))
            keep = [v for v in model.graph.value_info if v.name != name]
            del model.graph.value_info[:]
            model.graph.value_info.extend(keep)
            return
    raise KeyError(name)


def rename_input(model: onnx.ModelProto, old: str, new: str) -> None:
    """Rename a graph input everywhere it is consumed, so the graph stays valid."""
    for v in model.graph.input:
        if v.name == old:
            v.name = new
    for node in model.graph.node:
        for i, name in enumerate(node.input):
            if name == old:
                node.input[i] = new


def refused(path: Path, backend: str, match: str) -> ModelContractError:
    """load_policy must raise ModelContractError (a ValueError) whose message matches."""
    with pytest.raises(ModelContractError, match=match) as excinfo:
        load_policy(path, backend)
    assert isinstance(excinfo.value, ValueError)
    return excinfo.value


# --- the bad files, one builder each: tmp_path → (path, regex the message must match) ------


def _missing(tmp_path):
    return tmp_path / "no_such_policy.onnx", r"no such file"


def _empty(tmp_path):
    path = tmp_path / "empty.onnx"
    path.write_bytes(b"")
    return path, r"empty"


def _random_bytes(tmp_path):
    path = tmp_path / "random.onnx"
    path.write_bytes(np.random.default_rng(0).bytes(40_000))
    return path, r"not an ONNX model|no graph"


def _truncated(cut):
    def build(tmp_path):
        data = HOVER.read_bytes()
        n = len(data) - 1 if cut == "len-1" else int(len(data) * cut)
        path = tmp_path / "truncated.onnx"
        path.write_bytes(data[:n])
        return path, r"not an ONNX model|no graph|truncated"

    return build


def _external_data(tmp_path):
    path = tmp_path / "external.onnx"
    onnx.save_model(
        hover_model(),
        str(path),
        save_as_external_data=True,
        all_tensors_to_one_file=True,
        location="external.weights",
        size_threshold=0,
    )
    assert (tmp_path / "external.weights").is_file()
    return path, r"external data.*actor\.0\.weight"


def _wrong_schema(tmp_path):
    m = hover_model()
    set_meta(m, "quadpilot.schema", "quadpilot.onnx/2")
    return save(m, tmp_path), r"schema.*expected 'quadpilot\.onnx/1'.*found 'quadpilot\.onnx/2'"


def _unknown_layout(tmp_path):
    m = hover_model()
    edit_json_meta(m, "quadpilot.obs_layout", lambda j: j.update(name="quadpilot.obs.hover/9"))
    return save(m, tmp_path), r"unknown observation layout 'quadpilot\.obs\.hover/9'.*quadpilot\.obs\.hover/1"


def _layout_field_renamed(tmp_path):
    m = hover_model()
    edit_json_meta(m, "quadpilot.obs_layout", lambda j: j["fields"][1].update(name="velocity"))
    return save(m, tmp_path), r"observation layout 'quadpilot\.obs\.hover/2'.*'velocity'.*'vel'"


def _layout_field_dropped(tmp_path):
    m = hover_model()
    edit_json_meta(m, "quadpilot.obs_layout", lambda j: j["fields"].pop())  # no 'rates'
    return save(m, tmp_path), r"observation layout 'quadpilot\.obs\.hover/2'.*'rates'"


def _layout_field_resized(tmp_path):
    m = hover_model()
    edit_json_meta(m, "quadpilot.obs_layout", lambda j: j["fields"][2].update(size=6))  # rot as 6D
    return save(m, tmp_path), r"observation layout 'quadpilot\.obs\.hover/2'"


def _golden_action_edited(tmp_path):
    m = hover_model()

    def edit(golden):
        golden["action"][2][1] += 0.01

    edit_json_meta(m, "quadpilot.golden", edit)
    return save(m, tmp_path), r"{backend} backend does not reproduce the file's golden vectors"


def _golden_shape_wrong(tmp_path):
    m = hover_model()
    edit_json_meta(m, "quadpilot.golden", lambda g: g.update(action=[row[:3] for row in g["action"]]))
    return save(m, tmp_path), r"golden vectors: expected .*\(K, 4\).*found"


def _weight_altered(tmp_path):
    m = hover_model()
    set_initializer(m, "actor.0.weight", initializer(m, "actor.0.weight") + np.float32(0.1))
    return save(m, tmp_path), r"{backend} backend does not reproduce the file's golden vectors.*altered"


def _input_renamed(tmp_path):
    m = hover_model()
    rename_input(m, "obs", "x")
    return save(m, tmp_path), r"expected \['obs'\].*found \['x'\]"


def _output_renamed(tmp_path):
    m = hover_model()
    old = m.graph.output[0].name
    m.graph.output[0].name = "motors"
    for node in m.graph.node:
        for i, name in enumerate(node.output):
            if name == old:
                node.output[i] = "motors"
    return save(m, tmp_path), r"expected \['obs'\] → \['action'\].*found \['obs'\] → \['motors'\]"


def _input_dim_edited(tmp_path):
    """Only the declared width changes: the graph is now inconsistent (the checker's shape
    inference may catch it before the contract check does); either way a ModelContractError."""
    m = hover_model()
    m.graph.input[0].type.tensor_type.shape.dim[1].dim_value = 17
    return save(m, tmp_path), r"17"


def _input_width_17(tmp_path):
    """A consistent, valid graph taking 17 values: the first layer's weight loses a column. Only
    the contract (layout hover/2 has 18 values) can refuse it."""
    m = hover_model()
    set_initializer(m, "actor.0.weight", initializer(m, "actor.0.weight")[:, :17])
    m.graph.input[0].type.tensor_type.shape.dim[1].dim_value = 17
    onnx.checker.check_model(m, full_check=True)  # the file itself is a valid ONNX model
    return save(m, tmp_path), r"obs: expected shape \[batch, 18\], found .*17"


def _input_double(tmp_path):
    """A valid graph whose input `obs` is float64, cast to float32 inside: only the contract
    (obs is float32) can refuse it."""
    m = hover_model()
    rename_input(m, "obs", "obs_f32")
    m.graph.input[0].name = "obs"
    m.graph.input[0].type.tensor_type.elem_type = onnx.TensorProto.DOUBLE
    cast = onnx.helper.make_node("Cast", ["obs"], ["obs_f32"], to=onnx.TensorProto.FLOAT)
    m.graph.node.insert(0, cast)
    onnx.checker.check_model(m, full_check=True)  # the file itself is a valid ONNX model
    return save(m, tmp_path), r"obs: expected float32, found double"


def _claims_lstm(tmp_path):
    """Metadata says LSTM, the graph is the MLP: the I/O the architecture implies is missing."""
    m = hover_model()
    edit_json_meta(m, "quadpilot.architecture", lambda a: a.update(kind="lstm", hidden=64))
    return save(m, tmp_path), r"expected \['obs', 'h_in', 'c_in'\].*found \['obs'\]"


def _unknown_architecture(tmp_path):
    m = hover_model()
    edit_json_meta(m, "quadpilot.architecture", lambda a: a.update(kind="transformer"))
    return save(m, tmp_path), r"architecture kind: expected 'mlp' or 'lstm', found 'transformer'"


def _metadata_not_json(tmp_path):
    m = hover_model()
    set_meta(m, "quadpilot.golden", get_meta(m, "quadpilot.golden")[:-40])
    return save(m, tmp_path), r"quadpilot\.golden is not valid JSON"


def _control_period_zero(tmp_path):
    m = hover_model()
    set_meta(m, "quadpilot.control_period_s", "0")
    return save(m, tmp_path), r"control period .*expected"


BAD_FILES = {
    "missing": _missing,
    "empty": _empty,
    "random-40KB": _random_bytes,
    "truncated-10%": _truncated(0.1),
    "truncated-50%": _truncated(0.5),
    "truncated-90%": _truncated(0.9),
    "truncated-len-1": _truncated("len-1"),
    "external-data": _external_data,
    "wrong-schema": _wrong_schema,
    "unknown-layout": _unknown_layout,
    "layout-field-renamed": _layout_field_renamed,
    "layout-field-dropped": _layout_field_dropped,
    "layout-field-resized": _layout_field_resized,
    "golden-action-edited": _golden_action_edited,
    "golden-shape-wrong": _golden_shape_wrong,
    "weight-altered": _weight_altered,
    "input-renamed": _input_renamed,
    "output-renamed": _output_renamed,
    "input-dim-edited": _input_dim_edited,
    "input-width-17": _input_width_17,
    "input-double": _input_double,
    "claims-lstm": _claims_lstm,
    "unknown-architecture": _unknown_architecture,
    "metadata-not-json": _metadata_not_json,
    "control-period-zero": _control_period_zero,
}


# --- the shipped file is fine (so the refusals below are about the edits) ------------------


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_shipped_hover_file_loads_and_replays_its_golden_vectors(backend):
    policy = load_policy(HOVER, backend)
    assert policy.backend == backend
    assert policy.info.obs_dim == OBS_DIM and not policy.info.recurrent
    assert policy.verify_golden() <= 1e-5


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_an_unedited_round_trip_through_onnx_save_still_loads(tmp_path, backend):
    """The helpers' own load → save path changes nothing the contract looks at."""
    load_policy(save(hover_model(), tmp_path), backend)


# --- every bad file is refused -------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("case", list(BAD_FILES))
def test_bad_file_is_refused_with_a_contract_error(tmp_path, case, backend):
    path, match = BAD_FILES[case](tmp_path)
    err = refused(path, backend, match.replace("{backend}", backend))
    assert str(path) in str(err), "the message names the file"


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("case", list(BAD_FILES))
def test_refusal_shows_no_traceback_from_onnx_onnxruntime_or_protobuf(tmp_path, case, backend):
    """What a user sees, if the error reaches the top level, is the runtime's message alone: no
    frame inside onnx / onnxruntime / protobuf, and no chained "During handling of the above
    exception" from one of them."""
    path, _ = BAD_FILES[case](tmp_path)
    with pytest.raises(ModelContractError) as excinfo:
        load_policy(path, backend)
    err = excinfo.value
    shown = "".join(traceback.format_exception(type(err), err, err.__traceback__))
    assert "During handling of the above exception" not in shown, shown
    assert "The above exception was the direct cause" not in shown, shown
    for foreign in ("google/protobuf", "site-packages/onnx/", "site-packages/onnxruntime/", "DecodeError"):
        assert foreign not in shown, shown


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize(
    "key",
    [
        "quadpilot.schema",
        "quadpilot.obs_layout",
        "quadpilot.control_period_s",
        "quadpilot.vehicle",
        "quadpilot.golden",
        "quadpilot.architecture",
        "quadpilot.envelope",
    ],
)
def test_a_missing_metadata_key_is_named(tmp_path, key, backend):
    m = hover_model()
    del_meta(m, key)
    refused(save(m, tmp_path), backend, re.escape(key))


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_metadata_that_is_not_utf8_is_a_contract_error(tmp_path, backend):
    """One flipped bit in a metadata value (here the envelope's first key, "max…" → "ma\\xf8…")
    leaves the protobuf parseable but the string invalid UTF-8; protobuf then hands the value over
    as bytes. Found by flipping bits of the shipped file at random: such a file must be refused
    like any other corruption, not raise UnicodeDecodeError from json."""
    data = bytearray(HOVER.read_bytes())
    i = data.find(b'"max_distance_m"')
    assert i > 0
    data[i + 3] ^= 0x80  # 'x' (0x78) → 0xf8, not a UTF-8 start byte
    path = tmp_path / "flipped.onnx"
    path.write_bytes(bytes(data))
    refused(path, backend, r"quadpilot\.envelope|UTF-8|utf-8")


def test_unknown_backend_is_a_value_error_naming_the_backends():
    with pytest.raises(ValueError, match=r"unknown backend 'torch'.*onnxruntime.*numpy"):
        load_policy(HOVER, "torch")


def test_altered_weights_are_refused_by_every_backend_independently(tmp_path):
    """ONNX Runtime runs the graph; the NumPy backend reads the same initializers itself, and the
    c backend compiles C generated from them. Each replays the golden vectors on its own, so each
    must notice the edit."""
    m = hover_model()
    set_initializer(m, "actor.0.weight", initializer(m, "actor.0.weight") + np.float32(0.1))
    path = save(m, tmp_path)
    backends = [b for b in BACKENDS if b != "c" or HAS_CC]
    messages = [str(refused(path, b, r"golden vectors")) for b in backends]
    for backend, message in zip(backends, messages, strict=True):
        assert f"{backend} backend" in message


# --- the LSTM variant ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def lstm_onnx(tmp_path_factory):
    pytest.importorskip("torch")
    from quadpilot.export.onnx_export import export_onnx
    from quadpilot.train.envs import make_config
    from quadpilot.train.ppo import PPOConfig
    from quadpilot.train.ppo.checkpoint import save_untrained_policy

    d = tmp_path_factory.mktemp("lstm")
    pt = save_untrained_policy(d / "policy.pt", PPOConfig(arch="lstm"), make_config("hover"))
    path = d / "policy.onnx"
    export_onnx(pt, path)
    return path


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_lstm_file_loads_with_explicit_recurrent_state(lstm_onnx, backend):
    policy = load_policy(lstm_onnx, backend)
    info = policy.info
    assert info.recurrent is True and info.hidden > 0
    assert info.input_names() == ("obs", "h_in", "c_in")
    assert info.output_names() == ("action", "h_out", "c_out")
    # the state is carried between calls and cleared by reset()
    first = np.array([policy.act(o) for o in info.golden_obs])
    np.testing.assert_allclose(first, info.golden_action, atol=1e-5)
    carried = np.array([policy.act(o) for o in info.golden_obs])
    assert np.max(np.abs(carried - info.golden_action)) > 1e-4, "state did not carry over"
    policy.reset()
    again = np.array([policy.act(o) for o in info.golden_obs])
    np.testing.assert_allclose(again, info.golden_action, atol=1e-5)


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_lstm_file_that_claims_to_be_an_mlp_is_refused(lstm_onnx, tmp_path, backend):
    m = onnx.load(str(lstm_onnx))
    edit_json_meta(m, "quadpilot.architecture", lambda a: a.update(kind="mlp"))
    refused(save(m, tmp_path), backend, r"expected \['obs'\].*found \['obs', 'h_in', 'c_in'\]")


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_lstm_file_with_a_renamed_state_input_is_refused(lstm_onnx, tmp_path, backend):
    m = onnx.load(str(lstm_onnx))
    rename_input(m, "h_in", "hidden")
    refused(save(m, tmp_path), backend, r"expected \['obs', 'h_in', 'c_in'\].*found \['obs', 'hidden', 'c_in'\]")


# --- act(): the observation's shape --------------------------------------------------------


@pytest.fixture(scope="module", params=BACKEND_PARAMS)
def hover_policy(request):
    return load_policy(HOVER, request.param)


@pytest.mark.parametrize("shape", [(17,), (19,), (2, OBS_DIM), (0,), (1, 17)], ids=str)
def test_wrong_observation_size_raises_naming_the_expected_shape(hover_policy, shape):
    obs = np.zeros(shape, np.float32)
    with pytest.raises(ObservationShapeError, match=rf"expects \({OBS_DIM},\)") as excinfo:
        hover_policy.act(obs)
    assert str(shape).replace(" ", "") in str(excinfo.value).replace(" ", ""), "names the shape it found"
    assert isinstance(excinfo.value, ValueError)


def test_wrong_size_list_raises_too(hover_policy):
    with pytest.raises(ObservationShapeError, match=r"expects \(18,\)"):
        hover_policy.act([0.0] * 17)


def test_a_list_of_floats_of_the_right_size_works(hover_policy):
    obs = hover_policy.info.golden_obs[0]
    want = hover_policy.act(obs)
    got = hover_policy.act([float(v) for v in obs])
    assert got.shape == (4,) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=1e-7)
    np.testing.assert_allclose(got, hover_policy.info.golden_action[0], atol=1e-5)


@pytest.mark.parametrize("layout", ["batch-of-one", "float64"])
def test_accepted_array_forms_give_the_golden_command(hover_policy, layout):
    obs = hover_policy.info.golden_obs[1]
    x = obs[None] if layout == "batch-of-one" else obs.astype(np.float64)
    np.testing.assert_allclose(hover_policy.act(x), hover_policy.info.golden_action[1], atol=1e-5)


def test_schema_constant_is_what_the_shipped_file_says():
    assert get_meta(hover_model(), "quadpilot.schema") == SCHEMA


@pytest.mark.parametrize(
    ("checkpoint", "says"),
    [
        (
            "hover_px4_raptor_sih",
            "a px4-raptor checkpoint (quad-train --contract px4-raptor), not a policy file; "
            "export it with quad-export --format px4-raptor ",
        ),
        ("hover", "a PyTorch checkpoint, not a policy file; export it with quad-export "),
    ],
)
def test_a_checkpoint_given_as_the_policy_file_says_how_to_export_it(checkpoint, says, capsys):
    from quadpilot.sitl import main as sitl

    pt = HOVER.parents[1] / checkpoint / "policy.pt"
    with pytest.raises(ModelContractError, match=re.escape(says)):
        load_policy(pt, "numpy")
    assert sitl([str(pt), "--episodes", "1", "--gcs", "none"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("quad-sitl: error:") and says in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
