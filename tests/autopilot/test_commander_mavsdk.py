"""MAVSDK-Python 4.1.0 (the real client, with its MAVSDK C++ library) commands the commander over UDP
loopback: connect, wait for health, a refused take-off, arm, take-off altitude 2.5 m, take off, go
3 m, upload and fly a 3-item mission, land, wait for disarm. The vehicle is the point mass of
`commander_gcs` on a pymavlink socket (`commander_udp`), simulated time at 3× the wall clock; what is
tested is the protocol as MAVSDK speaks it, not flight."""

import asyncio
import math
import socket
import time

import numpy as np
from commander_gcs import HOME
from commander_udp import UdpVehicle
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission import MissionAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.action import ActionError
from mavsdk.plugins.mission import MissionItem, MissionPlan
from mavsdk.plugins.telemetry import FlightMode, LandedState

from quadpilot.link.frames import geodetic_to_local, local_to_geodetic

NAN = math.nan
WAYPOINTS = ((3.0, 2.0, 2.5), (1.0, 2.0, 3.0), (1.0, 0.0, 2.5))  # m east, north, up from home


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def degrees(east: float, north: float, up: float) -> tuple[float, float, float]:
    lat, lon, alt_mm = local_to_geodetic((east, north, up), HOME)
    return lat * 1e-7, lon * 1e-7, alt_mm * 1e-3


async def wait_for(agen, ok, timeout: float):
    async def first():
        async for value in agen:
            if ok(value):
                return value

    return await asyncio.wait_for(first(), timeout)


async def fly(port: int, vehicle: UdpVehicle) -> dict:
    seen = {}
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        vehicle.start()
        drone = await mavsdk.first_autopilot(10)
        assert drone is not None, "no autopilot found"
        telemetry, action, mission = TelemetryAsync(drone), ActionAsync(drone), MissionAsync(drone)
        await wait_for(telemetry.subscribe_health(), lambda h: h.is_global_position_ok and h.is_home_position_ok, 10)
        try:
            await action.takeoff()
            seen["takeoff_disarmed"] = "accepted"
        except ActionError as e:
            seen["takeoff_disarmed"] = e.result.name
        await action.arm()
        await action.set_takeoff_altitude(2.5)
        seen["takeoff_alt"] = await action.get_takeoff_altitude()
        await action.takeoff()
        await wait_for(telemetry.subscribe_position(), lambda p: p.relative_altitude_m > 2.4, 15)
        await asyncio.sleep(1.0)
        seen["after_takeoff"] = vehicle.vehicle.state[0:3].copy()
        await action.goto_location(*degrees(3.0, 0.0, 2.5), NAN)
        await asyncio.sleep(3.0)
        seen["after_goto"] = vehicle.vehicle.state[0:3].copy()
        seen["mode_goto"] = await telemetry.flight_mode()
        items = [
            MissionItem(*degrees(e, n, 0.0)[:2], u, 2.0, False, NAN, NAN, None, NAN, NAN, 0.1, NAN, NAN, None)
            for e, n, u in WAYPOINTS
        ]
        await mission.upload_mission(MissionPlan(items))
        await mission.start_mission()
        start = time.monotonic()
        while not await mission.is_mission_finished():
            assert time.monotonic() - start < 30, "mission not finished"
            await asyncio.sleep(0.1)
        await action.land()
        await wait_for(telemetry.subscribe_armed(), lambda armed: not armed, 20)
        seen["landed_state"] = await telemetry.landed_state()
        seen["end"] = vehicle.vehicle.state[0:3].copy()
    finally:
        vehicle.stop.set()
        mavsdk.destroy()
    return seen


def test_mavsdk_flies_takeoff_goto_mission_land():
    port = free_udp_port()
    vehicle = UdpVehicle(port, speedup=3.0)
    seen = asyncio.run(asyncio.wait_for(fly(port, vehicle), 60))
    vehicle.join(5)
    assert vehicle.error is None
    assert seen["takeoff_disarmed"] == "COMMAND_DENIED"  # MAVSDK's denied error, not a time-out
    assert seen["takeoff_alt"] == 2.5
    assert abs(seen["after_takeoff"][2] - 2.5) <= 0.15
    assert np.linalg.norm(seen["after_goto"] - [3.0, 0.0, 2.5]) <= 0.15
    assert seen["mode_goto"] == FlightMode.HOLD
    c = vehicle.commander
    assert {it.frame for it in c.missions.items if it.command == 16} == {3}  # MAVSDK 4.1.0: GLOBAL_RELATIVE_ALT
    waypoint_seqs = [it.seq for it in c.missions.items if it.command == 16]
    for seq, (e, n, u) in zip(waypoint_seqs, WAYPOINTS, strict=True):
        assert np.linalg.norm(vehicle.reached[seq] - [e, n, u]) <= 0.15
        item = c.missions.items[seq]
        assert np.allclose(geodetic_to_local(item.x, item.y, 0, HOME)[:2], [e, n], atol=0.02)
    assert seen["landed_state"] == LandedState.ON_GROUND
    assert np.linalg.norm(seen["end"] - [1.0, 0.0, 0.0]) <= 0.15
    assert not c.armed and vehicle.heard["COMMAND_LONG"] > 0 and vehicle.heard["COMMAND_INT"] == 1
    assert set(c.dropped) <= {"not_for_us"}, c.dropped  # every message MAVSDK sent was understood
