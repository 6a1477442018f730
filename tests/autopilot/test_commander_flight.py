"""End to end through the state machine: a ground station commands a point-mass stand-in (position
follows the setpoint with a first-order lag; it drives the logic, it is not a flight model) over
packed MAVLink bytes: arm, take off to 2.5 m, go 3 m, fly a 3-item mission, land, and end landed and
disarmed; the telemetry a ground station judges that by; link loss; auto-disarm."""

import math

import numpy as np
import pytest
from commander_gcs import HOME, Gcs, ack, mission_item, of_type, texts, upload
from pymavlink.dialects.v20 import common as M

from quadpilot.autopilot.commander import BadVehicleState, Commander
from quadpilot.link.frames import geodetic_to_local

WP = M.MAV_CMD_NAV_WAYPOINT


def flying_at(altitude: float) -> Gcs:
    g = Gcs(MIS_TAKEOFF_ALT=altitude)
    g.run(0.2)
    g.arm()
    g.takeoff()
    g.run(15, until=lambda g: g.commander.mode == (4, 3))
    return g


def landed_states(msgs) -> list[int]:
    out = []
    for m in of_type(msgs, "EXTENDED_SYS_STATE"):
        if not out or out[-1] != m.landed_state:
            out.append(m.landed_state)
    return out


def test_arm_takeoff_goto_mission_land_ends_landed_and_disarmed():
    g = Gcs()
    log = g.run(1.0)
    assert ack(g.param_set("MIS_TAKEOFF_ALT", 2.5) + g.arm(), M.MAV_CMD_COMPONENT_ARM_DISARM) == 0
    assert ack(g.takeoff(), M.MAV_CMD_NAV_TAKEOFF) == M.MAV_RESULT_ACCEPTED
    log += g.run(15, until=lambda g: g.commander.mode == (4, 3))
    assert abs(g.position[2] - 2.5) <= 0.15
    assert ack(g.goto(3.0, 0.0, 2.5), M.MAV_CMD_DO_REPOSITION) == M.MAV_RESULT_ACCEPTED
    log += g.run(10)
    assert np.linalg.norm(g.position - [3.0, 0.0, 2.5]) <= 0.15
    items = [
        mission_item(0, WP, 3.0, 2.0, 2.5, param1=0.5),  # MAVSDK 4.1.0: frame 3, hold 0.5 s
        mission_item(1, WP, 1.0, 2.0, 3.0, param1=0.5),
        mission_item(2, WP, 1.0, 0.0, 2.5, param1=0.5),
    ]
    assert of_type(upload(g, items), "MISSION_ACK")[0].type == M.MAV_MISSION_ACCEPTED
    out = g.set_mode(4, 4)
    assert ack(out, M.MAV_CMD_DO_SET_MODE) == M.MAV_RESULT_ACCEPTED
    arrivals = []
    while g.commander.mission_state != M.MISSION_STATE_COMPLETE and g.now < 80:
        step = g.run(0.01)
        arrivals += [(m.seq, g.position.copy()) for m in of_type(step, "MISSION_ITEM_REACHED")]
        log += step
    first = {}
    for seq, pos in arrivals:
        first.setdefault(seq, pos)
    assert sorted(first) == [0, 1, 2]
    for seq, pos in first.items():
        goal = geodetic_to_local(items[seq]["x"], items[seq]["y"], 0, HOME)
        goal[2] = items[seq]["z"]
        assert np.linalg.norm(pos - goal) <= 0.15, (seq, pos, goal)
    out = g.command(M.MAV_CMD_NAV_LAND, *[math.nan] * 7)
    assert ack(out, M.MAV_CMD_NAV_LAND) == M.MAV_RESULT_ACCEPTED
    log += g.run(30, until=lambda g: not g.commander.armed)
    log += g.run(1.5)
    assert not g.commander.armed and g.position[2] == 0.0
    hb = of_type(log, "HEARTBEAT")[-1]
    assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert landed_states(log) == [
        M.MAV_LANDED_STATE_ON_GROUND,
        M.MAV_LANDED_STATE_TAKEOFF,
        M.MAV_LANDED_STATE_IN_AIR,
        M.MAV_LANDED_STATE_LANDING,
        M.MAV_LANDED_STATE_ON_GROUND,
    ]
    said = texts(log)
    assert said.index("Takeoff detected") < said.index("Landing detected") < said.index("Disarmed by landing")


