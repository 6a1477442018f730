"""Every command the commander supports, accepted and refused, through packed MAVLink bytes.

Each test sends what a ground station sends (pymavlink-built COMMAND_LONG / COMMAND_INT / SET_MODE)
and reads what the vehicle answers after it crossed the wire: exactly one COMMAND_ACK per command,
with the result PX4 gives, and a STATUSTEXT saying why whenever it refuses.
"""

import math

import numpy as np
from commander_gcs import HOME, Gcs, ack, mission_item, of_type, texts, upload
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as M

from quadpilot.autopilot.commander import Commander
from quadpilot.link.frames import local_to_geodetic

ARM = M.MAV_CMD_COMPONENT_ARM_DISARM
TAKEOFF = M.MAV_CMD_NAV_TAKEOFF
LAND = M.MAV_CMD_NAV_LAND
RTL = M.MAV_CMD_NAV_RETURN_TO_LAUNCH
REPOSITION = M.MAV_CMD_DO_REPOSITION
SET_MODE = M.MAV_CMD_DO_SET_MODE
NAN7 = [math.nan] * 7


def custom(hb) -> tuple[int, int]:
    return (hb.custom_mode >> 16) & 0xFF, (hb.custom_mode >> 24) & 0xFF


def flying(**params) -> Gcs:
    """Armed and holding at 2.5 m after a take-off."""
    g = Gcs(**params)
    g.run(0.5)
    g.arm()
    g.takeoff()
    g.run(10, until=lambda g: g.commander.mode == (4, 3))
    assert not g.commander.landed and g.position[2] > 2.3
    return g


# --- heartbeat ----------------------------------------------------------------------------------


def test_heartbeat_is_px4_quadrotor_with_custom_mode_and_armed_flag():
    g = Gcs()
    hb = of_type(g.run(1.0), "HEARTBEAT")[-1]
    assert (hb.type, hb.autopilot) == (M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4)
    assert hb.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert custom(hb) == (4, 3) and hb.system_status == M.MAV_STATE_STANDBY  # Hold, on the ground
    out = g.arm()
    hb = of_type(out, "HEARTBEAT")[-1]  # sent at once on arming, not a second later
    assert hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and hb.system_status == M.MAV_STATE_ACTIVE
    out = g.takeoff()
    assert custom(of_type(out, "HEARTBEAT")[-1]) == (4, 2)


# --- arm / disarm -------------------------------------------------------------------------------


def test_arm_on_the_ground_then_again_is_accepted_once():
    g = Gcs()
    g.run(0.1)
    out = g.arm()
    assert ack(out, ARM) == M.MAV_RESULT_ACCEPTED and g.commander.armed
    out = g.arm()  # arming an armed vehicle on the ground changes nothing
    assert ack(out, ARM) == M.MAV_RESULT_ACCEPTED and g.commander.armed


def test_arm_before_any_position_is_temporarily_rejected():
    g = Gcs()
    out = g.arm()
    assert ack(out, ARM) == M.MAV_RESULT_TEMPORARILY_REJECTED and not g.commander.armed
    assert any("no position" in t for t in texts(out))


def test_arm_in_the_air_is_denied():
    g = Gcs()
    g.vehicle.state[2] = 3.0  # a disarmed vehicle 3 m up: not on the ground
    g.run(0.1)
    out = g.arm()
    assert ack(out, ARM) == M.MAV_RESULT_DENIED and not g.commander.armed
    assert any("not on the ground" in t for t in texts(out))


def test_arm_while_flying_is_denied():
    g = flying()
    out = g.arm()
    assert ack(out, ARM) == M.MAV_RESULT_DENIED
    assert any("already flying" in t for t in texts(out))


