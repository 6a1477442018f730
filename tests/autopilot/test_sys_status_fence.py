"""SYS_STATUS and the geofence: the vehicle has no fence (present and enabled bits clear) and so
none breached (the health bit set). MAVLink reads a health bit of 0 as an error, and MAVProxy's
fence module says "fence breach" on the first SYS_STATUS without it (tests/sitl/test_mavproxy_fence.py
hears it from real MAVProxy); the commander's SYS_STATUS and the telemetry-only one alike."""

from commander_gcs import Gcs, of_type
from pymavlink.dialects.v20 import common as M

from quadpilot.link import wire

FENCE = M.MAV_SYS_STATUS_GEOFENCE


def _fence_bits(status) -> tuple[bool, bool, bool]:
    return tuple(
        bool(bits & FENCE)
        for bits in (
            status.onboard_control_sensors_present,
            status.onboard_control_sensors_enabled,
            status.onboard_control_sensors_health,
        )
    )


def test_the_commanders_sys_status_has_no_fence_and_none_breached():
    g = Gcs()
    statuses = of_type(g.run(2.1), "SYS_STATUS")
    g.arm()
    statuses += of_type(g.run(1.1), "SYS_STATUS")
    assert len(statuses) >= 3
    assert {_fence_bits(s) for s in statuses} == {(False, False, True)}


def test_the_telemetry_sys_status_has_no_fence_and_none_breached():
    fields = wire.sys_status_fields(M.MAV_SYS_STATUS_SENSOR_3D_GYRO, errors=0, received=10)
    status = M.MAVLink_sys_status_message(**fields)
    assert _fence_bits(status) == (False, False, True)
    assert fields["onboard_control_sensors_present"] == M.MAV_SYS_STATUS_SENSOR_3D_GYRO  # nothing else claimed
