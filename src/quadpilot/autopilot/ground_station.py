"""The node's link to a ground station: one UDP socket that sends telemetry and, with a commander,
answers commands.

One socket, pinned to the ground station's address (`link.transport.connect`), both sends and
receives: MAVSDK with `udpin` (and QGroundControl, MAVProxy) replies to the source address of the
vehicle's datagrams, so the answers must come from, and arrive at, the socket the telemetry leaves.

Without a commander it is today's telemetry: HEARTBEAT (MAV_AUTOPILOT_GENERIC) and SYS_STATUS at
1 Hz, ATTITUDE and LOCAL_POSITION_NED at `telemetry_hz`, GLOBAL_POSITION_INT at 5 Hz, on simulated
time (`step`), and whatever the ground station sends is read and discarded. With a commander
(`autopilot.commander`), `serve` hands every message to it and sends its answers, and the commander's
own streams (PX4's messages and rates, which the ground station may change) replace this telemetry;
the node still reports its safety events here with STATUSTEXT. Telemetry is best effort: nobody
listening costs nothing and stops nothing.
"""

from __future__ import annotations

from collections import Counter

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.link import transport, wire

from .commander import Commander, CommanderConfig
from .modes import MODE_NAMES

NODE_SYSTEM_ID = 1
NODE_COMPONENT_ID = 1  # MAV_COMP_ID_AUTOPILOT1
MAX_MESSAGES_PER_SERVE = 256
"""Messages read per `serve` call at most: a flooding ground station cannot stall a control step (the
rest wait in the socket for the next call)."""


class GroundStation:
    """Telemetry to a ground station over UDP, rate-limited on simulated time; with `commander`,
    also its commands (see the module docstring)."""

    def __init__(
        self, address: str, home: wire.Home, control_period_s: float, telemetry_hz: float, tap=None, commander=None
    ):
        self.link = transport.connect(address, NODE_SYSTEM_ID, NODE_COMPONENT_ID)
        self.link.tap = tap
        self.home = home
        self.commander = commander
        self.every = max(1, round(1.0 / (telemetry_hz * control_period_s)))
        self.every_global = max(1, round(0.2 / control_period_s))  # 5 Hz
        self.every_status = max(1, round(1.0 / control_period_s))  # 1 Hz
        self.sent = 0
        self.received = 0
        self.dropped: Counter = Counter()
        """What arrived and could not be read (`parser_error`), by reason."""

    def heartbeat(self, armed: bool, status: int) -> None:
        mode = mavlink2.MAV_MODE_FLAG_HIL_ENABLED | (mavlink2.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
        self.link.mav.heartbeat_send(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_GENERIC, mode, 0, status)
        self.sent += 1

    def statustext(self, severity: int, text: str) -> None:
        self.link.mav.statustext_send(severity, text.encode()[:50])
        self.sent += 1

    def send(self, msgs) -> None:
        """Send messages built elsewhere (the commander's) with this link's sequence numbers."""
        for m in msgs:
            self.link.mav.send(m)
            self.sent += 1

    def serve(self, now: float) -> list:
        """Read what the ground station sent: to the commander (at time `now`, s), whose answers go
        back at once and are returned; without one, discarded (we take no commands then)."""
        answers: list = []
        for _ in range(MAX_MESSAGES_PER_SERVE):
            try:
                msg = self.link.recv(0.0)
            except Exception:  # pymavlink reports garbage as BAD_DATA; anything else it raises is too
                self.dropped["parser_error"] += 1
                continue
            if msg is None:
                break
            self.received += 1
            if self.commander is not None:
                try:
                    out = self.commander.handle(msg, now)
                except Exception as e:  # counted, never the end of a flight: nothing that arrives ends the loop
                    self.dropped[f"commander_error: {type(e).__name__}"] += 1
                    continue
                self.send(out)
                answers += out
        return answers

    def step(self, k: int, state: np.ndarray, time_usec: int, armed: bool, errors: int, received: int) -> None:
        """Telemetry of policy step `k` (without a commander)."""
        ms = time_usec // 1000
        mav = self.link.mav
        if k % self.every == 0:
            mav.attitude_send(**wire.attitude_fields(state, ms))
            mav.local_position_ned_send(**wire.local_position_ned_fields(state, ms))
            self.sent += 2
        if k % self.every_global == 0:
            mav.global_position_int_send(**wire.global_position_int_fields(state, self.home, ms))
            self.sent += 1
        if k % self.every_status == 0:
            self.heartbeat(armed, mavlink2.MAV_STATE_ACTIVE)
            sensors = (
                mavlink2.MAV_SYS_STATUS_SENSOR_3D_GYRO
                | mavlink2.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                | mavlink2.MAV_SYS_STATUS_SENSOR_3D_MAG
                | mavlink2.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
            )
            mav.sys_status_send(**wire.sys_status_fields(sensors, errors, received))
            self.sent += 2
            self.serve(time_usec * 1e-6)  # drain whatever a ground station sent us (its heartbeats)

    def close(self) -> None:
        self.link.close()


def commander_for(vehicle) -> Commander:
    """A commander for the policy's vehicle (`core.params.VehicleParams`): its land detector compares
    the commanded thrust with the vehicle's hover thrust (MPC_THR_HOVER = hover_command², thrust ∝ ω²).
    ValueError naming the vehicle when its hover thrust is outside the parameter's range."""
    try:
        return Commander(CommanderConfig(params={"MPC_THR_HOVER": vehicle.hover_command**2}))
    except ValueError as e:
        raise ValueError(f"vehicle {vehicle.name}: {e}") from None


def commander_summary(c: Commander, gcs: GroundStation | None, disarmed_at_us: int | None) -> dict:
    """The commander at the end of a flight (`node.EpisodeLog.commander`)."""
    return {
        "armed": bool(c.armed),
        "flown": bool(c.flown),
        "landed_state": mavlink2.enums["MAV_LANDED_STATE"][c.landed_state].name.removeprefix("MAV_LANDED_STATE_"),
        "mode": MODE_NAMES.get(c.mode, str(c.mode)),
        "gcs_messages": int(c.received),
        "gcs_dropped": {**dict(c.dropped), **(dict(gcs.dropped) if gcs is not None else {})},
        "disarmed_at_s": None if disarmed_at_us is None else disarmed_at_us * 1e-6,
        "policies": list(c.policies),
    }