def test_disarm_in_flight_is_denied_unless_forced():
    g = flying()
    out = g.command(ARM, 0.0)
    assert ack(out, ARM) == M.MAV_RESULT_DENIED and g.commander.armed
    assert "Disarming denied: not landed" in texts(out)
    out = g.command(ARM, 0.0, 21196.0)
    assert ack(out, ARM) == M.MAV_RESULT_ACCEPTED and not g.commander.armed
    assert not g.commander.setpoint.motors_enabled


def test_disarm_on_the_ground_and_when_disarmed_is_accepted():
    g = Gcs()
    g.run(0.1)
    g.arm()
    assert ack(g.command(ARM, 0.0), ARM) == M.MAV_RESULT_ACCEPTED and not g.commander.armed
    assert ack(g.command(ARM, 0.0), ARM) == M.MAV_RESULT_ACCEPTED


def test_arm_with_a_bad_param1_is_denied():
    g = Gcs()
    g.run(0.1)
    assert ack(g.command(ARM, 0.5), ARM) == M.MAV_RESULT_DENIED and not g.commander.armed


# --- take-off -----------------------------------------------------------------------------------


def test_takeoff_disarmed_is_denied_with_a_reason():
    g = Gcs()
    g.run(0.1)
    out = g.takeoff()
    assert ack(out, TAKEOFF) == M.MAV_RESULT_DENIED
    assert "Takeoff denied: disarmed" in texts(out)
    assert g.commander.mode == (4, 3)


def test_takeoff_with_nan_altitude_climbs_to_mis_takeoff_alt():
    g = Gcs()
    g.run(0.1)
    g.param_set("MIS_TAKEOFF_ALT", 1.5)
    g.arm()
    assert ack(g.takeoff(), TAKEOFF) == M.MAV_RESULT_ACCEPTED
    g.run(10, until=lambda g: g.commander.mode == (4, 3))  # Hold once there (PX4: takeoff completes to Hold)
    assert abs(g.position[2] - 1.5) <= 0.1


def test_takeoff_param7_is_an_altitude_above_mean_sea_level():
    g = Gcs()
    g.run(0.1)
    g.arm()
    out = g.command(TAKEOFF, *([math.nan] * 6), HOME.alt_m + 4.0)
    assert ack(out, TAKEOFF) == M.MAV_RESULT_ACCEPTED
    g.run(15, until=lambda g: g.commander.mode == (4, 3))
    assert abs(g.position[2] - 4.0) <= 0.1


def test_a_resent_command_gets_its_first_answer_and_is_not_done_again():
    g = Gcs()
    g.run(0.1)
    first = g.arm()
    g.takeoff()
    g.run(1.5)  # in the air now: arming again would be refused
    again = g.command(ARM, 1.0, confirmation=1)  # MAVSDK's resend: it did not hear the first ACK
    assert ack(first, ARM) == ack(again, ARM) == M.MAV_RESULT_ACCEPTED and texts(again) == []
    fresh = g.arm()  # a new command (confirmation 0) is judged again
    assert ack(fresh, ARM) == M.MAV_RESULT_DENIED and any("already flying" in t for t in texts(fresh))


def test_a_takeoff_sent_again_does_not_raise_the_target():
    g = Gcs()
    g.run(0.1)
    g.arm()
    first = g.takeoff()
    g.run(0.8)
    again = g.takeoff()  # a second NaN take-off while climbing: the same take-off, not 2.5 m more
    assert ack(first, TAKEOFF) == ack(again, TAKEOFF) == M.MAV_RESULT_ACCEPTED
    g.run(10, until=lambda g: g.commander.mode == (4, 3))
    assert abs(g.position[2] - 2.5) <= 0.1


def test_takeoff_below_the_current_altitude_is_denied():
    g = flying()
    out = g.command(TAKEOFF, *([math.nan] * 6), HOME.alt_m + 1.0)
    assert ack(out, TAKEOFF) == M.MAV_RESULT_DENIED
    assert any("already higher" in t for t in texts(out))


# --- goto (DO_REPOSITION) -----------------------------------------------------------------------


