"""The mission protocol through packed MAVLink bytes: upload, download and clear round trips (with
MAVSDK 4.1.0's frame 3, newer MAVSDK's frame 6, and AMSL frame 0), sequence errors, bad items,
time-outs, and the progress messages a mission is finished by."""

import math

import numpy as np
import pytest
from commander_gcs import HOME, Gcs, ack, mission_item, of_type, texts, upload
from pymavlink.dialects.v20 import common as M

WP, TKO, LND, RTL = M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_RETURN_TO_LAUNCH
FIELDS = ("seq", "frame", "command", "autocontinue", "param1", "param2", "param3", "param4", "x", "y", "z")


def three(frame=M.MAV_FRAME_GLOBAL_RELATIVE_ALT) -> list[dict]:
    return [
        mission_item(0, WP, 2.0, 0.0, 2.5, frame, param2=0.1),
        mission_item(1, WP, 2.0, 2.0, 3.0, frame, param1=1.0),
        mission_item(2, WP, 0.0, 2.0, 2.5, frame, param4=90.0),
    ]


def download(g: Gcs) -> list:
    count = of_type(g.send(g.tx.mission_request_list_encode(1, 1, M.MAV_MISSION_TYPE_MISSION)), "MISSION_COUNT")[0]
    items = []
    for seq in range(count.count):
        items += of_type(
            g.send(g.tx.mission_request_int_encode(1, 1, seq, M.MAV_MISSION_TYPE_MISSION)), "MISSION_ITEM_INT"
        )
    g.send(g.tx.mission_ack_encode(1, 1, M.MAV_MISSION_ACCEPTED, M.MAV_MISSION_TYPE_MISSION))
    return items


def acks(msgs) -> list[int]:
    return [m.type for m in of_type(msgs, "MISSION_ACK")]


def same(sent: dict, got) -> bool:
    """The item as sent, after the wire's float32 fields (NaN equal to NaN)."""
    for f in FIELDS:
        a, b = sent[f], getattr(got, f)
        if isinstance(a, float):
            a = float(np.float32(a))
            if math.isnan(a) and math.isnan(b):
                continue
        if a != b:
            return False
    return True


@pytest.mark.parametrize(
    "frame", [M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_FRAME_GLOBAL]
)
def test_upload_download_clear_round_trip(frame):
    g = Gcs()
    items = three(frame)
    out = upload(g, items)
    assert [m.seq for m in of_type(out, "MISSION_REQUEST_INT")] == [0, 1, 2]
    assert acks(out) == [M.MAV_MISSION_ACCEPTED]
    assert of_type(out, "MISSION_CURRENT")[-1].total == 3
    got = download(g)
    assert len(got) == 3 and all(same(s, r) for s, r in zip(items, got, strict=True))
    out = g.send(g.tx.mission_clear_all_encode(1, 1, M.MAV_MISSION_TYPE_MISSION))
    assert acks(out) == [M.MAV_MISSION_ACCEPTED]
    assert download(g) == [] and of_type(out, "MISSION_CURRENT")[-1].mission_state == M.MISSION_STATE_NO_MISSION


def test_frames_3_6_and_0_put_the_item_at_the_same_place():
    g = Gcs()
    places = []
    for frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_FRAME_GLOBAL):
        upload(g, three(frame))
        places.append(np.array([it.local(HOME) for it in g.commander.missions.items]))
    assert np.allclose(places[0], places[1], atol=1e-3) and np.allclose(places[0], places[2], atol=1e-3)
    assert np.allclose(places[0][1], [2.0, 2.0, 3.0], atol=0.01)


def test_a_repeated_item_is_answered_by_the_request_again_and_a_wrong_one_ends_the_transfer():
    g = Gcs()
    items = three()
    g.send(g.tx.mission_count_encode(1, 1, 3, 0))
    g.send(g.tx.mission_item_int_encode(**items[0]))
    out = g.send(g.tx.mission_item_int_encode(**items[0]))  # our request for item 1 was lost
    assert [m.seq for m in of_type(out, "MISSION_REQUEST_INT")] == [1] and acks(out) == []
    out = g.send(g.tx.mission_item_int_encode(**items[2]))  # skips item 1
    assert acks(out) == [M.MAV_MISSION_INVALID_SEQUENCE]
    assert not g.commander.missions.uploading and g.commander.missions.items == []
    assert acks(upload(g, items)) == [M.MAV_MISSION_ACCEPTED]  # a fresh upload works


