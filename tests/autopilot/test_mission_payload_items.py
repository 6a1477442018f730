"""Gimbal, mount and camera mission items on a vehicle with neither (autopilot.mission_protocol.PAYLOAD_COMMANDS):
accepted in an upload and downloaded as sent, reported current and reached in their order as PX4
reports its instantly completed "do" items, flown as nothing (the vehicle goes straight from
waypoint to waypoint), while items that would move or turn the vehicle stay refused. The missions
here are laid out as MAVSDK 4.x's Mission plugin lays out MAVSDK's own mission.py example
(cpp/src/mavsdk/plugins/mission/mission_impl.cpp, convert_to_int_items: a waypoint, then its speed,
gimbal and camera items, all in frame 2 MISSION)."""

import math

import numpy as np
import pytest
from commander_gcs import Gcs, mission_item, of_type, upload
from pymavlink.dialects.v20 import common as M

from quadpilot.autopilot import mission_protocol as missions

WP, SPEED = M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_DO_CHANGE_SPEED
CONFIGURE, PITCHYAW = M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
PHOTO, VIDEO, VIDEO_STOP = M.MAV_CMD_IMAGE_START_CAPTURE, M.MAV_CMD_VIDEO_START_CAPTURE, M.MAV_CMD_VIDEO_STOP_CAPTURE
GIMBAL_FLAGS = M.GIMBAL_MANAGER_FLAGS_ROLL_LOCK | M.GIMBAL_MANAGER_FLAGS_PITCH_LOCK  # MAVSDK's, in x


def payload_item(seq: int, command: int, p=(0.0, 0.0, 0.0, 0.0), x: int = 0) -> dict:
    """A no-position item as MAVSDK sends it: frame 2 MISSION, z NaN (gimbal items: z 0, x the flags)."""
    item = mission_item(seq, command, 0.0, 0.0, 0.0, M.MAV_FRAME_MISSION)
    z = 0.0 if command in (CONFIGURE, PITCHYAW) else math.nan
    return {**item, "param1": p[0], "param2": p[1], "param3": p[2], "param4": p[3], "x": x, "y": 0, "z": z}


def mavsdk_mission() -> list[dict]:
    """Two waypoints with MAVSDK's companions: speed, gimbal control taken, pitch/yaw, a photo and a
    video start at the second, gimbal control released at the end (seqs 0..8)."""
    return [
        mission_item(0, WP, 0.0, 3.0, 2.0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, param1=0.5, param2=1.0, param4=0.0),
        payload_item(1, SPEED, (1.0, 5.0, -1.0, 0.0)),
        payload_item(2, CONFIGURE, (-2.0, -2.0, -1.0, -1.0)),
        payload_item(3, PITCHYAW, (20.0, 60.0, math.nan, math.nan), x=GIMBAL_FLAGS),
        mission_item(4, WP, 2.0, 3.0, 2.0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, param2=1.0, param4=0.0),
        payload_item(5, PITCHYAW, (0.0, -60.0, math.nan, math.nan), x=GIMBAL_FLAGS),
        payload_item(6, PHOTO, (0.0, 0.0, 1.0, 0.0)),
        payload_item(7, VIDEO, (0.0, 0.0, math.nan, math.nan)),
        payload_item(8, CONFIGURE, (-3.0, -3.0, -1.0, -1.0)),
    ]


def acks(msgs) -> list[int]:
    return [m.type for m in of_type(msgs, "MISSION_ACK")]


@pytest.mark.parametrize("command", sorted(missions.PAYLOAD_COMMANDS))
def test_each_gimbal_and_camera_item_is_accepted_and_downloaded_as_sent(command):
    g = Gcs()
    sent = [mission_item(0, WP, 0.0, 1.0, 2.0), payload_item(1, command, (1.0, 2.0, 3.0, 4.0), x=12)]
    assert acks(upload(g, sent)) == [M.MAV_MISSION_ACCEPTED]
    out = g.send(g.tx.mission_request_int_encode(1, 1, 1, M.MAV_MISSION_TYPE_MISSION))
    (got,) = of_type(out, "MISSION_ITEM_INT")
    assert (got.command, got.frame, got.param1, got.param4, got.x) == (command, M.MAV_FRAME_MISSION, 1.0, 4.0, 12)


def test_mavsdks_mission_example_layout_uploads():
    g = Gcs()
    assert acks(upload(g, mavsdk_mission())) == [M.MAV_MISSION_ACCEPTED]
    assert [it.command for it in g.commander.missions.items] == [it["command"] for it in mavsdk_mission()]


@pytest.mark.parametrize(
    "command",
    [
        M.MAV_CMD_DO_SET_ROI_LOCATION,  # turns the vehicle towards a point
        M.MAV_CMD_DO_SET_ROI_NONE,
        M.MAV_CMD_DO_JUMP,
        M.MAV_CMD_NAV_LOITER_UNLIM,
        M.MAV_CMD_DO_VTOL_TRANSITION,
        M.MAV_CMD_DO_SET_SERVO,
    ],
)
def test_items_that_would_move_or_actuate_the_vehicle_stay_refused(command):
    g = Gcs()
    out = upload(g, [mission_item(0, WP, 0.0, 1.0, 2.0), payload_item(1, command)])
    assert acks(out) == [M.MAV_MISSION_UNSUPPORTED] and g.commander.missions.items == []


def test_gimbal_and_camera_items_are_reached_in_order_at_once_and_fly_nothing():
    g = Gcs()
    g.run(0.5)
    upload(g, mavsdk_mission())
    g.arm()
    g.set_mode(4, 4)  # MAVSDK's start_mission, on the ground: take-off first
    out, track, reached_at = [], [], {}
    while g.commander.mission_state != M.MISSION_STATE_COMPLETE and g.now < 60.0:
        step = g.run(g.dt)
        out += step
        track.append(g.position)
        for m in of_type(step, "MISSION_ITEM_REACHED"):
            reached_at.setdefault(m.seq, len(track))  # the control step it was first reported at
    assert list(reached_at) == list(range(9))  # every item, in order
    currents = [m.seq for m in of_type(out, "MISSION_CURRENT")]
    assert currents == sorted(currents) and set(range(9)) <= set(currents)
    # done at once: one control step per item after the waypoint before it (PX4: one navigator cycle)
    assert [reached_at[s] - reached_at[0] for s in (1, 2, 3)] == [1, 2, 3]
    assert [reached_at[s] - reached_at[4] for s in (5, 6, 7, 8)] == [1, 2, 3, 4]
    # flown as nothing: from waypoint 0 straight east to waypoint 4 at the same north and height (a
    # payload item flown as a position would head for its x, y: near latitude 0, longitude 0)
    after_wp0 = np.array(track[reached_at[0] :])
    assert np.all(np.abs(after_wp0[:, 1] - 3.0) < 0.3) and np.all(np.abs(after_wp0[:, 2] - 2.0) < 0.3)
    assert np.allclose(g.position, [2.0, 3.0, 2.0], atol=0.3)
    assert g.commander.mode == (4, 3) and g.commander.armed  # the end holds, as after any mission