def test_any_distance_is_flown_with_the_target_within_the_lead():
    g = Gcs()
    g.run(0.2)
    g.arm()
    g.takeoff()
    g.run(15, until=lambda g: g.commander.mode == (4, 3))
    g.goto(40.0, -30.0, 6.0)
    worst = 0.0
    while g.now < 120 and np.linalg.norm(g.position - [40.0, -30.0, 6.0]) > 0.05:
        g.run(0.01)
        worst = max(worst, float(np.linalg.norm(g.commander.setpoint.position - g.position)))
    assert np.linalg.norm(g.position - [40.0, -30.0, 6.0]) <= 0.05
    assert worst <= g.commander.cfg.lead_m + 0.06  # 0.75 m plus one step at MPC_XY_CRUISE (5 m/s)


def test_telemetry_a_ground_station_needs():
    g = Gcs()
    log = g.run(4.1)
    status = of_type(log, "SYS_STATUS")[-1]
    gps = M.MAV_SYS_STATUS_SENSOR_GPS
    assert status.onboard_control_sensors_present & gps and status.onboard_control_sensors_enabled & gps
    assert status.onboard_control_sensors_health & gps  # MAVSDK: is_global_position_ok
    assert status.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK  # MAVSDK: is_armable
    assert of_type(log, "GPS_RAW_INT")[-1].fix_type == M.GPS_FIX_TYPE_3D_FIX
    assert len(of_type(log, "HOME_POSITION")) == 3  # 0.5 Hz (t = 0, 2, 4)
    assert len(of_type(log, "GLOBAL_POSITION_INT")) >= 20  # 5 Hz
    assert len(of_type(log, "HEARTBEAT")) == 5
    g.vehicle.state[0:3] = [2.0, 1.0, 0.0]
    log = g.run(0.3)
    pos = of_type(log, "GLOBAL_POSITION_INT")[-1]
    assert np.allclose(geodetic_to_local(pos.lat, pos.lon, pos.alt, HOME), [2.0, 1.0, 0.0], atol=0.01)


def test_link_loss_holds_then_lands():
    g = Gcs(COM_DL_LOSS_T=5, COM_FAIL_ACT_T=3.0)
    g.run(0.5)
    g.arm()
    g.takeoff()
    g.run(15, until=lambda g: g.commander.mode == (4, 3))
    g.goto(30.0, 0.0, 2.5)
    last = g.now  # the ground station's last message (the heartbeat of the next run is sent now too)
    g.run(0.5)
    log = g.run(10, heartbeat=False, until=lambda g: g.commander.failsafe is not None)
    assert abs(g.now - last - 5.0) <= 0.03  # COM_DL_LOSS_T (to a step or two)
    assert "Connection to ground station lost" in texts(log) and g.position[0] < 25.0  # stopped mid-goto
    assert g.commander.mode == (4, 3) and of_type(log, "HEARTBEAT")[-1].system_status == M.MAV_STATE_CRITICAL
    lost, held = g.now, g.position.copy()
    log = g.run(10, heartbeat=False, until=lambda g: g.commander.mode != (4, 3))
    assert abs(g.now - lost - 3.0) <= 0.03  # COM_FAIL_ACT_T of hold
    assert np.linalg.norm(g.position - held) < 0.75 and g.commander.mode == (4, 6)
    assert "Failsafe activated: Land" in texts(log)
    g.run(30, heartbeat=False, until=lambda g: not g.commander.armed)
    assert not g.commander.armed and g.position[2] == 0.0 and abs(g.position[0] - held[0]) < 0.75


def test_link_back_during_the_hold_resumes_the_goto():
    g = Gcs(COM_DL_LOSS_T=5, COM_FAIL_ACT_T=5.0)
    g.run(0.5)
    g.arm()
    g.takeoff()
    g.run(15, until=lambda g: g.commander.mode == (4, 3))
    g.goto(20.0, 0.0, 2.5)
    g.run(0.3)
    g.run(5.5, heartbeat=False)
    assert g.commander.failsafe == "hold" and g.position[0] < 15.0
    log = g.run(15)  # heartbeats again
    assert "Ground station connection regained" in texts(log) and g.commander.failsafe is None
    assert np.linalg.norm(g.position - [20.0, 0.0, 2.5]) <= 0.05