def test_goto_flies_to_the_global_position_in_hold_mode():
    g = flying()
    out = g.goto(3.0, -1.0, 3.0)
    assert ack(out, REPOSITION) == M.MAV_RESULT_ACCEPTED
    g.run(10)
    assert g.commander.mode == (4, 3)
    assert np.allclose(g.position, [3.0, -1.0, 3.0], atol=0.02)


def test_goto_relative_altitude_frames_3_and_6():
    g = flying()
    for frame, east in ((M.MAV_FRAME_GLOBAL_RELATIVE_ALT, 1.0), (M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 2.0)):
        lat, lon, _ = local_to_geodetic((east, 0.0, 0.0), HOME)
        out = g.command_int(REPOSITION, frame, lat, lon, 1.8, -1.0, 1.0, 0.0, math.nan)
        assert ack(out, REPOSITION) == M.MAV_RESULT_ACCEPTED
        g.run(6)
        assert np.allclose(g.position, [east, 0.0, 1.8], atol=0.02)


def test_goto_yaw_nan_keeps_the_yaw_and_a_heading_sets_it():
    g = flying()
    yaw = g.commander.yaw
    g.goto(1.0, 0.0, 2.5)
    assert g.commander.yaw == yaw
    g.goto(1.0, 0.0, 2.5, yaw=math.pi / 2)  # heading east (NED, radians as PX4 reads it)
    assert abs(g.commander.yaw) < 1e-6  # ENU yaw 0 is east (param4 is a float32)


def test_goto_int32_max_keeps_the_horizontal_goal():
    g = flying()
    g.goto(2.0, 0.0, 2.5)
    out = g.command_int(REPOSITION, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, 2**31 - 1, 2**31 - 1, 3.5, -1, 1, 0, math.nan)
    assert ack(out, REPOSITION) == M.MAV_RESULT_ACCEPTED
    g.run(8)
    assert np.allclose(g.position, [2.0, 0.0, 3.5], atol=0.02)


def test_goto_refusals():
    g = Gcs()
    g.run(0.1)
    out = g.goto(1.0, 0.0, 2.0)
    assert ack(out, REPOSITION) == M.MAV_RESULT_DENIED and "Goto denied: disarmed" in texts(out)
    g.arm()
    out = g.goto(1.0, 0.0, 2.0)
    assert ack(out, REPOSITION) == M.MAV_RESULT_DENIED and any("landed" in t for t in texts(out))
    g = flying(GF_MAX_HOR_DIST=5.0)
    before = g.commander.mover.goal.copy()
    out = g.goto(6.0, 0.0, 2.5)
    assert ack(out, REPOSITION) == M.MAV_RESULT_DENIED and any("geofence" in t for t in texts(out))
    out = g.command_int(REPOSITION, M.MAV_FRAME_LOCAL_NED, 0, 0, 1.0, -1, 1, 0, math.nan)
    assert ack(out, REPOSITION) == M.MAV_RESULT_DENIED
    out = g.command_int(REPOSITION, M.MAV_FRAME_GLOBAL, 950_000_000, 0, 500.0, -1, 1, 0, math.nan)
    assert ack(out, REPOSITION) == M.MAV_RESULT_DENIED
    out = g.command(REPOSITION, -1, 1, 0, math.nan, 47.4, 8.5, 490.0)  # float lat/lon: too coarse
    assert ack(out, REPOSITION) == M.MAV_RESULT_COMMAND_INT_ONLY
    assert np.array_equal(g.commander.mover.goal, before)  # no refused goto moved the goal


# --- land, return -------------------------------------------------------------------------------


def test_land_descends_here_and_disarms_on_the_ground():
    g = flying()
    g.goto(1.0, 1.0, 2.5)
    g.run(5)
    out = g.command(LAND, *NAN7)
    assert ack(out, LAND) == M.MAV_RESULT_ACCEPTED and g.commander.mode == (4, 6)
    g.run(1)
    assert g.commander.landed_state == M.MAV_LANDED_STATE_LANDING
    g.run(20, until=lambda g: not g.commander.armed)
    assert not g.commander.armed and np.allclose(g.position, [1.0, 1.0, 0.0], atol=0.02)


