"""The refusal of every command in the supported table (docs/commander_tables.py commands, from
`commands.COMMANDS`), in one place, through packed MAVLink bytes: what a ground station
sends when the vehicle cannot do it, the one COMMAND_ACK's result, the STATUSTEXT saying why, and
that nothing changed. The refusals tests/autopilot/test_commander_commands.py already checks are not
repeated here; `test_every_supported_command_has_a_refusal_test` fails when a command is added to
the table without one here or there.

The audit behind it (accepted / refused, where):

| command | accepted | refused |
|---|---|---|
| COMPONENT_ARM_DISARM | test_commander_commands | no position, in the air, flying, bad param1, disarm in air |
| NAV_TAKEOFF | test_commander_commands | disarmed, below; here: no position, geofence |
| NAV_LAND | test_commander_commands | disarmed; here: no position |
| NAV_RETURN_TO_LAUNCH | test_commander_commands | landed; here: disarmed, no position |
| DO_REPOSITION | test_commander_commands | disarmed, landed, fence, frame, off globe, LONG; here: no position |
| DO_SET_MODE | test_commander_commands | unknown modes, no custom flag, Mission without one, Takeoff disarmed |
| MISSION_START | test_commander_commands | no mission, first beyond it; here: geofence, no position |
| DO_CHANGE_SPEED | test_commander_commands | bad type, bad speed |
| REQUEST_MESSAGE | test_commander_commands | no home yet, a message it does not send |
| SET_MESSAGE_INTERVAL | test_commander_commands | a message it does not stream, bad interval |
| GET_MESSAGE_INTERVAL | test_commander_commands | here: a message id that cannot be one |
| GET_HOME_POSITION | test_commander_commands | no home yet |
| REQUEST_AUTOPILOT_CAPABILITIES | test_commander_commands | none (needs no state); here: answered before a position |
"""

import math
from pathlib import Path

import numpy as np
import pytest
from commander_gcs import Gcs, ack, mission_item, of_type, texts, upload
from pymavlink.dialects.v20 import common as M

from quadpilot.autopilot.commands import COMMANDS

NAN7 = [math.nan] * 7
# command → the tests that check its refusal (this file's, and test_commander_commands.py's)
REFUSAL_TESTS = {
    M.MAV_CMD_COMPONENT_ARM_DISARM: ["test_commander_commands::test_arm_in_the_air_is_denied"],
    M.MAV_CMD_NAV_TAKEOFF: ["test_takeoff_before_any_position", "test_takeoff_beyond_the_geofence"],
    M.MAV_CMD_NAV_LAND: ["test_land_before_any_position"],
    M.MAV_CMD_NAV_RETURN_TO_LAUNCH: ["test_return_disarmed", "test_return_before_any_position"],
    M.MAV_CMD_DO_REPOSITION: ["test_goto_before_any_position"],
    M.MAV_CMD_DO_SET_MODE: ["test_commander_commands::test_set_mode_refusals"],
    M.MAV_CMD_MISSION_START: ["test_mission_start_beyond_the_geofence", "test_mission_start_before_any_position"],
    M.MAV_CMD_DO_CHANGE_SPEED: ["test_commander_commands::test_change_speed_bounds_the_reference_speed_and_refuses"],
    M.MAV_CMD_REQUEST_MESSAGE: ["test_commander_commands::test_request_message_sends_the_message_then_the_ack"],
    M.MAV_CMD_SET_MESSAGE_INTERVAL: ["test_commander_commands::test_set_message_interval_refusals"],
    M.MAV_CMD_GET_MESSAGE_INTERVAL: ["test_get_message_interval_of_an_impossible_message_id"],
    M.MAV_CMD_GET_HOME_POSITION: ["test_commander_commands::test_get_home_position_and_capabilities"],
    M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: ["test_capabilities_are_answered_before_any_position"],
}


def fresh() -> Gcs:
    """A vehicle that has not had its first step: no position, no home."""
    return Gcs()


def on_ground(**params) -> Gcs:
    g = Gcs(**params)
    g.run(0.1)
    return g


def flying(**params) -> Gcs:
    """Armed and holding at 2.5 m after a take-off."""
    g = on_ground(**params)
    g.arm()
    g.takeoff()
    g.run(10, until=lambda g: g.commander.mode == (4, 3))
    assert not g.commander.landed and g.position[2] > 2.3
    return g


def test_every_supported_command_has_a_refusal_test():
    assert set(REFUSAL_TESTS) == set(COMMANDS)
    for command, names in REFUSAL_TESTS.items():
        for name in names:
            module, _, test = name.rpartition("::")
            source = (Path(__file__).parent / f"{module}.py") if module else Path(__file__)
            assert f"def {test}" in source.read_text(), f"command {command}: no test {name}"