def test_motors_idle_from_ground_contact_on_during_a_landing():
    """A policy has no thrust ramp-down: the commander idles the motors once the land detector has
    ground contact, a stage before it declares the vehicle landed."""
    g = flying_at(1.0)
    g.command(M.MAV_CMD_NAV_LAND, *[math.nan] * 7)
    idle_at = landed_at = None
    while g.commander.armed and g.now < 30:
        log = g.run(0.01)
        if idle_at is None and not g.commander.setpoint.motors_enabled:
            idle_at = g.now
        if "Landing detected" in texts(log):
            landed_at = g.now
    assert idle_at is not None and landed_at is not None and landed_at - idle_at >= 0.6  # two stages of 1/3 s


def test_no_link_loss_failsafe_when_disabled_or_on_the_ground():
    g = Gcs(NAV_DLL_ACT=0, COM_DL_LOSS_T=5)
    g.run(0.5)
    g.arm()
    g.takeoff()
    g.run(15, until=lambda g: g.commander.mode == (4, 3))
    g.run(8, heartbeat=False)
    assert g.commander.failsafe is None and g.commander.mode == (4, 3)
    g = Gcs(COM_DL_LOSS_T=5)
    g.run(8, heartbeat=False)  # disarmed on the ground: nothing to do
    assert g.commander.failsafe is None


def test_armed_without_taking_off_disarms_after_com_disarm_prflt():
    g = Gcs(COM_DISARM_PRFLT=3.0)
    g.run(0.2)
    g.arm()
    log = g.run(2.5)
    assert g.commander.armed and not g.commander.setpoint.motors_enabled  # idle on the ground
    log = g.run(1.0)
    assert not g.commander.armed and "Disarmed by auto preflight disarming" in texts(log)


def test_arm_in_air_holds_where_a_simulator_started_the_vehicle():
    g = Gcs()
    g.vehicle.state[0:3] = [1.0, 2.0, 2.0]  # a simulator that starts its vehicle in the air
    g.run(0.01)
    g.commander.arm_in_air()
    sp = g.commander.setpoint
    assert g.commander.armed and not g.commander.landed and sp.motors_enabled
    assert np.allclose(sp.position, [1.0, 2.0, 2.0], atol=1e-3) and g.commander.mode == (4, 3)
    g.run(3)
    assert np.allclose(g.position, [1.0, 2.0, 2.0], atol=0.01)  # held, not landed by the detector
    g.command(M.MAV_CMD_NAV_LAND, *[math.nan] * 7)
    g.run(20, until=lambda g: not g.commander.armed)
    assert not g.commander.armed and np.allclose(g.position, [1.0, 2.0, 0.0], atol=0.02)


def test_mission_mode_chosen_on_the_ground_starts_when_armed():
    g = Gcs()
    g.run(0.2)
    upload(g, [mission_item(0, WP, 1.0, 0.0, 2.0), mission_item(1, M.MAV_CMD_NAV_LAND, 1.0, 0.0, 0.0)])
    assert ack(g.set_mode(4, 4), M.MAV_CMD_DO_SET_MODE) == M.MAV_RESULT_ACCEPTED  # PX4 allows it disarmed
    g.run(1)
    assert g.position[2] == 0.0 and g.commander.mission_state == M.MISSION_STATE_NOT_STARTED
    g.arm()  # PX4: arming in Mission mode starts the mission (with a take-off from the ground)
    log = g.run(30, until=lambda g: not g.commander.armed)
    assert {m.seq for m in of_type(log, "MISSION_ITEM_REACHED")} == {0, 1}
    assert not g.commander.armed and np.allclose(g.position, [1.0, 0.0, 0.0], atol=0.02)


def test_a_state_that_cannot_be_one_is_refused_in_one_line():
    c = Commander()
    for state, thrust in ((np.full(12, np.nan), 0.0), (np.zeros(11), 0.0), (np.zeros(12), math.inf)):
        with pytest.raises(BadVehicleState, match="expected"):
            c.step(state, HOME, 0.0, thrust)
    assert np.all(np.isfinite(c.setpoint.position))
