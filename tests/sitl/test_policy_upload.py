"""A policy.tar put onto the vehicle over MAVLink FTP with MAVSDK's ftp plugin, as onto a PX4 SD card
(`/fs/microsd/raptor/policy.tar`), and flown: `quad-sitl POLICY.tar --realtime --start landed`
(the px4-raptor policy trained here, flown through mc_raptor's contract), MAVSDK 4.x on the ground.

A damaged file (one weight changed: its stored example no longer replays) is uploaded first: the
vehicle refuses it and MAVSDK sees why in a STATUSTEXT; then a good file (the same weights under
another checkpoint name, so another SHA-256) is checked and loaded while disarmed, read back by
MAVSDK (its CRC32 of the card's file, and a burst download), and the vehicle arms, takes off on it,
holds, lands and disarms (autopilot/policy_upload.py)."""

from __future__ import annotations

import asyncio
import io
import json
import struct
import tarfile
import time

import numpy as np
import pytest
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.ftp import FtpAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.telemetry import FlightMode
from mavsdk_gcs import Track, connect, free_udp_port, policy_copy, start_vehicle, stop_vehicle, wait_for

from quadpilot.runtime import rltools_tar
from quadpilot.sitl import SHIPPED_HOVER

pytestmark = pytest.mark.sitl
PX4_RAPTOR = SHIPPED_HOVER.parents[1] / "hover_px4_raptor_sih" / "policy.tar"
NEW_NAME = "uploaded-over-mavlink-ftp"
TAKEOFF_ALT = 2.5  # MIS_TAKEOFF_ALT's default
ARRIVAL_M = 0.15


def files(tmp_path):
    """(good, damaged) policy.tar files to upload, each alone in its directory (MAVSDK uploads a file
    under its own name)."""
    tar = rltools_tar.read_policy_tar(PX4_RAPTOR)
    good = rltools_tar.policy_tar_bytes(tar.weights, tar.example_in, tar.example_out, NEW_NAME)
    with tarfile.open(fileobj=io.BytesIO(good)) as archive:
        at = archive.getmember("actor/layers/2/biases/parameters/data").offset_data
    damaged = bytearray(good)
    damaged[at : at + 4] = struct.pack("<f", struct.unpack("<f", good[at : at + 4])[0] + 0.5)  # no longer replays
    out = []
    for name, data in (("good", good), ("damaged", damaged)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "policy.tar").write_bytes(data)
        out.append(tmp_path / name / "policy.tar")
    return out, rltools_tar.sha256_hex(good)


async def upload_and_fly(port: int, good, damaged) -> dict:
    mavsdk, drone = await connect(port)
    seen: dict = {"texts": []}
    track = None
    try:
        telemetry, action, ftp = TelemetryAsync(drone), ActionAsync(drone), FtpAsync(drone)

        async def texts():
            async for t in telemetry.subscribe_status_text():
                seen["texts"].append(t.text)

        listener = asyncio.ensure_future(texts())

        async def said(prefix: str, timeout: float = 10) -> str:
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                hit = [t for t in seen["texts"] if t.startswith(prefix)]
                if hit:
                    return hit[0]
                await asyncio.sleep(0.05)
            raise AssertionError(f"no STATUSTEXT {prefix!r} within {timeout:g} s: {seen['texts']}")

        await wait_for(telemetry.subscribe_health(), lambda h: h.is_global_position_ok and h.is_home_position_ok, 20)
        async for _ in ftp.upload(str(damaged), "/fs/microsd/raptor"):
            pass
        seen["refused"] = await said("policy.tar refused")
        async for _ in ftp.upload(str(good), "/fs/microsd/raptor"):
            pass
        seen["checked"] = await said("policy.tar checked")
        seen["loaded"] = await said("Policy loaded")
        # read back: MAVSDK's CRC32 of the card's file (PX4's convention) and a burst download
        seen["identical"] = await ftp.are_files_identical(str(good), "/fs/microsd/raptor/policy.tar")
        back = good.parent.parent / "back"
        back.mkdir()
        async for _ in ftp.download("/fs/microsd/raptor/policy.tar", str(back), True):
            pass
        seen["read_back"] = (back / "policy.tar").read_bytes() == good.read_bytes()
        track = Track(telemetry)
        await action.arm()
        await action.takeoff()
        await wait_for(telemetry.subscribe_position(), lambda p: p.relative_altitude_m > 2.0, 20)
        await wait_for(telemetry.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD, 20)
        seen["held_at"] = (await track.settled([0.0, 0.0, TAKEOFF_ALT], 15)).tolist()
        await action.land()
        await wait_for(telemetry.subscribe_armed(), lambda armed: not armed, 30)
        listener.cancel()
    finally:
        if track is not None:
            track.cancel()
        mavsdk.destroy()
    return seen


def test_a_policy_uploaded_with_mavsdk_ftp_is_checked_loaded_and_flown(tmp_path):
    (good, damaged), good_sha = files(tmp_path)
    port = free_udp_port()
    out = tmp_path / "summary.json"
    proc = start_vehicle(policy_copy(tmp_path, PX4_RAPTOR), port, out)
    try:
        seen = asyncio.run(asyncio.wait_for(upload_and_fly(port, good, damaged), 90))
    finally:
        code, _, stderr = stop_vehicle(proc)
    print(json.dumps(seen, indent=1))
    assert code == 0, stderr
    # the damaged file: refused, with the reader's reason, seen by MAVSDK (chunks put back together)
    assert "does not replay" in seen["refused"], seen["refused"]
    assert seen["checked"] == f"policy.tar checked: {NEW_NAME}"
    assert seen["loaded"] == f"Policy loaded: {NEW_NAME}"
    assert seen["identical"] and seen["read_back"]
    assert np.linalg.norm(np.array(seen["held_at"]) - [0.0, 0.0, TAKEOFF_ALT]) <= ARRIVAL_M
    (c,) = json.loads(out.read_text())["commanded"]
    print(c["policies"])
    assert [p["sha256"] for p in c["policies"]] == [None, good_sha, good_sha]  # refused, checked, loaded
    loaded_at = c["policies"][-1]["at_s"]
    armed_at = next(t for t, text in c["events"] if text.startswith("Armed"))
    assert loaded_at < armed_at  # loaded on the ground, before the flight
    assert not c["armed"] and c["flown"] and c["landed_state"] == "ON_GROUND", c
    assert c["gcs_dropped"].keys() <= {"not_for_us"}, c["gcs_dropped"]
