"""The autopilot side of software-in-the-loop: a MAVLink node that flies a policy file.

It connects to a PX4-style simulator (it is the client; the simulator listens, TCP 4560 by
default), sends HEARTBEAT, and per simulation step answers exactly once: on HIL_SENSOR (the
message PX4 itself steps on, sent last in each step), with the ground truth of the same step's
HIL_STATE_QUATERNION and the body rates of the HIL_SENSOR gyro, it builds the observation with
`core.observation.build_observation` (the function training used), runs the policy through the
`SafetyMonitor`, and sends one HIL_ACTUATOR_CONTROLS (armed, lockstep flag in lockstep mode).
When the simulator also sends ODOMETRY for the step (a state estimate, `--estimator-noise`), the
observation is built from that estimate instead of the ground truth, which is still what the
flight is logged and judged on.

One receive point (`Link.recv`, one system call per batch of messages) dispatching on
`get_type()` through a table of handlers, one per message type (`_Flight.HANDLERS`). Link loss is
measured on the host's monotonic clock, never simulation time: no state for `link_timeout_s`
(100 ms) latches a failsafe (motors off, disarmed, STATUSTEXT), which only a new `fly()` clears.
Timestamps that go backwards, repeat or jump are dropped and counted. Motor commands go to the
simulator's address only; optional MAVLink 2 signing (`signing_key`).

Nothing that arrives can end the loop. A state that cannot be a state (`link.wire.BadState`:
non-finite values, a zero or non-unit quaternion, a body rate or position no vehicle has) is dropped
and counted by reason (`state_non_finite`, `state_quaternion_not_unit`, `state_out_of_range`; an
ODOMETRY estimate likewise as `odometry_*`, and its step then flies on the ground truth, as without
one). It is never flown on, logged, or sent to the ground station. Its step is still answered, once:
a lockstep simulator waits for it (without it both sides stall), and an autopilot in lockstep runs
one cycle, with one actuator output, per HIL_SENSOR whatever its estimator makes of the data. The
answer is the safety monitor's blind command (hover thrust on every motor, no moment,
`SafetyMonitor.blind`), not the policy on the last valid state: flying a frozen attitude was
measured to flip the vehicle within 0.2 s (see `runtime.safety`); the monitor then hands over to
the fallback, as for any observation it cannot trust. A dropped state does not restart the
link-loss timer, so a stream of them ends in the same failsafe as silence ("no valid state").

Telemetry for a ground station (`gcs`, UDP 127.0.0.1:14550 by default, where QGroundControl and
MAVProxy listen): HEARTBEAT and SYS_STATUS at 1 Hz, ATTITUDE and LOCAL_POSITION_NED at
`telemetry_hz`, GLOBAL_POSITION_INT at 5 Hz (simulated time), STATUSTEXT on failsafe and
fallback. Telemetry is best effort: nobody listening costs nothing and stops nothing.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.core.observation import build_observation
from quadpilot.link import transport, wire

from .safety import SafetyMonitor

NODE_SYSTEM_ID = 1
NODE_COMPONENT_ID = 1  # MAV_COMP_ID_AUTOPILOT1


class NodeError(RuntimeError):
    """The node could not fly (no simulator to connect to, ...); the message says why."""


@dataclass(frozen=True)
class NodeConfig:
    """How the node connects and what it flies."""

    connect: str = "tcp:127.0.0.1:4560"
    """Address of the simulator: tcp:HOST:PORT, or udp:HOST:PORT for a simulator on UDP."""
    target: tuple[float, float, float] = (0.0, 0.0, 2.0)
    """m, local ENU hover target (the training environment's home)."""
    targets: Callable[[int], tuple[np.ndarray, np.ndarray | None]] | None = field(default=None, compare=False)
    """Moving target: step k → (position (3,), velocity (3,) or None), world ENU. None: `target`."""
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
    """s between HEARTBEATs to the simulator, sent from the control loop."""
    max_time_jump_s: float = 1.0
    """A state timestamp further ahead than this is dropped as a jump."""
    gcs: str | None = "udp:127.0.0.1:14550"
    """Where ground-station telemetry goes (udp:HOST:PORT); None: no telemetry."""
    telemetry_hz: float = 25.0
    """ATTITUDE and LOCAL_POSITION_NED rate, per simulated second."""
    signing_key: bytes | None = field(default=None, repr=False)
    """MAVLink 2 signing key (32 bytes) for the simulator link; None: unsigned."""
    control_period_s: float | None = None
    """s per simulator step, if it differs from the policy's (a timing test at another rate)."""


@dataclass
class EpisodeLog:
    """What one flight recorded: ground truth per step and what the node did."""

    t: list = field(default_factory=list)
    states: list = field(default_factory=list)
    """Ground truth per step (12-state ENU/FLU); a step whose state was dropped repeats the last valid one."""
    targets: list = field(default_factory=list)
    commands: list = field(default_factory=list)
    sources: list = field(default_factory=list)
    latency_s: list = field(default_factory=list)
    wall: list = field(default_factory=list)
    """perf_counter() at each step's HIL_SENSOR: the loop's period and jitter."""
    dropped: Counter = field(default_factory=Counter)
    """Messages and states refused, by reason (see the module docstring)."""
    failsafe: str | None = None
    failsafe_latency_s: float | None = None
    wall_s: float = 0.0
    telemetry_sent: int = 0

    @property
    def steps(self) -> int:
        return len(self.commands)


class GroundStation:
    """Telemetry to a ground station over UDP, rate-limited on simulated time."""

    def __init__(self, address: str, home: wire.Home, control_period_s: float, telemetry_hz: float, tap=None):
        self.link = transport.connect(address, NODE_SYSTEM_ID, NODE_COMPONENT_ID)
        self.link.tap = tap
        self.home = home
        self.every = max(1, round(1.0 / (telemetry_hz * control_period_s)))
        self.every_global = max(1, round(0.2 / control_period_s))  # 5 Hz
        self.every_status = max(1, round(1.0 / control_period_s))  # 1 Hz
        self.sent = 0

    def heartbeat(self, armed: bool, status: int) -> None:
        mode = mavlink2.MAV_MODE_FLAG_HIL_ENABLED | (mavlink2.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
        self.link.mav.heartbeat_send(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_GENERIC, mode, 0, status)
        self.sent += 1

    def statustext(self, severity: int, text: str) -> None:
        self.link.mav.statustext_send(severity, text.encode()[:50])
        self.sent += 1

    def step(self, k: int, state: np.ndarray, time_usec: int, armed: bool, errors: int, received: int) -> None:
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
            self.link.recv(0.0)  # drain whatever a GCS sent us (heartbeats); we take no commands
            self.link._pending.clear()

    def close(self) -> None:
        self.link.close()


class Node:
    """One connection to a simulator per episode: `fly(monitor)` → EpisodeLog."""

    def __init__(self, cfg: NodeConfig) -> None:
        self.cfg = cfg
        self._target = np.asarray(cfg.target, np.float64)
        self._signing = None  # carried over between episodes: a recorded packet cannot be replayed later

    def _connect(self) -> transport.Link:
        cfg = self.cfg
        try:
            link = transport.connect(cfg.connect, NODE_SYSTEM_ID, NODE_COMPONENT_ID, cfg.connect_timeout_s)
        except (ConnectionError, ValueError) as e:
            raise NodeError(f"{e}; start one with `quad-sitl --sim-only` or let quad-sitl start it") from None
        if cfg.signing_key is not None:
            link.sign(cfg.signing_key, state=self._signing)
            self._signing = link.signing_state
        return link

    def fly(
        self,
        monitor: SafetyMonitor,
        tap: Callable[[str, bytes], None] | None = None,
        targets: Callable[[int], tuple[np.ndarray, np.ndarray | None]] | None = None,
    ) -> EpisodeLog:
        """Fly one episode; the monitor is reset first (new episode: policy state cleared).
        `tap(direction, raw)` sees every message sent and received (a .tlog writer); `targets`
        (step → target position, velocity or None, e.g. `core.mission.Mission.target_at`)
        overrides `cfg.targets` for this episode."""
        cfg = self.cfg
        log = EpisodeLog()
        monitor.reset()
        period = cfg.control_period_s or monitor.policy.info.control_period_s
        link = self._connect()
        link.tap = tap
        gcs = None
        if cfg.gcs:
            try:
                gcs = GroundStation(cfg.gcs, cfg.home, period, cfg.telemetry_hz, tap)
            except (OSError, ValueError) as e:
                log.dropped[f"gcs_unavailable: {e}"] += 1
        mav = link.mav
        steps = round(cfg.duration_s / period)
        start = time.monotonic()
        flight = _Flight(cfg, monitor, link, gcs, targets or cfg.targets, self._target, log, start)
        handle = flight.handle
        last_heartbeat = -math.inf
        try:
            while log.steps < steps:
                now = time.monotonic()
                if now - last_heartbeat >= cfg.heartbeat_period_s:
                    mav.heartbeat_send(
                        mavlink2.MAV_TYPE_QUADROTOR,
                        mavlink2.MAV_AUTOPILOT_GENERIC,
                        mavlink2.MAV_MODE_FLAG_SAFETY_ARMED,
                        0,
                        mavlink2.MAV_STATE_ACTIVE,
                    )
                    link.flush()
                    last_heartbeat = now
                wait = cfg.link_timeout_s - (now - flight.last_state_at)
                try:
                    msg = link.recv(wait) if wait > 0 else None  # the one receive point
                except transport.PeerClosed:
                    raise
                except Exception:  # pymavlink reports garbage as BAD_DATA; anything else it raises is too
                    log.dropped["parser_error"] += 1
                    continue
                if msg is None:
                    if time.monotonic() - flight.last_state_at >= cfg.link_timeout_s:
                        log.failsafe = (
                            "no valid state" if flight.bad_at > flight.last_state_at else "state stream silent"
                        )
                        log.failsafe_latency_s = time.monotonic() - flight.last_state_at
                        self._failsafe(link, gcs, log.failsafe, flight.state_time)
                        break
                    continue
                handle(msg)
        except transport.PeerClosed:
            if log.steps < steps:
                log.failsafe = "simulator closed the link"
                log.failsafe_latency_s = time.monotonic() - flight.last_state_at
                self._failsafe(link, gcs, log.failsafe, flight.state_time)
        finally:
            for name, reason in (("foreign_datagrams", "foreign_peer"), ("truncated_datagrams", "truncated_datagram")):
                if getattr(link, name, 0):
                    log.dropped[reason] += getattr(link, name)
            if getattr(link, "oversized_datagrams", 0):
                log.dropped["oversized_datagram"] += link.oversized_datagrams
            link.close()
            if gcs is not None:
                log.telemetry_sent = gcs.sent
                gcs.close()
            log.wall_s = time.monotonic() - start
        return log

    @staticmethod
    def _failsafe(link: transport.Link, gcs: GroundStation | None, reason: str, time_usec: int) -> None:
        """Latch motors off (disarmed, all commands 0) and say why over STATUSTEXT, to the
        simulator and the ground station. The episode ends here: re-arming is a new `fly()`,
        never automatic. If the peer is gone, the sends fail and there is nothing more to do."""
        text = f"failsafe: {reason}, motors off"
        try:
            link.mav.statustext_send(mavlink2.MAV_SEVERITY_CRITICAL, text.encode()[:50])
            link.mav.hil_actuator_controls_send(
                **wire.actuator_controls_fields(np.zeros(4), max(time_usec, 0), False, False)
            )
            link.flush()
        except (OSError, transport.PeerClosed):
            pass
        if gcs is not None:
            gcs.statustext(mavlink2.MAV_SEVERITY_CRITICAL, text)
            gcs.heartbeat(False, mavlink2.MAV_STATE_CRITICAL)


class _Flight:
    """One episode of `Node.fly`: what the node knows so far, and one handler per message type.

    `handle` dispatches a received message on `get_type()` through `HANDLERS`; a new message type
    is one more method and one more entry. Types not in the table are counted as dropped
    (`unknown_message_id` for ids pymavlink does not know, else `unexpected_<type>`)."""

    def __init__(
        self,
        cfg: NodeConfig,
        monitor: SafetyMonitor,
        link: transport.Link,
        gcs: GroundStation | None,
        targets: Callable[[int], tuple[np.ndarray, np.ndarray | None]] | None,
        fixed: np.ndarray,
        log: EpisodeLog,
        start: float,
    ) -> None:
        self.cfg, self.monitor, self.link, self.mav, self.gcs = cfg, monitor, link, link.mav, gcs
        self.targets, self.fixed, self.log = targets, fixed, log
        self.last_state_at = start  # host monotonic clock: link loss is measured on it
        self.state: np.ndarray | None = None  # the last state that passed wire's checks
        self.state_time = -1
        self.bad_time = -1  # time_usec of the last state dropped by those checks: its step is flown blind
        self.bad_at = -math.inf
        self.estimate: np.ndarray | None = None  # ODOMETRY: the estimator's state, if the simulator sends one
        self.estimate_time = -1
        self.last_sensor_time = -1
        self.received = 0
        self.source = "policy"

    def handle(self, msg) -> None:
        kind = msg.get_type()
        handler = self.HANDLERS.get(kind)
        if handler is not None:
            handler(self, msg)
        elif kind.startswith("UNKNOWN_"):
            self.log.dropped["unknown_message_id"] += 1
        else:
            self.log.dropped[f"unexpected_{kind.lower()}"] += 1

    def on_state(self, msg) -> None:
        """HIL_STATE_QUATERNION: the ground truth of a step, checked before it is believed."""
        log = self.log
        if msg.time_usec <= self.state_time:
            log.dropped["time_backwards" if msg.time_usec < self.state_time else "time_repeated"] += 1
            return
        if self.state_time >= 0 and msg.time_usec - self.state_time > self.cfg.max_time_jump_s * 1e6:
            log.dropped["time_jump"] += 1
            return
        try:
            new = wire.state_from_hil_state_quaternion(msg, self.cfg.home)
        except wire.BadState as e:
            # never flown on, logged or sent to the ground station; its step is still answered (see
            # on_sensor), and the link-loss timer keeps running
            log.dropped[f"state_{e.reason}"] += 1
            self.bad_time, self.bad_at = msg.time_usec, time.monotonic()
            return
        self.state = new
        self.state_time = msg.time_usec
        self.last_state_at = time.monotonic()
        self.received += 1

    def on_sensor(self, msg) -> None:
        """HIL_SENSOR: the step's last message; answered exactly once with HIL_ACTUATOR_CONTROLS."""
        t_in = time.perf_counter()
        log, monitor, state = self.log, self.monitor, self.state
        t_us = msg.time_usec
        blind = t_us == self.bad_time and self.bad_time > self.state_time  # its step's state was dropped
        # a step is answered once, and never after a later one
        if t_us <= self.last_sensor_time or (t_us != self.state_time and not blind):
            log.dropped["sensor_without_state"] += 1
            return
        self.last_sensor_time = t_us
        self.received += 1
        k = log.steps
        target, target_vel = (self.fixed, None) if self.targets is None else self.targets(k)
        fresh = t_us == self.state_time
        if fresh:
            s = (self.estimate if self.estimate_time == t_us else state).copy()
            s[9:12] = wire.gyro_from_hil_sensor(msg)
            obs = build_observation(s[None], target, target_vel)[0]
            cmd = monitor.act(obs)
        else:
            # this step's state was dropped: the step is still answered, once (a lockstep peer waits
            # for it), with the monitor's blind hover command, as for any observation it cannot trust
            cmd = monitor.blind("state_dropped")
        self.mav.hil_actuator_controls_send(**wire.actuator_controls_fields(cmd, t_us, True, self.cfg.lockstep))
        self.link.flush()
        if state is None:  # flown blind before any valid state: nothing to log it against
            return
        log.latency_s.append(time.perf_counter() - t_in)
        log.wall.append(t_in)
        log.t.append(t_us * 1e-6)
        log.states.append(state)  # on a blind step the last valid state, what the node knew
        log.targets.append(target)
        log.commands.append(cmd)
        log.sources.append(monitor.source)
        gcs = self.gcs
        if gcs is not None:
            if monitor.source != self.source:
                self.source = monitor.source
                gcs.statustext(
                    mavlink2.MAV_SEVERITY_WARNING,
                    f"safety: {self.source} flying ({', '.join(sorted(monitor.events)) or 'policy'})",
                )
            if fresh:  # telemetry only ever from a state that passed the checks, and new
                gcs.step(k, state, t_us, True, sum(log.dropped.values()), self.received)

    def on_odometry(self, msg) -> None:
        """ODOMETRY: the estimator's state for a step, flown on instead of the ground truth."""
        try:
            self.estimate, self.estimate_time = wire.state_from_odometry(msg), msg.time_usec
        except wire.BadState as e:  # as no estimate: the step flies on the ground truth
            self.log.dropped[f"odometry_{e.reason}"] += 1

    def on_bad_data(self, msg) -> None:
        self.log.dropped[transport.bad_data_reason(msg)] += 1

    def ignore(self, msg) -> None:
        """A message the node has no use for (GPS: it flies on the state messages)."""

    HANDLERS = {
        "HIL_STATE_QUATERNION": on_state,
        "HIL_SENSOR": on_sensor,
        "ODOMETRY": on_odometry,
        "BAD_DATA": on_bad_data,
        "HIL_GPS": ignore,
        "HEARTBEAT": ignore,
        "STATUSTEXT": ignore,
    }


def episode_summary(log: EpisodeLog, control_period_s: float, task: str = "hover") -> dict:
    """Success and errors of one flight with the project's one definition (`core.mission.judge`,
    the same as the training evaluation's); a failsafe is never a success. `dropped`: what the
    node refused, by reason (EpisodeLog.dropped)."""
    from quadpilot.core.mission import judge

    out = judge(task, np.asarray(log.states), np.asarray(log.targets), control_period_s)
    out["success"] = bool(out["success"] and log.failsafe is None)
    out["dropped"] = dict(log.dropped)  # packets and states refused, by reason
    return out
