"""The autopilot side of software-in-the-loop: a MAVLink node that flies a policy file.

It connects to a PX4-style simulator (it is the client; the simulator listens, TCP 4560 by
default), sends HEARTBEAT first (a PX4-API simulator waits for it before its first step) and then
at 1 Hz, and per simulation step answers exactly once: on HIL_SENSOR (the message PX4 itself steps
on, sent last in each step), with the ground truth of the same step's HIL_STATE_QUATERNION and the
body rates of the HIL_SENSOR gyro (FRD, the frame MAVLink defines; a simulator's
HIL_STATE_QUATERNION rates are not trusted for flying: RotorPy 3.0.0 sends them in FLU), it builds
the observation with `core.observation.build_observation` (the function training used; for the one
vehicle in scalar arithmetic, the same bits: `observation_one.observe`), runs the
policy through the `SafetyMonitor`, and sends one HIL_ACTUATOR_CONTROLS (armed, lockstep flag in
lockstep mode). When the simulator also sends ODOMETRY for the step (a state estimate,
`--estimator-noise`), the observation is built from that estimate instead of the ground truth,
which is still what the flight is logged and judged on.

The simulator's step need not be the policy's: the policy runs at the rate it was trained at on
simulated time (the steps' `time_usec`), at the first step at or after each of its ticks, and the
steps in between are answered with the command held from the last tick (a 250 Hz simulator gets
one reply per step and a new command every 10 ms, alternately after 3 and 2 steps). The flight
lasts `duration_s` of simulated time. The node speaks the MAVLink version the simulator speaks
(`transport.Link.speak_as_peer`: MAVLink 1 until its first message), MAVLink 2 when signing.

Home, the origin of the local frame the policy's target is given in, is `NodeConfig.home`, or the
first valid position the simulator reports (`home=None`: a simulator whose origin we do not know,
RotorPy's is lat 40, lon -74.3); the target is `NodeConfig.target` metres ENU from home, or the
first valid position itself (`target=None`: hold where it started). The commanded heading (what a
version-2 policy holds, `core.observation`) is the ground station's yaw in a commanded flight, else
the heading of the first valid state; the policy is given it at most `HEADING_REACH_RAD` ahead of
its yaw (`heading_within_reach`).

One receive point (`Link.recv`, one system call per batch of messages) dispatching on
`get_type()` through a table of handlers, one per message type (`flight.Flight.HANDLERS`). In real time,
link loss is measured on the host's monotonic clock: no state and no HIL_SENSOR for `link_timeout_s`
(100 ms) latches a failsafe (motors off, disarmed, STATUSTEXT), which only a new `fly()` clears (a
HIL_SENSOR without its state is no link loss: see below). In lockstep time is
the simulator's: between two steps nothing happens to the vehicle however long the host takes, so
the node waits for the next step as long as the simulator holds the TCP link open (a closed or lost
connection still ends the flight at once); over UDP, which has no connection to lose, up to
`UDP_LOCKSTEP_SILENCE_S`. Valid states that stop while bad ones keep coming are still a failsafe:
after `link_timeout_s` of simulated time ("no valid state").
Timestamps that go backwards, repeat or jump are dropped and counted.

A step whose HIL_SENSOR comes without its state is still answered: the node flies on an estimate of
its own from HIL_SENSOR, then holds attitude and height, then lands (`autopilot.state_loss`), and a
HIL_SENSOR is proof enough that the link is alive (the real-time link-loss timer restarts on it).
Before any valid state has arrived such steps are answered with the motors off, disarmed, and after
`StateLossConfig.arm_wait_s` the node refuses to arm ("refusing to arm: ...") Motor commands go to the
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
the fallback, as for any observation it cannot trust, and hands back to the policy once valid states
have kept the vehicle inside its recovery envelope for `safety.HAND_BACK_HOLD_S`. Every hand-over
and hand-back goes into `EpisodeLog.handovers` and a STATUSTEXT. A dropped state does not restart
the link-loss timer, so a stream of them ends in the same failsafe as silence ("no valid state").

Telemetry for a ground station (`gcs`, UDP 127.0.0.1:14550 by default, where QGroundControl and
MAVProxy listen; `autopilot.ground_station`): HEARTBEAT and SYS_STATUS at 1 Hz, ATTITUDE and
LOCAL_POSITION_NED at `telemetry_hz`, GLOBAL_POSITION_INT at 5 Hz (simulated time), STATUSTEXT on
failsafe, hand-over and hand-back. Telemetry is best effort: nobody listening costs nothing and stops nothing.

Commanded (`NodeConfig.command`): the same socket also takes the ground station's commands. Every
step, what it sent goes to a `autopilot.commander.Commander` (at the step's simulated time) and the
answers go back at once; every policy tick the commander steps on the state the policy flies on and
its setpoint is the policy's target (with its velocity for a track-layout policy). While the
commander is disarmed, or idle on the ground, the node sends zero commands with its armed flag and
does not run the policy (the simulator's ground holds the vehicle); when the motors switch on again
the monitor is reset, as for a new episode. The commander's streams replace the telemetry above, the
node's safety STATUSTEXTs stay, and on the node's own failsafe the commander reports disarmed and
CRITICAL (`Commander.motors_cut`). Times are simulated: with a real-time simulator they run with the
wall clock, so COM_DL_LOSS_T is in real seconds.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.link import spin, transport, wire
from quadpilot.runtime.safety import SafetyMonitor

from .commander import Commander
from .flight import DISARMED_LINGER_S as DISARMED_LINGER_S
from .flight import HEADING_REACH_RAD as HEADING_REACH_RAD
from .flight import IDLE as IDLE
from .flight import TICK_TOLERANCE_US as TICK_TOLERANCE_US
from .flight import Flight
from .flight import heading_within_reach as heading_within_reach
from .flight_log import EpisodeLog
from .ground_station import NODE_COMPONENT_ID, NODE_SYSTEM_ID, GroundStation, commander_for, commander_summary
from .node_config import START_MODES as START_MODES
from .node_config import NodeConfig

UDP_LOCKSTEP_SILENCE_S = 5.0
"""s of host time a lockstep flight over UDP waits for the next state: the same as our simulator
waits for the node (`simulator.config.SimConfig.lockstep_timeout_s`)."""


class NodeError(RuntimeError):
    """The node could not fly (no simulator to connect to, ...); the message says why."""


class Node:
    """One connection to a simulator per episode: `fly(monitor)` → EpisodeLog."""

    def __init__(self, cfg: NodeConfig) -> None:
        self.cfg = cfg
        self._target = None if cfg.target is None else np.asarray(cfg.target, np.float64)
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
        period = monitor.policy.info.control_period_s
        try:
            commander = commander_for(monitor.policy.info.vehicle) if cfg.command else None
        except ValueError as e:
            raise NodeError(str(e)) from None
        link = self._connect()
        link.tap = tap
        link.spin_s = spin.spin_window(cfg.spin_s) if cfg.lockstep else 0.0
        if cfg.speak_as_peer and cfg.signing_key is None:
            link.speak_as_peer()
        gcs = None
        if cfg.gcs:
            try:
                gcs = GroundStation(cfg.gcs, cfg.home or wire.Home(), period, cfg.telemetry_hz, tap, commander)
            except (OSError, ValueError) as e:
                log.dropped[f"gcs_unavailable: {e}"] += 1
        start = time.monotonic()
        flight = Flight(cfg, monitor, link, gcs, targets or cfg.targets, self._target, log, start, commander)
        handle = flight.handle
        last_heartbeat = -math.inf
        try:
            while not flight.done:
                if commander is not None and gcs is not None and flight.state is None:
                    gcs.serve(0.0)  # before the first state too: the ground station is never left unread
                now = time.monotonic()
                if now - last_heartbeat >= cfg.heartbeat_period_s:
                    link.mav.heartbeat_send(
                        mavlink2.MAV_TYPE_QUADROTOR,
                        mavlink2.MAV_AUTOPILOT_GENERIC,
                        mavlink2.MAV_MODE_FLAG_SAFETY_ARMED,
                        0,
                        mavlink2.MAV_STATE_ACTIVE,
                    )
                    link.flush()
                    last_heartbeat = now
                limit = cfg.link_timeout_s if flight.any_state else cfg.first_state_timeout_s
                if cfg.lockstep and flight.any_state:  # the simulator's time: wait while the link holds
                    limit = UDP_LOCKSTEP_SILENCE_S if link.peer_label.startswith("udp:") else math.inf
                wait = min(limit - (now - flight.last_state_at), cfg.heartbeat_period_s)
                try:
                    msg = link.recv(wait) if wait > 0 else None  # the one receive point
                except transport.PeerClosed:
                    raise
                except Exception:  # pymavlink reports garbage as BAD_DATA; anything else it raises is too
                    log.dropped["parser_error"] += 1
                    continue
                if msg is None:
                    if time.monotonic() - flight.last_state_at >= limit:
                        if not flight.any_state:
                            log.failsafe = f"no state within {limit:g} s"
                        elif flight.bad_at > flight.last_state_at:
                            log.failsafe = "no valid state"
                        else:
                            log.failsafe = "state stream silent"
                        log.failsafe_latency_s = time.monotonic() - flight.last_state_at
                        self._failsafe(link, gcs, log.failsafe, flight.state_time, commander)
                        break
                    continue
                handle(msg)
                while not flight.done:  # the rest of what that read brought (a step's messages come together)
                    msg = link.next_parsed()
                    if msg is None:
                        break
                    handle(msg)
                if flight.failsafe is not None:  # lockstep: valid states stopped, on simulated time
                    log.failsafe, log.failsafe_latency_s = flight.failsafe, time.monotonic() - flight.last_state_at
                    self._failsafe(link, gcs, log.failsafe, flight.state_time, commander)
                    break
        except transport.PeerClosed:
            if not flight.done:
                log.failsafe = "simulator closed the link"
                log.failsafe_latency_s = time.monotonic() - flight.last_state_at
                self._failsafe(link, gcs, log.failsafe, flight.state_time, commander)
        finally:
            for name, reason in (("foreign_datagrams", "foreign_peer"), ("truncated_datagrams", "truncated_datagram")):
                if getattr(link, name, 0):
                    log.dropped[reason] += getattr(link, name)
            if getattr(link, "oversized_datagrams", 0):
                log.dropped["oversized_datagram"] += link.oversized_datagrams
            log.mavlink_version = link.version
            log.home = flight.home
            if flight.loss is not None and flight.loss.latched and log.failsafe is None:
                # the state-loss landing is a failsafe (never a success), not a crash
                log.failsafe = f"state lost: {'landed' if flight.loss.phase == 'landed' else 'landing'}"
            if commander is not None:
                log.commander = commander_summary(commander, gcs, flight.disarmed_at)
            link.close()
            if gcs is not None:
                log.telemetry_sent = gcs.sent
                gcs.close()
            log.wall_s = time.monotonic() - start
        return log

    @staticmethod
    def _failsafe(
        link: transport.Link, gcs: GroundStation | None, reason: str, time_usec: int, commander: Commander | None
    ) -> None:
        """Latch motors off (disarmed, all commands 0) and say why over STATUSTEXT, to the
        simulator and the ground station (with a commander, its heartbeat then says disarmed and
        CRITICAL: `Commander.motors_cut`). The episode ends here: re-arming is a new `fly()`,
        never automatic. If the peer is gone, the sends fail and there is nothing more to do."""
        text = reason if reason.startswith("refusing to arm") else f"failsafe: {reason}, motors off"
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
            if commander is None:
                gcs.heartbeat(False, mavlink2.MAV_STATE_CRITICAL)
            else:
                gcs.send(commander.motors_cut(reason))