def test_land_disarmed_is_denied():
    g = Gcs()
    g.run(0.1)
    out = g.command(LAND, *NAN7)
    assert ack(out, LAND) == M.MAV_RESULT_DENIED and "Land denied: disarmed" in texts(out)


def test_return_climbs_returns_and_lands_at_home():
    g = flying(RTL_RETURN_ALT=4.0, RTL_DESCEND_ALT=3.0, RTL_CONE_ANG=0, RTL_MIN_DIST=0.5)
    g.goto(3.0, 0.0, 2.5)
    g.run(6)
    assert ack(g.command(RTL), RTL) == M.MAV_RESULT_ACCEPTED and g.commander.mode == (4, 5)
    top = 0.0
    while g.commander.armed and g.now < 60:
        g.run(0.1)
        top = max(top, g.position[2])
    assert abs(top - 4.0) <= 0.05  # climbed to RTL_RETURN_ALT first
    assert not g.commander.armed and np.allclose(g.position, [0.0, 0.0, 0.0], atol=0.02)


def test_return_on_the_ground_is_denied():
    g = Gcs()
    g.run(0.1)
    g.arm()
    out = g.command(RTL)
    assert ack(out, RTL) == M.MAV_RESULT_DENIED and any("landed" in t for t in texts(out))


# --- modes --------------------------------------------------------------------------------------


def test_set_mode_px4_custom_modes():
    g = flying(RTL_RETURN_ALT=3.0, RTL_DESCEND_ALT=3.0)
    for sub in (6, 5, 3):  # LAND, RTL, LOITER (Hold)
        out = g.set_mode(4, sub)
        assert ack(out, SET_MODE) == M.MAV_RESULT_ACCEPTED
        assert custom(of_type(out, "HEARTBEAT")[-1]) == (4, sub)
    out = g.set_mode(3)
    assert ack(out, SET_MODE) == M.MAV_RESULT_ACCEPTED and g.commander.mode == (3, 0)


def test_set_mode_refusals():
    g = flying()
    for out in (g.set_mode(6), g.set_mode(4, 8)):  # OFFBOARD, AUTO/FOLLOW_TARGET
        assert ack(out, SET_MODE) == M.MAV_RESULT_DENIED and any("not supported" in t for t in texts(out))
    out = g.command(SET_MODE, 0, 4, 3)  # base_mode without CUSTOM_MODE_ENABLED
    assert ack(out, SET_MODE) == M.MAV_RESULT_DENIED
    out = g.set_mode(4, 4)  # MISSION without a mission
    assert ack(out, SET_MODE) == M.MAV_RESULT_DENIED and "Mission denied: no mission uploaded" in texts(out)
    assert g.commander.mode == (4, 3)


def test_set_mode_takeoff_disarmed_is_denied():
    g = Gcs()
    g.run(0.1)
    out = g.set_mode(4, 2)
    assert ack(out, SET_MODE) == M.MAV_RESULT_DENIED and g.commander.mode == (4, 3)


def test_set_mode_message_is_acknowledged_as_do_set_mode():
    g = flying()
    out = g.send(g.tx.set_mode_encode(1, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4 << 16 | 6 << 24))
    assert ack(out, SET_MODE) == M.MAV_RESULT_ACCEPTED and g.commander.mode == (4, 6)


