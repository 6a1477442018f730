"""Test kit for commanded flights: quad-sitl started as a ground-station-commanded vehicle in a
subprocess, and what a MAVSDK 4.1.0 client needs around it (positions in the local frame, waiting on
its telemetry streams). Nothing here stands in for either side: the vehicle is quad-sitl with the
shipped policy file and our simulator, the client is MAVSDK."""

from __future__ import annotations

import asyncio
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk

from quadpilot.link.frames import Home, local_to_geodetic
from quadpilot.sitl import SHIPPED_HOVER

HOME = Home()  # our simulator's, and quad-sitl's node's, home


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def policy_copy(tmp: Path, policy: Path = SHIPPED_HOVER) -> Path:
    """A shipped model (the hover model unless `policy` names another's file) copied into `tmp`
    (nothing may write next to models/)."""
    shutil.copytree(policy.parent, tmp / policy.parent.name)
    return tmp / policy.parent.name / policy.name


def start_vehicle(
    policy: Path, port: int, json_out: Path, duration_s: float = 90.0, tlog: Path | None = None
) -> subprocess.Popen:
    """`quad-sitl POLICY --realtime --start landed --gcs udp:127.0.0.1:PORT` as a subprocess, with
    `--tlog TLOG` (every message the node sent and received) if given."""
    cmd = [sys.executable, "-m", "quadpilot.sitl", str(policy), "--realtime", "--start", "landed"]
    cmd += ["--duration", f"{duration_s:g}", "--gcs", f"udp:127.0.0.1:{port}", "--json", str(json_out)]
    if tlog is not None:
        cmd += ["--tlog", str(tlog)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def upstream_part(path: Path) -> bytes:
    """A vendored upstream file (tests/sitl/outsider/) without the header we put above it: the bytes
    whose SHA-256 must equal the upstream file's."""
    text = path.read_bytes()
    marker = b"# ---- end of header ----\n"
    return text[text.index(marker) + len(marker) :]


def stop_vehicle(proc: subprocess.Popen, timeout: float = 20.0) -> tuple[int, str, str]:
    """Wait for quad-sitl to end on its own (it ends after landing and disarming); kill it if it
    does not within `timeout` s. (exit code, stdout, stderr)."""
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    return proc.returncode, out, err


def degrees(east: float, north: float, up: float) -> tuple[float, float, float]:
    """Local ENU metres → (latitude °, longitude °, altitude AMSL m), as MAVSDK takes them."""
    lat, lon, alt_mm = local_to_geodetic((east, north, up), HOME)
    return lat * 1e-7, lon * 1e-7, alt_mm * 1e-3


def enu(position) -> np.ndarray:
    """A MAVSDK telemetry Position → local ENU metres from home."""
    n = (position.latitude_deg - HOME.lat_deg) * HOME.metres_per_deg_lat
    e = (position.longitude_deg - HOME.lon_deg) * HOME.metres_per_deg_lon
    return np.array([e, n, position.relative_altitude_m])


async def connect(port: int, timeout_s: float = 20.0):
    """A MAVSDK ground station listening on `port` (udpin) and the first autopilot it finds."""
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
    drone = await mavsdk.first_autopilot(timeout_s)
    assert drone is not None, f"no autopilot found within {timeout_s:g} s"
    return mavsdk, drone


async def wait_for(agen, ok, timeout: float):
    """The first value of the stream `agen` for which `ok` holds, within `timeout` s."""

    async def first():
        async for value in agen:
            if ok(value):
                return value

    return await asyncio.wait_for(first(), timeout)


class Track:
    """Every position MAVSDK reports (subscribe_position), with the host time it arrived."""

    def __init__(self, telemetry) -> None:
        self.t: list[float] = []
        self.p: list[np.ndarray] = []
        self._task = asyncio.ensure_future(self._run(telemetry))

    async def _run(self, telemetry) -> None:
        async for pos in telemetry.subscribe_position():
            self.t.append(time.monotonic())
            self.p.append(enu(pos))

    def latest(self) -> np.ndarray:
        return self.p[-1]

    def since(self, t0: float) -> np.ndarray:
        return np.array([p for t, p in zip(self.t, self.p, strict=True) if t >= t0]).reshape(-1, 3)

    async def settled(self, goal, timeout: float, speed: float = 0.1, window_s: float = 0.5) -> np.ndarray:
        """The position once the vehicle has stopped (moved less than `speed` · `window_s` over the
        last `window_s` s) within 0.5 m of `goal`: its arrival there."""
        goal = np.asarray(goal, np.float64)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            await asyncio.sleep(0.05)
            now = time.monotonic()
            recent = self.since(now - window_s)
            if len(recent) >= 3 and np.linalg.norm(recent[-1] - goal) < 0.5:
                if np.linalg.norm(recent[-1] - recent[0]) < speed * window_s:
                    return recent[-1]
        raise AssertionError(f"did not settle near {goal.tolist()} within {timeout:g} s (at {self.latest().tolist()})")

    async def hold(self, seconds: float) -> np.ndarray:
        """The positions reported over the next `seconds` s."""
        t0 = time.monotonic()
        await asyncio.sleep(seconds)
        return self.since(t0)

    def cancel(self) -> None:
        self._task.cancel()
