"""One episode of the node (`autopilot.node.Node.fly`): what it knows so far, and one handler per
MAVLink message type: the state (HIL_STATE_QUATERNION) checked before it is believed, the step
(HIL_SENSOR) answered exactly once, an estimator's ODOMETRY, and, while the state stream is silent,
the node's own estimate, hold and landing (`autopilot.state_loss`). The module docstring of
`autopilot.node` describes the protocol; this is its per-message half.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.core.dynamics import NUM_MOTORS
from quadpilot.core.state import POS, VEL, YAW
from quadpilot.link import transport, wire
from quadpilot.runtime.observation_one import observe
from quadpilot.runtime.safety import SafetyMonitor

from .commander import Commander
from .dead_reckoning import ImuCalibration
from .flight_log import EpisodeLog
from .ground_station import GroundStation
from .node_config import NodeConfig
from .policy_upload import fly_uploaded
from .setpoint import collective_thrust
from .state_loss import StateLoss

DISARMED_LINGER_S = 1.0
"""s a commanded flight goes on after the vehicle has flown and been disarmed (simulated time), so
that the ground station hears the landed, disarmed vehicle in its 1 Hz streams before the link closes."""
_ACTUATOR_CONTROLS = mavlink2.MAVLink_hil_actuator_controls_message
IDLE = np.zeros(NUM_MOTORS, np.float32)
"""The command while the commander holds the motors off (disarmed, or idle on the ground)."""
TICK_TOLERANCE_US = 100
"""µs: a step this close before a policy tick counts as at it. Simulators that keep time in a float
stamp steps a microsecond off (RotorPy: int(t·1e6) of a sum of 0.004 s steps gives 11 999 for 12 ms);
any simulator step is many times longer."""


HEADING_REACH_RAD = math.radians(25.0)
"""The heading a version-2 policy is given is at most this far from its yaw: it was trained on
commanded headings up to 30° from its start (`train.envs.EnvConfig.heading_offset_deg`), so a
larger turn (a ground station's new heading) is fed to it as a heading that moves ahead of the
vehicle, and the vehicle turns at the rate the policy turns by 25°."""


def heading_within_reach(yaw: float, commanded: float) -> float:
    """The commanded heading, or the heading HEADING_REACH_RAD from `yaw` towards it (rad, ENU)."""
    err = math.remainder(commanded - yaw, 2.0 * math.pi)
    return math.remainder(yaw + max(-HEADING_REACH_RAD, min(HEADING_REACH_RAD, err)), 2.0 * math.pi)


class Flight:
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
        fixed: np.ndarray | None,
        log: EpisodeLog,
        start: float,
        commander: Commander | None = None,
    ) -> None:
        self.cfg, self.monitor, self.link, self.gcs = cfg, monitor, link, gcs
        self.commander = commander  # None: fly to `targets`/`fixed`; else to its setpoint
        self.track = monitor.policy.info.layout.tracks  # observes the target's velocity
        # a version-2 policy sees its attitude relative to the commanded heading: the commander's
        # yaw, else the heading of the first valid state (`core.mission`'s default)
        self.heading_frame = monitor.policy.info.layout.heading_frame
        self.heading: float | None = None
        self.own_observation = monitor.policy.own_observation  # None, or a contract's (run every step)
        airborne = commander is None or cfg.start == "air"
        self.held_armed = airborne  # the armed flag sent with `held`: the commander's, else always armed
        self.motors_on = airborne  # the motors were on at the last tick (or are at the start)
        self.commanded = False  # the commander has had its first step
        self.disarmed_at: int | None = None  # time_usec the commanded vehicle was first seen flown and disarmed
        self.targets, self.fixed, self.log = targets, fixed, log
        self.home = cfg.home  # None until the first valid position, when `cfg.home` is None
        self.last_state_at = start  # host monotonic clock: link loss is measured on it
        self.any_state = False  # a state message (valid or not) has arrived: link loss counts from here
        self.state: np.ndarray | None = None  # the last state that passed wire's checks
        self.state_values: list = []  # the same state as floats, for the observation
        self.state_time = -1
        self.bad_time = -1  # time_usec of the last state dropped by those checks: its step is flown blind
        self.bad_at = -math.inf
        self.valid_us: int | None = None  # time_usec of the last valid state (or the first state of any kind)
        self.failsafe: str | None = None  # set by a handler: the loop latches it
        self.estimate: np.ndarray | None = None  # ODOMETRY: the estimator's state, if the simulator sends one
        self.estimate_time = -1
        self.last_sensor_time = -1
        self.loss: StateLoss | None = None  # the state stream is silent: what flies meanwhile
        self.calibration = ImuCalibration(monitor.policy.info.vehicle.gravity)  # IMU biases, for the estimate
        self.estimate_values: list = []  # the estimate of the last step without a state, as floats
        self.unarmed_since: int | None = None  # time_usec of the first HIL_SENSOR while no state ever came
        self.received = 0
        # the policy's clock on simulated time (see the module docstring)
        policy_period = monitor.policy.info.control_period_s
        self.period_us = round(policy_period * 1e6)
        self.step_us = round((cfg.control_period_s or policy_period) * 1e6)  # measured once 2 steps arrive
        self.first_us: int | None = None
        self.next_tick_us: int | None = None
        self.ticks = 0
        self.held: np.ndarray | None = None  # the command of the last tick, answered until the next
        self.held_source = "policy"
        self.target = fixed
        self._fixed_of: np.ndarray | None = None  # the fixed target `_fixed_values` holds as floats
        self._fixed_values: list = []
        self.done = False

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
        self.any_state = True
        if self.valid_us is None:
            self.valid_us = msg.time_usec
        if self.cfg.lockstep and self.bad_time > self.state_time and msg.time_usec > self.bad_time:
            if msg.time_usec - self.valid_us > self.cfg.link_timeout_s * 1e6:  # bad states since, on simulated time
                self.failsafe = "no valid state"
                return
        if msg.time_usec <= self.state_time:
            log.dropped["time_backwards" if msg.time_usec < self.state_time else "time_repeated"] += 1
            return
        # a jump from the simulator's last step (its last HIL_SENSOR: after a silent state stream, the
        # last state may be long ago, and the next one is no jump)
        last = max(self.state_time, self.last_sensor_time)
        if last >= 0 and msg.time_usec - last > self.cfg.max_time_jump_s * 1e6:
            log.dropped["time_jump"] += 1
            return
        home = self.home
        if home is None:  # home is this position, if it is a valid state at all
            home = wire.Home(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3)
        try:
            values = wire.state_values_from_hil_state_quaternion(msg, home)
        except wire.BadState as e:
            # never flown on, logged or sent to the ground station; its step is still answered (see
            # on_sensor), and the link-loss timer keeps running
            log.dropped[f"state_{e.reason}"] += 1
            self.bad_time, self.bad_at = msg.time_usec, time.monotonic()
            return
        new = np.array(values)
        if self.home is None:
            self.home = home
            if self.gcs is not None:
                self.gcs.home = home
        if self.fixed is None:  # hold the first valid position
            self.fixed = self.target = new[POS].copy()
        if self.heading is None:  # hold the first valid heading
            self.heading = float(new[YAW])
        self.state, self.state_values = new, values
        self.state_time = self.valid_us = msg.time_usec
        self.last_state_at = time.monotonic()
        self.received += 1

    def on_sensor(self, msg) -> None:
        """HIL_SENSOR: the step's last message; answered exactly once with HIL_ACTUATOR_CONTROLS."""
        t_in = time.perf_counter()
        log, monitor, state, lockstep = self.log, self.monitor, self.state, self.cfg.lockstep
        t_us = msg.time_usec
        blind = t_us == self.bad_time and self.bad_time > self.state_time  # its step's state was dropped
        if self.failsafe is not None:  # latched by this step's state: the loop ends the flight
            return
        # a step is answered once, and never after a later one, nor after a jump in the simulator's time
        if t_us <= self.last_sensor_time:
            log.dropped["sensor_out_of_order"] += 1
            return
        if self.last_sensor_time >= 0 and t_us - self.last_sensor_time > self.cfg.max_time_jump_s * 1e6:
            log.dropped["sensor_time_jump"] += 1
            return
        lost = t_us != self.state_time and not blind  # this step's state never came
        if lost and state is None:  # no state yet at all: motors off, and no arming without one
            self._unarmed(msg)
            return
        if self.first_us is None:
            self.first_us = t_us
        elif t_us - self.last_sensor_time <= self.cfg.max_time_jump_s * 1e6:
            self.step_us = t_us - self.last_sensor_time
        self.last_sensor_time = t_us
        self.received += 1
        if lost:
            self._lost_step(msg)
        elif not blind:  # a step with its state: the IMU's biases against it
            self.calibration.update(self.state_values, t_us, msg)
        if not lost and self.loss is not None and not self.loss.latched:  # states are back before the landing
            self._loss_note(t_us, "state back", "policy flying" if self.loss.phase == "policy" else "handing back")
            self.loss = None
        loss = self.loss
        on_estimate = lost and loss.phase == "policy"
        commander = self.commander
        if commander is not None and self.gcs is not None:  # the ground station's commands, before the setpoint
            self._log_texts(self.gcs.serve(t_us * 1e-6), t_us * 1e-6)
        every_step = self.own_observation is not None  # a contract of its own: every step (see policy.Policy)
        tick = not blind and (every_step or self.next_tick_us is None or t_us >= self.next_tick_us - TICK_TOLERANCE_US)
        if loss is not None and loss.phase != "policy":  # holding, landing or landed: every step
            s = (
                list(self.estimate_values)
                if lost
                else self.state_values[:9] + list(wire.gyro_values_from_hil_sensor(msg))
            )
            before = len(loss.changes)
            cmd = self.held = loss.command(s, t_us)
            self._loss_changes(before)  # the touchdown
            if loss.phase == "landed":
                self.held_armed = self.motors_on = False
            self.held_source = loss.phase
        elif blind and not self.motors_on:
            cmd = self.held = IDLE  # motors off stay off: a dropped state is no reason to spin them
            self.held_source = "idle"
        elif blind:
            # this step's state was dropped: the step is still answered, once (a lockstep peer waits
            # for it), with the monitor's blind hover command, as for any observation it cannot trust
            cmd = self.held = monitor.blind("state_dropped")
            self.held_source = monitor.source
        elif tick:
            # the state flown on, as floats, with the body rates of the gyro
            if on_estimate:  # the state stream is silent: the estimate from HIL_SENSOR
                s = list(self.estimate_values)
            else:
                s = (self.estimate.tolist() if self.estimate_time == t_us else self.state_values)[:9]
                s += wire.gyro_values_from_hil_sensor(msg)
            run = True
            heading = self.heading
            if commander is not None:
                sp = self._command(np.array(s), t_us)
                heading = sp.yaw
                target, target_vel = sp.position, (sp.velocity if self.track else None)
                run = sp.armed and sp.motors_enabled
                if run and not self.motors_on:
                    monitor.reset()  # a new flight for the policy: its state cleared, a hand-over undone
                self.held_armed, self.motors_on = sp.armed, run
            elif self.targets is None:
                target, target_vel = self.fixed, None
            else:  # the target at this simulated time, in the policy's steps
                target, target_vel = self.targets(round((t_us - self.first_us) / self.period_us))
            self.target = target
            if run:
                heading = heading_within_reach(float(s[YAW]), heading) if self.heading_frame else None
                if target is not self.fixed:
                    tp = np.asarray(target, np.float64).tolist()
                elif self._fixed_of is target:  # the node's own fixed target (never changed in place), as floats
                    tp = self._fixed_values
                else:
                    self._fixed_of, tp = target, np.asarray(target, np.float64).tolist()
                    self._fixed_values = tp
                own, tv = self.own_observation, None if target_vel is None else np.asarray(target_vel).tolist()
                if self.track or own is not None:  # RAPTOR, a track policy: the target's velocity (0: fixed)
                    tv = tv or [0.0, 0.0, 0.0]
                elif tv is not None:  # a hover policy follows a moving target in the target's frame
                    s[VEL], tv = np.subtract(s[VEL], tv).tolist(), None
                obs = observe(s, tp, tv, heading) if own is None else own(s, tp, tv, heading, t_us)
                cmd = self.held = monitor.act(obs)
                self.held_source = "estimate" if on_estimate and monitor.source == "policy" else monitor.source
            else:  # disarmed, or idle on the ground: motors off, the policy not run
                cmd = self.held = IDLE
                self.held_source = "idle"
            nxt = (t_us if self.next_tick_us is None else self.next_tick_us) + self.period_us
            self.next_tick_us = nxt if nxt > t_us else t_us + self.period_us  # never a burst to catch up
        else:
            cmd = self.held  # between two of the policy's ticks: the last command, held
        self.link.send_message(_ACTUATOR_CONTROLS, wire.actuator_controls_args(cmd, t_us, self.held_armed, lockstep))
        t_out = time.perf_counter()  # latency ends here: on one CPU the woken simulator may run inside the send
        self.link.flush()
        log.replies += 1
        log.blind_replies += blind
        # done after the step that ends `duration_s` (steps k = 0..N-1 of N = duration / step); half a
        # step of slack for stamps a microsecond off
        self.done = (t_us - self.first_us) + 1.5 * self.step_us >= self.cfg.duration_s * 1e6
        if commander is not None:  # a commanded flight ends once flown and disarmed (and heard so)
            if not (commander.flown and not commander.armed):
                self.disarmed_at = None
            elif self.disarmed_at is None:
                self.disarmed_at = t_us
            self.done |= self.disarmed_at is not None and t_us - self.disarmed_at >= DISARMED_LINGER_S * 1e6
        if state is None:  # flown blind before any valid state: nothing to log it against
            return
        log.latency_s.append(t_out - t_in)
        log.wall.append(t_in)
        log.t.append(t_us * 1e-6)
        log.states.append(state)  # on a blind step the last valid state, what the node knew
        log.targets.append(self.target)
        log.commands.append(cmd)
        log.sources.append(self.held_source)
        log.ticks.append(tick)
        gcs = self.gcs
        while monitor.transitions:  # hand-overs and hand-backs: into the log and to the ground station
            kind, why = monitor.transitions.popleft()
            log.handovers.append((round(t_us * 1e-6, 6), kind, why))
            if gcs is not None:
                text = {"hand-over": "fallback flying", "hand-back": "policy flying", "latched": "fallback latched"}
                gcs.statustext(mavlink2.MAV_SEVERITY_WARNING, f"safety: {text[kind]} ({why})")
        if gcs is not None:
            if tick and commander is None:  # telemetry only ever from a state that passed the checks, and new
                gcs.step(self.ticks, state, t_us, True, sum(log.dropped.values()), self.received)
        if tick:
            self.ticks += 1

    def _unarmed(self, msg) -> None:
        """A HIL_SENSOR before any valid state: answered once with the motors off and disarmed (a
        lockstep peer waits for it). After `StateLossConfig.arm_wait_s` of them the node refuses to
        arm: the flight ends, and says why in one line."""
        t_us = msg.time_usec
        self.last_sensor_time = t_us
        self.last_state_at = time.monotonic()  # the link is alive: this is no silence
        if self.unarmed_since is None:
            self.unarmed_since = t_us
        self.link.send_message(_ACTUATOR_CONTROLS, wire.actuator_controls_args(IDLE, t_us, False, self.cfg.lockstep))
        self.link.flush()
        self.log.replies += 1
        self.log.dropped["sensor_without_state"] += 1
        wait = self.cfg.state_loss.arm_wait_s
        if (t_us - self.unarmed_since) * 1e-6 >= wait:
            self.failsafe = f"refusing to arm: no state in {wait:g} s of sensor data"

    def _lost_step(self, msg) -> None:
        """A step whose state never came: the estimate goes on (started from the last valid state at
        the first such step), and the phase with it (`autopilot.state_loss`)."""
        t_us = msg.time_usec
        self.last_state_at = time.monotonic()  # sensors arrive: the link is alive, the state is what is lost
        self.log.state_lost_steps += 1
        if self.loss is None:
            self.loss = StateLoss(
                self.cfg.state_loss,
                self.monitor.policy.info.vehicle,
                [*self.state_values[:9], 0.0, 0.0, 0.0],
                self.state_time,
                msg,
                self.step_us * 1e-6,
                self.calibration,
            )
            self._loss_note(t_us, "state lost", "flying on the estimate")
        before = len(self.loss.changes)
        self.loss.update(msg)
        self.estimate_values = self.loss.estimate_state()  # once a step: the log keeps it, fliers copy it
        self.log.estimates.append((t_us * 1e-6, self.estimate_values))
        self._loss_changes(before)

    def _loss_changes(self, before: int) -> None:
        """The loss's phase changes from its `before`-th on: noted; a hold hands the vehicle over (the
        policy flies again by the usual hand-back)."""
        for t_us, phase, why in self.loss.changes[before:]:
            if phase == "hold":
                self.monitor.take_over("state_lost")
            self._loss_note(t_us, phase, why)

    def _loss_note(self, t_us: int, what: str, why: str) -> None:
        """A change of what flies while the state is lost: into the log and to the ground station."""
        self.log.handovers.append((round(t_us * 1e-6, 6), "state-loss", f"{what}: {why}"))
        if self.gcs is not None:
            self.gcs.statustext(mavlink2.MAV_SEVERITY_WARNING, f"state loss: {what}"[:50])

    def _command(self, s: np.ndarray, t_us: int):
        """One commander step on the state the policy flies on, at simulated time; its messages go to
        the ground station, its STATUSTEXTs into the log. Returns the setpoint."""
        c, now = self.commander, t_us * 1e-6
        if not self.commanded:
            self.commanded = True
            if self.cfg.start == "air":
                c.arm_in_air(s)  # armed, holding here, before the first step: its first heartbeat says so
        out = c.step(s, self.home, now, 0.0 if self.held is None else collective_thrust(self.held))
        if c.new_policy is not None and not c.armed and fly_uploaded(c, self.monitor):  # docs: policy_upload
            self.own_observation = self.monitor.policy.own_observation
        self._log_texts(out, now)
        if self.gcs is not None:
            self.gcs.send(out)
        return c.setpoint

    def _log_texts(self, msgs, now: float) -> None:
        for m in msgs:
            if m.get_type() == "STATUSTEXT":
                text = m.text.decode(errors="replace") if isinstance(m.text, bytes) else str(m.text)
                self.log.events.append((round(now, 3), text.rstrip("\x00")))

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
