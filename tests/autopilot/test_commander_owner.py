"""What the commander's owner (the node) may tell it outside the ground station's protocol: the vehicle
started in the air (`arm_in_air`, before any step, so that the first heartbeat already says armed),
and its own failsafe cut the motors (`motors_cut`: disarmed, CRITICAL, said with a STATUSTEXT); and the
ground-station link that hands it messages (`autopilot.ground_station`) survives a defect in it."""

import time

import numpy as np
import pytest
from commander_gcs import Gcs, of_type, texts
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M

from quadpilot.autopilot.commander import BadVehicleState, Commander
from quadpilot.autopilot.ground_station import GroundStation
from quadpilot.link.frames import Home

ARMED = M.MAV_MODE_FLAG_SAFETY_ARMED


def test_arm_in_air_before_the_first_step_makes_the_first_heartbeat_armed():
    g = Gcs()
    g.vehicle.state[0:3] = [1.0, -2.0, 2.0]
    g.commander.arm_in_air(g.vehicle.state)
    first = of_type(g.run(0.01), "HEARTBEAT")
    assert first and all(m.base_mode & ARMED for m in first)
    sp = g.commander.setpoint
    assert sp.armed and sp.motors_enabled and np.allclose(sp.position, [1.0, -2.0, 2.0])
    g.run(2.0)
    assert g.commander.armed and np.allclose(g.position, [1.0, -2.0, 2.0], atol=0.01)  # holding, not landed


def test_arm_in_air_refuses_a_state_that_cannot_be_one():
    c = Commander()
    with pytest.raises(BadVehicleState, match="expected 12 finite numbers"):
        c.arm_in_air(np.full(12, np.nan))
    with pytest.raises(ValueError, match="needs the vehicle's state"):
        c.arm_in_air()
    assert not c.armed


def test_motors_cut_reports_disarmed_and_critical_and_no_ground_station_message_undoes_it():
    g = Gcs()
    g.vehicle.state[0:3] = [0.0, 0.0, 2.0]
    g.commander.arm_in_air(g.vehicle.state)
    g.run(1.0)
    out = g._from_vehicle(g.commander.motors_cut("simulator closed the link"))
    (beat,) = of_type(out, "HEARTBEAT")
    assert not beat.base_mode & ARMED and beat.system_status == M.MAV_STATE_CRITICAL
    (text,) = of_type(out, "STATUSTEXT")
    assert text.severity == M.MAV_SEVERITY_CRITICAL and text.text == "Failsafe: simulator closed the link"
    assert not g.commander.armed and not g.commander.setpoint.motors_enabled
    later = g.send(g.tx.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0))
    assert not texts(later) and g.commander.heartbeat().system_status == M.MAV_STATE_CRITICAL


class _Refuses(Commander):
    """A commander with a defect: every message it is handed raises."""

    def handle(self, msg, now):
        raise RuntimeError("defect")


def test_the_ground_station_link_counts_a_message_the_commander_cannot_take_and_goes_on():
    client = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255)
    port = client.port.getsockname()[1]
    gcs = GroundStation(f"udp:127.0.0.1:{port}", Home(), 0.01, 25.0, commander=_Refuses())
    try:
        gcs.send([gcs.commander.heartbeat()])  # the ground station hears the vehicle first, then answers
        assert client.recv_match(type="HEARTBEAT", blocking=True, timeout=2) is not None
        for _ in range(3):
            client.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        deadline = time.monotonic() + 2
        while gcs.received < 3 and time.monotonic() < deadline:
            gcs.serve(0.0)
        assert gcs.received == 3 and gcs.dropped == {"commander_error: RuntimeError": 3}
    finally:
        gcs.close()
        client.close()
