"""The autopilot side of software-in-the-loop: a MAVLink node that flies a policy file.

It connects to a PX4-style simulator (it is the client; the simulator listens, TCP 4560 by
default), sends HEARTBEAT, and per simulation step answers exactly once: on HIL_SENSOR (the
message PX4 itself steps on, sent last in each step), with the ground truth of the same step's
HIL_STATE_QUATERNION and the body rates of the HIL_SENSOR gyro, it builds the observation with
`core.observation.build_observation` (the function training used), runs the policy through the
`SafetyMonitor`, and sends one HIL_ACTUATOR_CONTROLS (armed, lockstep flag in lockstep mode).

One receive point (`_recv`) dispatching on `get_type()` (never chained type-filtered
`recv_match` calls, which drop the other types). Link loss is measured on the host's monotonic
clock, never simulation time: no state for `link_timeout_s` (100 ms) latches a failsafe.
Timestamps that go backwards or repeat are dropped and counted.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from quadpilot.core.observation import build_observation
from quadpilot.link import wire

from .safety import SafetyMonitor


class NodeError(RuntimeError):
    """The node could not fly (no simulator to connect to, ...); the message says why."""


@dataclass(frozen=True)
class NodeConfig:
    """How the node connects and what it flies."""

    connect: str = "tcp:127.0.0.1:4560"
    """pymavlink address of the simulator (tcp:HOST:PORT, or udpout:HOST:PORT)."""
    target: tuple[float, float, float] = (0.0, 0.0, 2.0)
    """m, local ENU hover target (the training environment's home)."""
    home: wire.Home = field(default_factory=wire.Home)
    """Geodetic origin of the local frame; must match the simulator's."""
    duration_s: float = 5.0
    """s of simulated flight per episode."""
    lockstep: bool = True
    """Set the lockstep flag in HIL_ACTUATOR_CONTROLS (the simulator advances one step per message)."""
    link_timeout_s: float = 0.1
    """s without a state message (host monotonic clock) before the failsafe latches."""
    connect_timeout_s: float = 10.0
    """s to keep retrying the connection while the simulator starts."""
    heartbeat_period_s: float = 1.0
    """s between HEARTBEATs, sent from the control loop."""
    max_time_jump_s: float = 1.0
    """A state timestamp further ahead than this is dropped as a jump."""


@dataclass
class EpisodeLog:
    """What one flight recorded: ground truth per step and what the node did."""

    t: list = field(default_factory=list)
    states: list = field(default_factory=list)
    commands: list = field(default_factory=list)
    sources: list = field(default_factory=list)
    latency_s: list = field(default_factory=list)
    dropped: Counter = field(default_factory=Counter)
    failsafe: str | None = None
    failsafe_latency_s: float | None = None
    wall_s: float = 0.0

    @property
    def steps(self) -> int:
        return len(self.commands)


class Node:
    """One connection to a simulator per episode: `fly(monitor)` → EpisodeLog."""

    def __init__(self, cfg: NodeConfig) -> None:
        self.cfg = cfg
        self._target = np.asarray(cfg.target, np.float64)

    def _connect(self):
        from pymavlink import mavutil

        deadline = time.monotonic() + self.cfg.connect_timeout_s
        while True:
            try:
                return mavutil.mavlink_connection(
                    self.cfg.connect, source_system=1, source_component=1, autoreconnect=False, retries=0
                )
            except (ConnectionRefusedError, OSError) as e:
                if time.monotonic() > deadline:
                    raise NodeError(
                        f"no simulator at {self.cfg.connect} after {self.cfg.connect_timeout_s:g} s ({e}); "
                        "start one with `quad-sitl --sim-only` or let quad-sitl start it"
                    ) from None
                time.sleep(0.05)

    def fly(self, monitor: SafetyMonitor) -> EpisodeLog:
        """Fly one episode; the monitor is reset first (new episode: policy state cleared)."""
        from pymavlink import mavutil

        cfg = self.cfg
        log = EpisodeLog()
        monitor.reset()
        conn = self._connect()
        mav = conn.mav
        steps = round(cfg.duration_s / monitor.policy.info.control_period_s)
        start = time.monotonic()
        last_state_at = start
        last_heartbeat = -math.inf
        state: np.ndarray | None = None
        state_time = -1
        last_sensor_time = -1
        try:
            while log.steps < steps:
                now = time.monotonic()
                if now - last_heartbeat >= cfg.heartbeat_period_s:
                    mav.heartbeat_send(
                        mavutil.mavlink.MAV_TYPE_QUADROTOR,
                        mavutil.mavlink.MAV_AUTOPILOT_GENERIC,
                        mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED,
                        0,
                        mavutil.mavlink.MAV_STATE_ACTIVE,
                    )
                    last_heartbeat = now
                wait = cfg.link_timeout_s - (now - last_state_at)
                msg = conn.recv_match(blocking=True, timeout=max(wait, 0.0)) if wait > 0 else None
                if msg is None:
                    if time.monotonic() - last_state_at >= cfg.link_timeout_s:
                        log.failsafe = "state stream silent"
                        log.failsafe_latency_s = time.monotonic() - last_state_at
                        self._failsafe(mav, log.failsafe, state_time)
                        break
                    continue
                kind = msg.get_type()
                if kind == "HIL_STATE_QUATERNION":
                    if msg.time_usec <= state_time:
                        log.dropped["time_backwards" if msg.time_usec < state_time else "time_repeated"] += 1
                        continue
                    if state_time >= 0 and msg.time_usec - state_time > cfg.max_time_jump_s * 1e6:
                        log.dropped["time_jump"] += 1
                        continue
                    state = wire.state_from_hil_state_quaternion(msg, cfg.home)
                    state_time = msg.time_usec
                    last_state_at = time.monotonic()
                elif kind == "HIL_SENSOR":
                    received = time.perf_counter()
                    if state is None or msg.time_usec != state_time or msg.time_usec == last_sensor_time:
                        log.dropped["sensor_without_state"] += 1
                        continue
                    last_sensor_time = msg.time_usec
                    s = state.copy()
                    s[9:12] = wire.gyro_from_hil_sensor(msg)
                    obs = build_observation(s[None], self._target)[0]
                    cmd = monitor.act(obs)
                    mav.hil_actuator_controls_send(
                        **wire.actuator_controls_fields(cmd, msg.time_usec, True, cfg.lockstep)
                    )
                    log.latency_s.append(time.perf_counter() - received)
                    log.t.append(msg.time_usec * 1e-6)
                    log.states.append(state)
                    log.commands.append(cmd)
                    log.sources.append(monitor.source)
                elif kind == "BAD_DATA":
                    log.dropped["bad_data"] += 1
                elif kind not in ("HIL_GPS", "HEARTBEAT"):
                    log.dropped[f"unexpected_{kind.lower()}"] += 1
        finally:
            conn.close()
            log.wall_s = time.monotonic() - start
        return log

    @staticmethod
    def _failsafe(mav, reason: str, time_usec: int) -> None:
        """Latch motors off (disarmed, all commands 0) and say why over STATUSTEXT. The episode
        ends here: re-arming is a new `fly()`, never automatic. If the peer is gone, the sends
        fail and there is nothing more to do."""
        from pymavlink import mavutil

        try:
            mav.statustext_send(mavutil.mavlink.MAV_SEVERITY_CRITICAL, f"failsafe: {reason}".encode()[:50])
            mav.hil_actuator_controls_send(
                **wire.actuator_controls_fields(np.zeros(4), max(time_usec, 0), False, False)
            )
        except OSError:
            pass


def episode_summary(log: EpisodeLog, target, control_period_s: float, window_s: float = 2.0, tol: float = 0.05):
    """Success (no crash, mean error over the last `window_s` ≤ `tol`), errors and crash flag,
    with the training evaluation's definitions (quadpilot.train.evaluate, core.reward.crashed)."""
    from quadpilot.core.reward import RewardConfig, crashed

    if not log.states:
        return {"steps": 0, "success": False, "crashed": False, "rms_error_m": math.nan, "final_distance_m": math.nan}
    states = np.asarray(log.states)
    err = states[:, 0:3] - np.asarray(target)
    dist = np.linalg.norm(err, axis=1)
    crash = bool(crashed(states, err, RewardConfig()).any())
    k = max(1, round(window_s / control_period_s))
    window = float(dist[-k:].mean())
    return {
        "steps": len(states),
        "success": bool(not crash and len(states) >= k and window <= tol and log.failsafe is None),
        "crashed": crash,
        "rms_error_m": float(np.sqrt(np.mean(dist**2))),
        "mean_error_last_window_m": window,
        "final_distance_m": float(dist[-1]),
    }