def test_mission_start_runs_the_uploaded_mission_and_refuses_without_one():
    g = flying()
    out = g.command(M.MAV_CMD_MISSION_START, 0, 0)
    assert ack(out, M.MAV_CMD_MISSION_START) == M.MAV_RESULT_DENIED
    upload(g, [mission_item(0, M.MAV_CMD_NAV_WAYPOINT, 1, 0, 2.5), mission_item(1, M.MAV_CMD_NAV_WAYPOINT, 1, 1, 2.5)])
    out = g.command(M.MAV_CMD_MISSION_START, 5, 0)
    assert ack(out, M.MAV_CMD_MISSION_START) == M.MAV_RESULT_DENIED
    out = g.command(M.MAV_CMD_MISSION_START, 1, 1)
    assert ack(out, M.MAV_CMD_MISSION_START) == M.MAV_RESULT_ACCEPTED and g.commander.mode == (4, 4)
    assert of_type(out, "MISSION_CURRENT")[-1].seq == 1


# --- speed --------------------------------------------------------------------------------------


def test_change_speed_bounds_the_reference_speed_and_refuses_nonsense():
    g = flying()
    out = g.command(M.MAV_CMD_DO_CHANGE_SPEED, 1, 0.5, -1)
    assert ack(out, M.MAV_CMD_DO_CHANGE_SPEED) == M.MAV_RESULT_ACCEPTED
    g.goto(4.0, 0.0, 2.5)
    g.run(2)
    assert np.linalg.norm(g.commander.mover.velocity) <= 0.5 + 1e-9
    for bad in ((1, -3.0), (7, 1.0), (1, math.nan)):
        out = g.command(M.MAV_CMD_DO_CHANGE_SPEED, *bad)
        assert ack(out, M.MAV_CMD_DO_CHANGE_SPEED) == M.MAV_RESULT_DENIED


# --- telemetry requests -------------------------------------------------------------------------


def test_request_message_sends_the_message_then_the_ack():
    g = Gcs()
    out = g.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION)
    assert ack(out, M.MAV_CMD_REQUEST_MESSAGE) == M.MAV_RESULT_TEMPORARILY_REJECTED  # no home yet
    g.run(0.1)
    for msg_id, kind in (
        (M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, "AUTOPILOT_VERSION"),
        (M.MAVLINK_MSG_ID_HOME_POSITION, "HOME_POSITION"),
    ):
        out = g.command(M.MAV_CMD_REQUEST_MESSAGE, msg_id)
        assert [m.get_type() for m in out] == [kind, "COMMAND_ACK"] and out[1].result == M.MAV_RESULT_ACCEPTED
    home = out[0]
    assert (home.latitude, home.longitude, home.altitude) == local_to_geodetic((0, 0, 0), HOME)
    version = of_type(g.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION), "AUTOPILOT_VERSION")[0]
    assert version.capabilities & M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    assert version.capabilities & M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    out = g.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HIGHRES_IMU)  # not one this vehicle sends
    assert ack(out, M.MAV_CMD_REQUEST_MESSAGE) == M.MAV_RESULT_UNSUPPORTED


def test_get_home_position_and_capabilities():
    g = Gcs()
    assert ack(g.command(M.MAV_CMD_GET_HOME_POSITION), M.MAV_CMD_GET_HOME_POSITION) == M.MAV_RESULT_TEMPORARILY_REJECTED
    g.run(0.1)
    out = g.command(M.MAV_CMD_GET_HOME_POSITION)
    assert [m.get_type() for m in out] == ["HOME_POSITION", "COMMAND_ACK"]
    out = g.command(M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1)
    assert [m.get_type() for m in out] == ["AUTOPILOT_VERSION", "COMMAND_ACK"]


def rate(g: Gcs, kind: str, seconds: float = 4.0) -> float:
    return len(of_type(g.run(seconds), kind)) / seconds


