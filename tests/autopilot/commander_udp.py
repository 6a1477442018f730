"""The commander on a real UDP socket, for clients that are not ours (MAVSDK): one pymavlink socket
that sends to the client's port and receives its answers (MAVSDK's `udpin` replies to the source
address of the vehicle's datagrams), the point mass of `commander_gcs` as the flown vehicle, and
simulated time running at `speedup` × the wall clock. This is what the node will do, minus the
policy and the simulator."""

from __future__ import annotations

import threading
import time
from collections import Counter

from commander_gcs import HOME, HOVER_THRUST, PointMass
from pymavlink import mavutil

from quadpilot.autopilot.commander import Commander, CommanderConfig


class UdpVehicle(threading.Thread):
    def __init__(self, port: int, dt: float = 0.01, speedup: float = 1.0, **params) -> None:
        super().__init__(daemon=True)
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
        self.commander = Commander(CommanderConfig(params={"MPC_THR_HOVER": HOVER_THRUST, **params}))
        self.vehicle = PointMass()
        self.dt, self.speedup = dt, speedup
        self.now = 0.0
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.heard: Counter = Counter()  # message types received from the client
        self.sent: Counter = Counter()
        self.reached: dict[int, object] = {}  # mission item → vehicle position when first reported reached
        self.error: BaseException | None = None

    def _send(self, msgs) -> None:
        for m in msgs:
            self.conn.mav.send(m)
            self.sent[m.get_type()] += 1
            if m.get_type() == "MISSION_ITEM_REACHED" and m.seq not in self.reached:
                self.reached[m.seq] = self.vehicle.state[0:3].copy()

    def run(self) -> None:
        start = time.monotonic()
        try:
            while not self.stop.is_set():
                with self.lock:
                    while (msg := self.conn.recv_msg()) is not None:  # the one receive point
                        self.heard[msg.get_type()] += 1
                        self._send(self.commander.handle(msg, self.now))
                    self._send(self.commander.step(self.vehicle.state, HOME, self.now, self.vehicle.thrust))
                    self.vehicle.step(self.commander.setpoint, self.dt)
                    self.now += self.dt
                lag = start + self.now / self.speedup - time.monotonic()
                if lag > 0:
                    time.sleep(lag)
        except BaseException as e:  # seen by the test, which fails on it
            self.error = e
        finally:
            self.conn.close()
