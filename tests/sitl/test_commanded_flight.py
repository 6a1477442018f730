"""MAVSDK 4.1.0 commands `quad-sitl models/hover/policy.onnx --realtime --start landed --gcs ...`, the
shipped hover policy flying our simulator from the ground: connect, wait for health, a take-off
refused while disarmed, arm, take-off altitude 2.5 m, take off, go 3 m, upload and fly a 3-item
mission, land, wait for the disarm. Positions are what MAVSDK reports (GLOBAL_POSITION_INT, asked
for at 20 Hz); the errors are to where each command sent the vehicle.

Arrival: take-off, when the mode returns to Hold (the commander's take-off leg is done); goto, when
the vehicle has stopped (under 0.1 m/s over 0.5 s) near the goal; a mission item, when MAVSDK's
mission progress moves past it (the commander's MISSION_ITEM_REACHED). Holding: every position
reported over the 2 s after the take-off, the goto and the end of the mission."""

import asyncio
import json
import math
import time

import numpy as np
import pytest
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission import MissionAsync
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.action import ActionError
from mavsdk.plugins.mission import MissionItem, MissionPlan
from mavsdk.plugins.telemetry import FlightMode, LandedState
from mavsdk_gcs import (
    HOME,
    SHIPPED_HOVER,
    Track,
    connect,
    degrees,
    enu,
    free_udp_port,
    policy_copy,
    start_vehicle,
    stop_vehicle,
    wait_for,
)
from pymavlink import mavutil

from quadpilot.link.frames import geodetic_to_local

pytestmark = pytest.mark.sitl

NAN = math.nan
TAKEOFF = np.array([0.0, 0.0, 2.5])
GOTO = np.array([3.0, 0.0, 2.5])
WAYPOINTS = np.array([(3.0, 2.0, 2.5), (1.0, 2.0, 3.0), (1.0, 0.0, 2.5)])  # m east, north, up from home
ARRIVAL_M, HOLD_M = 0.15, 0.10
LOSS_S, HOLD_S = 5, 1.0  # COM_DL_LOSS_T (s, its minimum), COM_FAIL_ACT_T (s)


async def commanded_flight(port: int) -> dict:
    seen: dict = {"arrival_m": {}, "hold_max_m": {}}
    mavsdk, drone = await connect(port)
    track = None
    try:
        telemetry, action, mission = TelemetryAsync(drone), ActionAsync(drone), MissionAsync(drone)
        await wait_for(telemetry.subscribe_health(), lambda h: h.is_global_position_ok and h.is_home_position_ok, 20)
        await telemetry.set_rate_position(20.0)
        track = Track(telemetry)
        try:
            await action.takeoff()
            seen["takeoff_disarmed"] = "accepted"
        except ActionError as e:
            seen["takeoff_disarmed"] = e.result.name
        seen["on_ground_before"] = enu(await telemetry.position()).tolist()
        await action.arm()
        await action.set_takeoff_altitude(2.5)
        await action.takeoff()
        t0 = time.monotonic()
        await wait_for(telemetry.subscribe_position(), lambda p: p.relative_altitude_m > 2.0, 20)
        await wait_for(telemetry.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD, 20)
        seen["takeoff_s"] = time.monotonic() - t0
        seen["arrival_m"]["takeoff"] = float(np.linalg.norm(track.latest() - TAKEOFF))
        held = await track.hold(2.0)
        seen["hold_max_m"]["takeoff"] = float(np.linalg.norm(held - TAKEOFF, axis=1).max())

        t0 = time.monotonic()
        await action.goto_location(*degrees(*GOTO), NAN)
        arrived = await track.settled(GOTO, 20)
        seen["goto_s"] = time.monotonic() - t0
        seen["arrival_m"]["goto"] = float(np.linalg.norm(arrived - GOTO))
        held = await track.hold(2.0)
        seen["hold_max_m"]["goto"] = float(np.linalg.norm(held - GOTO, axis=1).max())

        items = [
            MissionItem(*degrees(e, n, 0.0)[:2], u, 2.0, False, NAN, NAN, None, NAN, NAN, 0.1, NAN, NAN, None)
            for e, n, u in WAYPOINTS
        ]
        await mission.upload_mission(MissionPlan(items))
        t0 = time.monotonic()
        await mission.start_mission()
        reached = 0
        async for progress in mission.subscribe_mission_progress():  # current moves past each reached item
            while reached < min(progress.current, len(WAYPOINTS)):
                seen["arrival_m"][f"item{reached}"] = float(np.linalg.norm(track.latest() - WAYPOINTS[reached]))
                reached += 1
            if await mission.is_mission_finished():
                break
            assert time.monotonic() - t0 < 40, "mission not finished"
        if reached < len(WAYPOINTS):  # the last item: reached when the mission is finished
            seen["arrival_m"][f"item{reached}"] = float(np.linalg.norm(track.latest() - WAYPOINTS[reached]))
        seen["mission_s"] = time.monotonic() - t0
        held = await track.hold(2.0)
        seen["hold_max_m"]["mission_end"] = float(np.linalg.norm(held - WAYPOINTS[-1], axis=1).max())

        t0 = time.monotonic()
        await action.land()
        await wait_for(telemetry.subscribe_armed(), lambda armed: not armed, 30)
        seen["land_to_disarm_s"] = time.monotonic() - t0
        seen["landed_state"] = await telemetry.landed_state()
        seen["landing_error_m"] = float(np.linalg.norm(track.latest() - [*WAYPOINTS[-1][:2], 0.0]))
    finally:
        if track is not None:
            track.cancel()
        mavsdk.destroy()
    return seen