@pytest.mark.parametrize(
    ("change", "result"),
    [
        ({"command": M.MAV_CMD_NAV_LOITER_TURNS}, M.MAV_MISSION_UNSUPPORTED),
        ({"frame": M.MAV_FRAME_LOCAL_NED}, M.MAV_MISSION_UNSUPPORTED_FRAME),
        ({"x": 910_000_000}, M.MAV_MISSION_INVALID_PARAM5_X),
        ({"y": -1_810_000_000}, M.MAV_MISSION_INVALID_PARAM6_Y),
        ({"z": math.nan}, M.MAV_MISSION_INVALID_PARAM7),
        ({"param1": -2.0}, M.MAV_MISSION_INVALID_PARAM1),
        ({"mission_type": M.MAV_MISSION_TYPE_FENCE}, M.MAV_MISSION_UNSUPPORTED),
    ],
)
def test_a_bad_item_is_refused_with_its_error_and_the_old_mission_stays(change, result):
    g = Gcs()
    old = three()
    upload(g, old)
    items = three()
    items[1] = {**items[1], **change}
    out = upload(g, items)
    assert acks(out) == [result]
    assert [it.seq for it in g.commander.missions.items] == [0, 1, 2]
    assert all(same(s, r) for s, r in zip(old, download(g), strict=True))


def test_upload_time_out_resends_requests_then_cancels_and_resets():
    g = Gcs()
    g.run(0.1)
    items = three()
    g.send(g.tx.mission_count_encode(1, 1, 3, 0))
    g.send(g.tx.mission_item_int_encode(**items[0]))
    out = g.run(1.0)
    resent = [m.seq for m in of_type(out, "MISSION_REQUEST_INT")]
    assert resent and set(resent) == {1}  # PX4 re-requests every 250 ms
    out = g.run(5.0)
    assert acks(out) == [M.MAV_MISSION_OPERATION_CANCELLED] and "mission: upload timed out" in texts(out)
    assert not g.commander.missions.uploading
    out = g.send(g.tx.mission_item_int_encode(**items[1]))  # too late: not taken
    assert out == [] and g.commander.missions.items == []
    assert acks(upload(g, items)) == [M.MAV_MISSION_ACCEPTED]


def test_count_zero_clears_too_many_is_no_space_and_fence_is_unsupported():
    g = Gcs()
    upload(g, three())
    out = g.send(g.tx.mission_count_encode(1, 1, 0, 0))
    assert acks(out) == [M.MAV_MISSION_ACCEPTED] and g.commander.missions.items == []
    out = g.send(g.tx.mission_count_encode(1, 1, 501, 0))
    assert acks(out) == [M.MAV_MISSION_NO_SPACE]
    out = g.send(g.tx.mission_count_encode(1, 1, 2, M.MAV_MISSION_TYPE_FENCE))
    assert [(m.type, m.mission_type) for m in of_type(out, "MISSION_ACK")] == [(M.MAV_MISSION_UNSUPPORTED, 1)]
    out = g.send(g.tx.mission_request_list_encode(1, 1, M.MAV_MISSION_TYPE_RALLY))
    assert of_type(out, "MISSION_COUNT")[0].count == 0


def test_download_beyond_the_mission_is_an_invalid_sequence():
    g = Gcs()
    upload(g, three())
    out = g.send(g.tx.mission_request_int_encode(1, 1, 3, 0))
    assert acks(out) == [M.MAV_MISSION_INVALID_SEQUENCE]


def test_the_last_item_again_after_the_upload_gets_the_ack_again():
    g = Gcs()
    items = three()
    upload(g, items)
    out = g.send(g.tx.mission_item_int_encode(**items[2]))  # our ACK was lost
    assert acks(out) == [M.MAV_MISSION_ACCEPTED]


def test_float_mission_items_are_unsupported():
    g = Gcs()
    g.send(g.tx.mission_count_encode(1, 1, 1, 0))
    out = g.send(g.tx.mission_item_encode(1, 1, 0, 3, WP, 1, 1, 0, 0, 0, 0, 47.4, 8.5, 2.0, 0))
    assert acks(out) == [M.MAV_MISSION_UNSUPPORTED] and not g.commander.missions.uploading


def flying(g: Gcs) -> None:
    g.run(0.5)
    g.arm()
    g.takeoff()
    g.run(10, until=lambda g: g.commander.mode == (4, 3))


def test_mission_progress_current_and_reached_for_every_item():
    g = Gcs()
    flying(g)
    upload(g, three())
    out = g.set_mode(4, 4)  # MAVSDK's start_mission
    assert ack(out, M.MAV_CMD_DO_SET_MODE) == M.MAV_RESULT_ACCEPTED
    out += g.run(30, until=lambda g: g.commander.mission_state == M.MISSION_STATE_COMPLETE)
    reached = sorted({m.seq for m in of_type(out, "MISSION_ITEM_REACHED")})
    assert reached == [0, 1, 2]
    currents = [m.seq for m in of_type(out, "MISSION_CURRENT")]
    assert currents[0] == 0 and currents == sorted(currents) and currents[-1] == 2
    assert of_type(out, "MISSION_CURRENT")[-1].mission_state == M.MISSION_STATE_COMPLETE
    assert np.allclose(g.position, [0.0, 2.0, 2.5], atol=0.1)
    assert g.commander.mode == (4, 3) and "Mission finished" in texts(out)  # holds at the end
    assert abs(g.commander.yaw) < 1e-6  # item 2's yaw 90° (east) → ENU 0


