"""Test kit for the commander: a ground station that speaks through real MAVLink bytes (pymavlink packs
what it sends and parses what the vehicle answers, so every field crosses the wire as on a link),
and a point-mass stand-in for the flown vehicle.

The point mass is only there to drive the commander's state machine: its position follows the
setpoint with a first-order lag (time constant `tau`) and stops on the ground at z = 0; the thrust it
reports is hover thrust scaled by how far the target is above it. It makes no claim about flight.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.autopilot.commander import Commander, CommanderConfig
from quadpilot.link.frames import Home, local_to_geodetic

M = mavlink2
GCS_SYSTEM, GCS_COMPONENT = 255, 190  # MAVSDK's and QGroundControl's ground-station ids
HOME = Home()
HOVER_THRUST = 0.45  # the seed vehicle: hover_command² = 1 / thrust-to-weight 2.2


class PointMass:
    """12-state stand-in: position lags the setpoint (first order), ground at z = 0."""

    def __init__(self, tau: float = 0.3, position=(0.0, 0.0, 0.0)) -> None:
        self.tau = tau
        self.state = np.zeros(12)
        self.state[0:3] = position
        self.thrust = 0.0

    def step(self, setpoint, dt: float) -> None:
        s = self.state
        p = s[0:3].copy()
        if setpoint.armed and setpoint.motors_enabled:
            new = p + (setpoint.position - p) * (1.0 - math.exp(-dt / self.tau))
            self.thrust = HOVER_THRUST * min(2.0, max(0.0, 1.0 + (setpoint.position[2] - p[2])))
        else:  # idle: stays on the ground, or falls
            new = p + s[3:6] * dt + np.array([0.0, 0.0, -0.5 * 9.81 * dt * dt])
            self.thrust = 0.0
        new[2] = max(new[2], 0.0)
        s[3:6] = (new - p) / dt
        if new[2] == 0.0 and s[5] < 0:
            s[5] = 0.0
        s[0:3] = new


class Gcs:
    """A commander, a point mass and a ground station exchanging packed MAVLink messages."""

    def __init__(self, cfg: CommanderConfig | None = None, dt: float = 0.01, **params) -> None:
        if cfg is None:
            cfg = CommanderConfig(params={"MPC_THR_HOVER": HOVER_THRUST, **params})
        self.commander = Commander(cfg)
        self.vehicle = PointMass()
        self.dt = dt
        self.now = 0.0
        self.tx = M.MAVLink(None, srcSystem=GCS_SYSTEM, srcComponent=GCS_COMPONENT)  # the GCS sends with it
        self.rx = M.MAVLink(None)  # the GCS parses the vehicle's bytes with it
        self.vehicle_rx = M.MAVLink(None)  # the vehicle parses the GCS's bytes with it
        self.received: list = []  # everything the vehicle sent, parsed, in order

    # --- the wire ---
    def _from_vehicle(self, msgs) -> list:
        out = []
        for m in msgs:
            out += self.rx.parse_buffer(m.pack(self.commander.mav)) or []
        self.received += out
        return out

    def send(self, msg) -> list:
        """Pack `msg` (a GCS message object) as bytes, let the vehicle parse and handle it; returns
        the vehicle's answers, parsed."""
        parsed = self.vehicle_rx.parse_buffer(msg.pack(self.tx))
        assert parsed and len(parsed) == 1, parsed
        return self._from_vehicle(self.commander.handle(parsed[0], self.now))

    # --- time ---
    def run(self, seconds: float, heartbeat: bool = True, until=None) -> list:
        """Fly for `seconds` (the GCS sending a HEARTBEAT every second unless `heartbeat` is False),
        or until `until(gcs)` is true; returns what the vehicle sent meanwhile."""
        out = []
        end = self.now + seconds
        next_hb = self.now
        while self.now < end - 1e-9:
            if heartbeat and self.now >= next_hb:
                out += self.send(self.tx.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0))
                next_hb += 1.0
            out += self._from_vehicle(self.commander.step(self.vehicle.state, HOME, self.now, self.vehicle.thrust))
            self.vehicle.step(self.commander.setpoint, self.dt)
            self.now = round(self.now + self.dt, 9)
            if until is not None and until(self):
                break
        return out

    # --- message builders ---
    def command(self, command: int, *params: float, confirmation: int = 0) -> list:
        p = list(params) + [0.0] * (7 - len(params))
        return self.send(self.tx.command_long_encode(1, 1, command, confirmation, *p))

    def command_int(self, command: int, frame: int, x: int, y: int, z: float, *params: float) -> list:
        p = list(params) + [0.0] * (4 - len(params))
        return self.send(self.tx.command_int_encode(1, 1, frame, command, 0, 0, *p, x, y, z))

    def arm(self) -> list:
        return self.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)

    def takeoff(self) -> list:
        return self.command(M.MAV_CMD_NAV_TAKEOFF, *([math.nan] * 7))

    def goto(self, east: float, north: float, up: float, yaw=math.nan) -> list:
        lat, lon, alt_mm = local_to_geodetic((east, north, up), HOME)
        return self.command_int(
            M.MAV_CMD_DO_REPOSITION, M.MAV_FRAME_GLOBAL, lat, lon, alt_mm / 1000.0, -1.0, 1.0, 0.0, yaw
        )

    def set_mode(self, main: int, sub: int = 0) -> list:
        return self.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)

    def param_set(self, name: str, value: float, kind: int = M.MAV_PARAM_TYPE_REAL32) -> list:
        return self.send(self.tx.param_set_encode(1, 1, name.encode(), value, kind))

    # --- reading the answers ---
    @property
    def position(self) -> np.ndarray:
        return self.vehicle.state[0:3].copy()