PX4_RAPTOR = SHIPPED_HOVER.parents[1] / "hover_px4_raptor_sih" / "policy.tar"
"""The policy of PX4 mc_raptor's contract trained here, flown from the file mc_raptor loads."""


@pytest.mark.parametrize("policy", [SHIPPED_HOVER, PX4_RAPTOR], ids=lambda p: p.parent.name)
def test_mavsdk_flies_the_hover_policy_from_the_ground_and_back(tmp_path, policy):
    port = free_udp_port()
    out = tmp_path / "summary.json"
    start = time.monotonic()
    proc = start_vehicle(policy_copy(tmp_path, policy), port, out)
    try:
        seen = asyncio.run(asyncio.wait_for(commanded_flight(port), 80))
    finally:
        code, _, stderr = stop_vehicle(proc)
    seen["wall_s"] = time.monotonic() - start
    print(json.dumps({k: (v.name if hasattr(v, "name") else v) for k, v in seen.items()}, indent=1))
    assert code == 0, stderr
    assert seen["takeoff_disarmed"] == "COMMAND_DENIED"  # MAVSDK's denied error, not a time-out
    assert seen["on_ground_before"] is not None and abs(seen["on_ground_before"][2]) < 0.02
    assert set(seen["arrival_m"]) == {"takeoff", "goto", "item0", "item1", "item2"}
    for where, err in seen["arrival_m"].items():
        assert err <= ARRIVAL_M, f"{where}: {err * 100:.1f} cm from where it was sent"
    for where, err in seen["hold_max_m"].items():
        assert err <= HOLD_M, f"holding after {where}: up to {err * 100:.1f} cm off"
    assert seen["landed_state"] == LandedState.ON_GROUND
    assert seen["landing_error_m"] <= ARRIVAL_M
    summary = json.loads(out.read_text())
    (c,) = summary["commanded"]
    print(c["events"], {k: summary[k] for k in ("steps", "control_latency_p50_us", "control_latency_p99_us")})
    assert not c["armed"] and c["flown"] and c["landed_state"] == "ON_GROUND", c
    assert c["gcs_dropped"].keys() <= {"not_for_us"}, c["gcs_dropped"]  # every message MAVSDK sent was understood
    assert summary["fallback_steps"] == 0 and summary["failsafe_events"] == 0


async def take_off_then_fall_silent(port: int) -> dict:
    """MAVSDK sets the link-loss parameters, arms, takes off to 2.5 m, and then goes away (destroyed:
    nothing more is sent from the ground station's port)."""
    mavsdk, drone = await connect(port)
    try:
        telemetry, action, param = TelemetryAsync(drone), ActionAsync(drone), ParamAsync(drone)
        await wait_for(telemetry.subscribe_health(), lambda h: h.is_global_position_ok and h.is_home_position_ok, 20)
        await param.set_param_int("COM_DL_LOSS_T", LOSS_S)  # PX4's minimum
        await param.set_param_float("COM_FAIL_ACT_T", HOLD_S)
        await action.arm()
        await action.takeoff()
        await wait_for(telemetry.subscribe_position(), lambda p: p.relative_altitude_m > 2.0, 20)
        await wait_for(telemetry.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD, 20)
        await asyncio.sleep(1.0)
        return {"held_at": enu(await telemetry.position())}
    finally:
        mavsdk.destroy()