def refused(out, command: int, result: int, why: str | None) -> None:
    assert ack(out, command) == result
    if why is not None:
        assert any(why in t for t in texts(out)), texts(out)


# --- flight commands before the first position: not yet (TEMPORARILY_REJECTED), not never -----------


def test_takeoff_before_any_position_is_temporarily_rejected():
    g = fresh()
    out = g.command(M.MAV_CMD_NAV_TAKEOFF, *NAN7)
    refused(out, M.MAV_CMD_NAV_TAKEOFF, M.MAV_RESULT_TEMPORARILY_REJECTED, "Takeoff denied: no position yet")
    assert g.commander.mode == (4, 3) and not g.commander.armed


def test_land_before_any_position_is_temporarily_rejected():
    g = fresh()
    out = g.command(M.MAV_CMD_NAV_LAND, *NAN7)
    refused(out, M.MAV_CMD_NAV_LAND, M.MAV_RESULT_TEMPORARILY_REJECTED, "Land denied: no position yet")
    assert g.commander.mode == (4, 3)


def test_return_before_any_position_is_temporarily_rejected():
    g = fresh()
    out = g.command(M.MAV_CMD_NAV_RETURN_TO_LAUNCH)
    refused(out, M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_RESULT_TEMPORARILY_REJECTED, "Return denied: no position yet")
    assert g.commander.mode == (4, 3)


def test_goto_before_any_position_is_temporarily_rejected():
    g = fresh()
    out = g.goto(1.0, 0.0, 2.0)
    refused(out, M.MAV_CMD_DO_REPOSITION, M.MAV_RESULT_TEMPORARILY_REJECTED, "Goto denied: no position yet")


def test_mission_start_before_any_position_is_temporarily_rejected():
    g = fresh()
    upload(g, [mission_item(0, M.MAV_CMD_NAV_WAYPOINT, 1, 0, 2.5)])
    out = g.command(M.MAV_CMD_MISSION_START, 0, 0)
    refused(out, M.MAV_CMD_MISSION_START, M.MAV_RESULT_TEMPORARILY_REJECTED, "Mission denied: no position yet")
    assert g.commander.mode == (4, 3)


# --- in a state that forbids it: DENIED ------------------------------------------------------------


def test_return_disarmed_is_denied():
    g = on_ground()
    out = g.command(M.MAV_CMD_NAV_RETURN_TO_LAUNCH)
    refused(out, M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_RESULT_DENIED, "Return denied: disarmed")
    assert g.commander.mode == (4, 3)


def test_takeoff_beyond_the_geofence_is_denied_and_stays_on_the_ground():
    g = on_ground(GF_MAX_VER_DIST=2.0)  # below MIS_TAKEOFF_ALT = 2.5
    g.arm()
    out = g.command(M.MAV_CMD_NAV_TAKEOFF, *NAN7)
    refused(out, M.MAV_CMD_NAV_TAKEOFF, M.MAV_RESULT_DENIED, "geofence 2 m")
    g.run(2)
    assert g.commander.landed and g.position[2] == 0.0 and g.commander.mode == (4, 3)


def test_mission_start_beyond_the_geofence_is_denied_and_holds():
    g = flying(GF_MAX_HOR_DIST=5.0)
    upload(g, [mission_item(0, M.MAV_CMD_NAV_WAYPOINT, 1, 0, 2.5), mission_item(1, M.MAV_CMD_NAV_WAYPOINT, 6, 0, 2.5)])
    before = g.position
    out = g.command(M.MAV_CMD_MISSION_START, 0, 0)
    refused(out, M.MAV_CMD_MISSION_START, M.MAV_RESULT_DENIED, "Mission denied: item 1")
    g.run(2)
    assert g.commander.mode == (4, 3) and np.linalg.norm(g.position - before) < 0.02


# --- telemetry requests ------------------------------------------------------------------------------


@pytest.mark.parametrize("msg_id", [-1.0, math.nan, 70_000.0])
def test_get_message_interval_of_an_impossible_message_id_is_denied(msg_id):
    g = on_ground()
    out = g.command(M.MAV_CMD_GET_MESSAGE_INTERVAL, msg_id)
    assert ack(out, M.MAV_CMD_GET_MESSAGE_INTERVAL) == M.MAV_RESULT_DENIED
    assert of_type(out, "MESSAGE_INTERVAL") == []


def test_capabilities_are_answered_before_any_position():
    """REQUEST_AUTOPILOT_CAPABILITIES has no refusal: AUTOPILOT_VERSION needs no state or home (a
    ground station asks for it first, before the vehicle has a position)."""
    g = fresh()
    out = g.command(M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1)
    assert [m.get_type() for m in out] == ["AUTOPILOT_VERSION", "COMMAND_ACK"]
    assert out[1].result == M.MAV_RESULT_ACCEPTED