def of_type(msgs, kind: str) -> list:
    return [m for m in msgs if m.get_type() == kind]


def ack(msgs, command: int) -> int:
    """The one COMMAND_ACK for `command` among `msgs` (fails if there is not exactly one)."""
    acks = [m for m in of_type(msgs, "COMMAND_ACK") if m.command == command]
    assert len(acks) == 1, f"{len(acks)} COMMAND_ACKs for {command}: {msgs}"
    return acks[0].result


def texts(msgs) -> list[str]:
    return [m.text for m in of_type(msgs, "STATUSTEXT")]


def mission_item(
    seq: int, command: int, east: float, north: float, up: float, frame=M.MAV_FRAME_GLOBAL_RELATIVE_ALT, **p
):
    """A MISSION_ITEM_INT field list for `Gcs.tx.mission_item_int_encode` (MAVSDK 4.1.0's frame 3 by
    default): position in metres from HOME, altitude above home for frames 3 and 6, AMSL for 0."""
    lat, lon, alt_mm = local_to_geodetic((east, north, up), HOME)
    z = up if frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT) else alt_mm / 1000.0
    return dict(
        target_system=1,
        target_component=1,
        seq=seq,
        frame=frame,
        command=command,
        current=int(seq == 0),
        autocontinue=1,
        param1=p.get("param1", 0.0),
        param2=p.get("param2", 0.0),
        param3=p.get("param3", 0.0),
        param4=p.get("param4", math.nan),
        x=lat,
        y=lon,
        z=z,
        mission_type=M.MAV_MISSION_TYPE_MISSION,
    )


def upload(gcs: Gcs, items: list[dict]) -> list:
    """The upload conversation as a ground station holds it: answer each MISSION_REQUEST_INT with
    the item it asks for, until the MISSION_ACK. Returns everything the vehicle sent."""
    out = gcs.send(gcs.tx.mission_count_encode(1, 1, len(items), M.MAV_MISSION_TYPE_MISSION))
    seen = list(out)
    for _ in range(len(items) + 1):
        reqs = of_type(out, "MISSION_REQUEST_INT")
        if not reqs:
            break
        out = gcs.send(gcs.tx.mission_item_int_encode(**items[reqs[-1].seq]))
        seen += out
    return seen