def listen(port: int, proc, timeout: float) -> list:
    """A ground station that only listens from now on (pymavlink on the same port, sending nothing):
    (host time, message) of every message until quad-sitl ends, at most `timeout` s."""
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    got = []
    deadline = time.monotonic() + timeout
    try:
        while proc.poll() is None and time.monotonic() < deadline:
            m = conn.recv_match(blocking=True, timeout=0.2)
            if m is not None and m.get_type() != "BAD_DATA":
                got.append((time.monotonic(), m))
    finally:
        conn.close()
    return got


def test_when_the_ground_station_falls_silent_the_drone_holds_then_lands(tmp_path):
    port = free_udp_port()
    out = tmp_path / "summary.json"
    proc = start_vehicle(policy_copy(tmp_path), port, out)
    try:
        seen = asyncio.run(asyncio.wait_for(take_off_then_fall_silent(port), 60))
        silent_at = time.monotonic()
        got = listen(port, proc, 40) if proc.poll() is None else []
    finally:
        code, _, stderr = stop_vehicle(proc, timeout=5)
    texts = [(t - silent_at, m.text) for t, m in got if m.get_type() == "STATUSTEXT"]
    print(texts)
    lost = next((t for t, text in texts if text.startswith("Connection to ground station lost")), None)
    action = next((t for t, text in texts if text.startswith("Failsafe activated: Land")), None)
    assert lost is not None and action is not None, texts
    assert code == 0, stderr  # it ended on its own: landed and disarmed
    print(f"lost after {lost:.2f} s of silence, landing {action - lost:.2f} s later")
    # MAVSDK's last message (a 1 Hz heartbeat) left at most 1 s before it was destroyed
    assert LOSS_S - 1.5 <= lost <= LOSS_S + 1.0
    assert HOLD_S - 0.2 <= action - lost <= HOLD_S + 0.5
    held_at = seen["held_at"]
    holding = [
        geodetic_to_local(m.lat, m.lon, m.relative_alt + round(HOME.alt_m * 1000), HOME)
        for t, m in got
        if m.get_type() == "GLOBAL_POSITION_INT" and lost <= t - silent_at <= action
    ]
    assert len(holding) >= 3
    assert np.linalg.norm(np.array(holding) - held_at, axis=1).max() <= HOLD_M  # it held where it was
    modes = [(t - silent_at, (m.custom_mode >> 16) & 0xFF, m.custom_mode >> 24) for t, m in got if is_vehicle(m)]
    assert all((main, sub) == (4, 3) for t, main, sub in modes if t < action - 0.1)  # Hold ...
    assert any((main, sub) == (4, 6) for t, main, sub in modes if t > action)  # ... then Land
    last = [m for t, m in got if is_vehicle(m)][-1]
    assert not last.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED  # landed and disarmed itself
    (c,) = json.loads(out.read_text())["commanded"]
    assert c["landed_state"] == "ON_GROUND" and not c["armed"]
    final = [m for t, m in got if m.get_type() == "GLOBAL_POSITION_INT"][-1]
    landed = geodetic_to_local(final.lat, final.lon, final.relative_alt + round(HOME.alt_m * 1000), HOME)
    disarmed = next((t for t, text in texts if text.startswith("Disarmed by landing")), math.nan)
    figures = {
        "lost_after_silence_s": lost,
        "hold_s": action - lost,
        "hold_max_error_m": float(np.linalg.norm(np.array(holding) - held_at, axis=1).max()),
        "landing_error_m": float(np.linalg.norm(landed - [held_at[0], held_at[1], 0.0])),
        "failsafe_land_to_disarm_s": disarmed - action,
    }
    print(json.dumps(figures))
    assert figures["landing_error_m"] <= ARRIVAL_M


def is_vehicle(m) -> bool:
    return m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1 and m.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4