def test_set_message_interval_changes_the_rate():
    g = Gcs()
    g.run(0.1)
    assert abs(rate(g, "EXTENDED_SYS_STATE") - 1.0) <= 0.25  # PX4's default
    out = g.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 1e6 / 5)
    assert ack(out, M.MAV_CMD_SET_MESSAGE_INTERVAL) == M.MAV_RESULT_ACCEPTED
    assert abs(rate(g, "EXTENDED_SYS_STATE") - 5.0) <= 0.5
    out = g.command(M.MAV_CMD_GET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE)
    assert of_type(out, "MESSAGE_INTERVAL")[0].interval_us == 200_000
    g.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, -1)
    assert rate(g, "EXTENDED_SYS_STATE") == 0.0
    g.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 0)
    assert abs(rate(g, "EXTENDED_SYS_STATE") - 1.0) <= 0.25


def test_set_message_interval_refusals():
    g = Gcs()
    g.run(0.1)
    out = g.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HIGHRES_IMU, 1e5)
    assert ack(out, M.MAV_CMD_SET_MESSAGE_INTERVAL) == M.MAV_RESULT_UNSUPPORTED
    out = g.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, -5)
    assert ack(out, M.MAV_CMD_SET_MESSAGE_INTERVAL) == M.MAV_RESULT_DENIED


def test_unknown_command_is_unsupported_and_foreign_commands_are_not_answered():
    g = Gcs()
    g.run(0.1)
    out = g.command(M.MAV_CMD_DO_SET_SERVO, 1, 1500)
    assert ack(out, M.MAV_CMD_DO_SET_SERVO) == M.MAV_RESULT_UNSUPPORTED
    out = g.send(g.tx.command_long_encode(2, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0))  # for system 2
    assert out == [] and not g.commander.armed


# --- one answer for anything --------------------------------------------------------------------

COMMANDS = [
    ARM,
    TAKEOFF,
    LAND,
    RTL,
    REPOSITION,
    SET_MODE,
    M.MAV_CMD_MISSION_START,
    M.MAV_CMD_DO_CHANGE_SPEED,
    M.MAV_CMD_REQUEST_MESSAGE,
    M.MAV_CMD_SET_MESSAGE_INTERVAL,
    M.MAV_CMD_GET_MESSAGE_INTERVAL,
    M.MAV_CMD_GET_HOME_POSITION,
    M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
    M.MAV_CMD_DO_SET_SERVO,
]
FLOATS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=32), st.sampled_from([0.0, 1.0, 4.0, 21196.0, -1.0])
)


@settings(derandomize=True, database=None, deadline=None, max_examples=300)
@given(
    armed=st.booleans(),
    as_int=st.booleans(),
    command=st.sampled_from(COMMANDS),
    params=st.lists(FLOATS, min_size=7, max_size=7),
    frame=st.sampled_from([0, 1, 3, 5, 6, 11]),
    xy=st.tuples(st.integers(-(2**31), 2**31 - 1), st.integers(-(2**31), 2**31 - 1)),
)
def test_every_command_gets_exactly_one_ack_and_never_a_nonfinite_setpoint(armed, as_int, command, params, frame, xy):
    g = Gcs()
    g.run(0.05)
    if armed:
        g.arm()
    if as_int:
        out = g.command_int(command, frame, xy[0], xy[1], params[6], *params[:4])
    else:
        out = g.command(command, *params)
    assert ack(out, command) in (0, 1, 2, 3, 4, 8)
    g.run(0.05)
    sp = g.commander.setpoint
    assert np.all(np.isfinite(sp.position)) and np.all(np.isfinite(sp.velocity)) and math.isfinite(sp.yaw)
    assert g.commander.dropped["command_error"] == 0  # no handler fell over (FAILED)


def test_commander_builds_messages_for_its_own_system_id():
    c = Commander()
    assert (c.mav.srcSystem, c.mav.srcComponent) == (1, 1)


def test_ping_requests_are_answered_to_the_sender():
    g = Gcs()
    out = g.send(g.tx.ping_encode(123456, 7, 0, 0))  # MAVSDK measures the link with these
    (pong,) = of_type(out, "PING")
    assert (pong.time_usec, pong.seq, pong.target_system, pong.target_component) == (123456, 7, 255, 190)
