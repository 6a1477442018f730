"""The parameter protocol through packed MAVLink bytes: list, read, set, and refusals that leave the
value unchanged (the PARAM_VALUE answer carries the old value, as PX4 answers, plus a STATUSTEXT)."""

import math
import struct

import pytest
from commander_gcs import Gcs, ack, of_type, texts
from pymavlink.dialects.v20 import common as M

from quadpilot.autopilot.commander import Commander, CommanderConfig
from quadpilot.autopilot.param_protocol import INT32, PARAMS, REAL32, ParamTable, decode, encode

REQUIRED = (
    "MIS_TAKEOFF_ALT",
    "MPC_XY_CRUISE",
    "MPC_Z_V_AUTO_UP",
    "MPC_Z_V_AUTO_DN",
    "RTL_RETURN_ALT",
    "COM_DL_LOSS_T",
    "NAV_DLL_ACT",
)


def int_bytes(v: int) -> float:
    """An int32 as PX4 and MAVSDK carry it in param_value: its bytes in the float."""
    return struct.unpack("<f", struct.pack("<i", v))[0]


def value_of(msgs, name: str):
    vals = [m for m in of_type(msgs, "PARAM_VALUE") if m.param_id == name]
    assert len(vals) == 1, msgs
    return vals[0]


def test_list_sends_every_parameter_once_with_its_index_and_count():
    g = Gcs()
    out = of_type(g.send(g.tx.param_request_list_encode(1, 1)), "PARAM_VALUE")
    assert [m.param_id for m in out] == [p.name for p in PARAMS]
    assert [m.param_index for m in out] == list(range(len(PARAMS)))
    assert {m.param_count for m in out} == {len(PARAMS)}
    assert set(REQUIRED) <= {m.param_id for m in out}
    takeoff = value_of(out, "MIS_TAKEOFF_ALT")
    assert (takeoff.param_type, takeoff.param_value) == (REAL32, 2.5)  # PX4's default
    dl = value_of(out, "COM_DL_LOSS_T")
    assert dl.param_type == INT32 and decode(INT32, dl.param_value) == 10


def test_read_by_name_and_by_index():
    g = Gcs()
    out = g.send(g.tx.param_request_read_encode(1, 1, b"MPC_XY_CRUISE", -1))
    assert value_of(out, "MPC_XY_CRUISE").param_value == 5.0
    i = [p.name for p in PARAMS].index("RTL_RETURN_ALT")
    out = g.send(g.tx.param_request_read_encode(1, 1, b"", i))
    assert value_of(out, "RTL_RETURN_ALT").param_value == 60.0


def test_read_of_an_unknown_name_or_index_is_a_statustext_only():
    g = Gcs()
    out = g.send(g.tx.param_request_read_encode(1, 1, b"NO_SUCH_PARAM", -1))
    assert of_type(out, "PARAM_VALUE") == [] and texts(out) == ["[pm] unknown param: NO_SUCH_PARAM"]
    out = g.send(g.tx.param_request_read_encode(1, 1, b"", 999))
    assert of_type(out, "PARAM_VALUE") == [] and texts(out) == ["[pm] unknown param ID: 999"]


def test_set_answers_with_the_same_id_type_and_value_and_takes_effect():
    g = Gcs()
    out = g.param_set("MIS_TAKEOFF_ALT", 1.5)  # MAVSDK's set_takeoff_altitude
    v = value_of(out, "MIS_TAKEOFF_ALT")
    assert (v.param_type, v.param_value) == (REAL32, 1.5) and texts(out) == []
    g.run(0.1)
    g.arm()
    g.takeoff()
    g.run(10, until=lambda g: g.commander.mode == (4, 3))
    assert abs(g.position[2] - 1.5) <= 0.1
    out = g.send(g.tx.param_request_read_encode(1, 1, b"MIS_TAKEOFF_ALT", -1))
    assert value_of(out, "MIS_TAKEOFF_ALT").param_value == 1.5  # persists