def test_a_mission_ending_with_land_is_reached_at_touchdown_and_disarms():
    g = Gcs()
    flying(g)
    items = [mission_item(0, WP, 1.0, 0.0, 2.5), mission_item(1, LND, 1.0, 1.0, 0.0)]
    upload(g, items)
    g.set_mode(4, 4)
    out = g.run(40, until=lambda g: not g.commander.armed)
    reached = of_type(out, "MISSION_ITEM_REACHED")
    first_land = next(i for i, m in enumerate(out) if m.get_type() == "MISSION_ITEM_REACHED" and m.seq == 1)
    landing = next(i for i, m in enumerate(out) if m.get_type() == "STATUSTEXT" and m.text == "Landing detected")
    assert {m.seq for m in reached} == {0, 1} and first_land > landing
    assert not g.commander.armed and np.allclose(g.position, [1.0, 1.0, 0.0], atol=0.02)


def test_mission_started_on_the_ground_takes_off_first():
    g = Gcs(RTL_RETURN_ALT=4.0, RTL_DESCEND_ALT=3.0)
    g.run(0.5)
    upload(g, [mission_item(0, WP, 1.0, 0.0, 3.0), mission_item(1, RTL, 0, 0, 0, M.MAV_FRAME_MISSION)])
    g.arm()
    assert ack(g.set_mode(4, 4), M.MAV_CMD_DO_SET_MODE) == M.MAV_RESULT_ACCEPTED
    g.run(2)
    assert g.position[2] > 1.0 and abs(g.position[0]) < 0.05  # straight up first
    g.run(60, until=lambda g: not g.commander.armed)
    assert not g.commander.armed and np.allclose(g.position, 0.0, atol=0.02)


def test_upload_and_clear_are_denied_while_the_mission_is_flown():
    g = Gcs()
    flying(g)
    upload(g, three())
    g.set_mode(4, 4)
    g.run(0.5)
    out = g.send(g.tx.mission_count_encode(1, 1, 1, 0))
    assert acks(out) == [M.MAV_MISSION_DENIED]
    out = g.send(g.tx.mission_clear_all_encode(1, 1, 0))
    assert acks(out) == [M.MAV_MISSION_DENIED] and len(g.commander.missions.items) == 3


def test_hold_pauses_and_mission_mode_resumes():
    g = Gcs()
    flying(g)
    upload(g, three())
    g.set_mode(4, 4)
    g.run(30, until=lambda g: g.commander.mission_seq == 1)
    out = g.set_mode(4, 3)
    assert of_type(out, "MISSION_CURRENT")[-1].mission_state == M.MISSION_STATE_PAUSED
    g.run(3)
    assert g.commander.mission_seq == 1
    g.set_mode(4, 4)
    out = g.run(30, until=lambda g: g.commander.mission_state == M.MISSION_STATE_COMPLETE)
    assert {m.seq for m in of_type(out, "MISSION_ITEM_REACHED")} >= {1, 2}


def test_an_item_without_autocontinue_holds_there_until_mission_mode_again():
    """MISSION_ITEM_INT autocontinue = 0 (common.xml: "continue to next wp automatically" off):
    reached, the vehicle holds at it with the mission paused at the next item, and goes on only
    when put in Mission mode again."""
    g = Gcs()
    flying(g)
    items = three()
    items[0]["autocontinue"] = 0
    upload(g, items)
    g.set_mode(4, 4)
    out = g.run(30, until=lambda g: g.commander.mission_state != M.MISSION_STATE_ACTIVE)
    assert [m.seq for m in of_type(out, "MISSION_ITEM_REACHED")][:1] == [0]
    assert g.commander.mode == (4, 3) and g.commander.mission_seq == 1
    assert g.commander.mission_state == M.MISSION_STATE_PAUSED
    g.run(3)
    assert np.allclose(g.position, [2.0, 0.0, 2.5], atol=0.1)  # held at item 0
    g.set_mode(4, 4)
    out = g.run(30, until=lambda g: g.commander.mission_state == M.MISSION_STATE_COMPLETE)
    assert {m.seq for m in of_type(out, "MISSION_ITEM_REACHED")} >= {1, 2}
    assert np.allclose(g.position, [0.0, 2.0, 2.5], atol=0.1)