def test_int32_parameters_travel_bytewise():
    g = Gcs()
    out = g.param_set("COM_DL_LOSS_T", int_bytes(7), M.MAV_PARAM_TYPE_INT32)
    v = value_of(out, "COM_DL_LOSS_T")
    assert v.param_type == INT32 and v.param_value == int_bytes(7) and g.commander.params["COM_DL_LOSS_T"] == 7


def test_an_int32_parameter_sent_as_a_whole_float_is_set():
    g = Gcs()
    out = g.param_set("COM_DL_LOSS_T", 7.0, REAL32)  # MAVProxy, after reading @PARAM/param.pck
    v = value_of(out, "COM_DL_LOSS_T")
    assert v.param_type == INT32 and v.param_value == int_bytes(7) and texts(out) == []
    assert g.commander.params["COM_DL_LOSS_T"] == 7


@pytest.mark.parametrize(
    ("name", "value", "kind", "why"),
    [
        ("MIS_TAKEOFF_ALT", 81.0, REAL32, "outside"),  # PX4 max 80 m
        ("MIS_TAKEOFF_ALT", -1.0, REAL32, "outside"),
        ("MIS_TAKEOFF_ALT", math.nan, REAL32, "not a number"),
        ("MPC_XY_CRUISE", 2.0, REAL32, "outside"),  # PX4 min 3 m/s
        ("MPC_Z_V_AUTO_DN", 4.5, REAL32, "outside"),
        ("COM_DL_LOSS_T", int_bytes(4), INT32, "outside"),  # PX4 min 5 s
        ("NAV_DLL_ACT", int_bytes(5), INT32, "not an allowed value"),  # Terminate: not supported here
        ("MIS_TAKEOFF_ALT", int_bytes(3), INT32, "type"),  # a REAL32 parameter sent as INT32
        ("COM_DL_LOSS_T", 7.5, REAL32, "not an integer"),  # as a float (MAVProxy after the file): whole only
        ("COM_DL_LOSS_T", int_bytes(7), REAL32, "not an integer"),  # bytewise, but typed REAL32
    ],
)
def test_refused_set_leaves_the_value_unchanged_and_says_why(name, value, kind, why):
    g = Gcs()
    before = g.commander.params[name]
    spec = {p.name: p for p in PARAMS}[name]
    out = g.param_set(name, value, kind)
    v = value_of(out, name)
    assert v.param_type == spec.kind and decode(spec.kind, v.param_value) == before
    assert g.commander.params[name] == before
    assert any(why in t for t in texts(out)), texts(out)


def test_set_of_an_unknown_name_changes_nothing_and_says_so():
    g = Gcs()
    before = dict(g.commander.params.values)
    out = g.param_set("NOT_A_PARAM", 1.0)
    assert of_type(out, "PARAM_VALUE") == [] and texts(out) == ["[pm] unknown param: NOT_A_PARAM"]
    assert g.commander.params.values == before


def test_every_default_is_in_its_own_range():
    for p in PARAMS:
        assert p.check(p.default) is None, p.name
        assert decode(p.kind, encode(p.kind, p.default)) == p.default


def test_overrides_are_checked():
    with pytest.raises(ValueError, match=r"MPC_THR_HOVER: 0.95 outside \[0.1, 0.8\]"):
        ParamTable(M.MAVLink(None), {"MPC_THR_HOVER": 0.95})
    with pytest.raises(ValueError, match="unknown parameter"):
        Commander(CommanderConfig(params={"NOPE": 1.0}))


def test_speed_parameters_take_effect_in_flight():
    g = Gcs()
    g.run(0.1)
    g.arm()
    g.param_set("MPC_TKO_SPEED", 1.0)
    g.takeoff()
    g.run(1.0)
    assert g.commander.mover.velocity[2] <= 1.0 + 1e-9
    g.run(10, until=lambda g: g.commander.mode == (4, 3))
    g.param_set("MPC_XY_CRUISE", 3.0)
    assert ack(g.goto(6.0, 0.0, 2.5), M.MAV_CMD_DO_REPOSITION) == M.MAV_RESULT_ACCEPTED
    top = 0.0
    for _ in range(100):
        g.run(0.02)
        top = max(top, abs(g.commander.mover.velocity[0]))
    assert 1.0 < top <= 3.0 + 1e-9
