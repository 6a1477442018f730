"""The simulator process: `Simulator` listens, serves one episode per connection, and steps the
plant in lockstep with the peer's actuator messages or on the host's clock.

Per episode: the start state and the sensors' noise come from np.random.default_rng([seed,
episode]); the simulator waits for the autopilot's HEARTBEAT (as PX4-API simulators do: RotorPy's
PX4Multirotor calls `wait_heartbeat()` before its first step), at most `lockstep_timeout_s`, then the
step's messages go out (`protocol`), and then, in lockstep, the simulator waits for exactly one
HIL_ACTUATOR_CONTROLS, applies it and advances the physics (`plant`) by one `dt`. In realtime mode
it advances on the host's monotonic clock instead, holding the last command like an ESC and cutting
the motors when valid commands stop. An actuator message before the HEARTBEAT is dropped and counted
(`before_heartbeat`).

A dropped command (see `protocol`) in lockstep still counts as the peer's answer for the step (the
peer is waiting for the next HIL_SENSOR: not stepping would stall both sides), and the motors keep
their previous command. Only applied commands (armed and valid, or disarmed: motors 0) feed the ESC
timeout: after `esc_timeout_s` without one (host clock in realtime, simulated time in lockstep) the
motors are cut, so a stream of bad commands cannot keep the last good one alive.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

import numpy as np

from quadpilot.core import dynamics
from quadpilot.core.reward import RewardConfig, crashed
from quadpilot.core.state import PITCH, POS, ROLL, VZ, X, Y, Z
from quadpilot.link import spin
from quadpilot.link.transport import Address, Listener, PeerClosed

from .config import SimConfig
from .faults import FaultPlayer
from .plant import Plant
from .protocol import Protocol
from .records import TOUCHDOWN_MAX_SPEED, TOUCHDOWN_MAX_TILT_DEG, EpisodeRecord, EpisodeTally, SimStats
from .sensors import Sensors, isa_pressure_hpa, isa_temperature_c

log = logging.getLogger(__name__)

POLL_S = 0.05
"""s, longest a wait goes without looking at `stop()`."""


def _isa(alt_msl_m: float) -> tuple[float, float]:
    """The barometer's pressure (hPa) and temperature (°C) at an altitude (a faulted one, `faults`)."""
    return isa_pressure_hpa(alt_msl_m), isa_temperature_c(alt_msl_m)


def crashed_one(state: np.ndarray, target: np.ndarray, reward: RewardConfig) -> bool:
    """`core.reward.crashed` for one 12-state (ENU) and its target, in scalar arithmetic: it runs
    every step, and the batched function is mostly NumPy's per-call overhead on a batch of one. The same decision: the
    comparisons are the same, and the squared distance, whose sum may round one ulp apart from
    `crashed`'s einsum, is handed to `crashed` itself when it is that close to the limit."""
    values, (tx, ty, tz) = state.tolist(), target.tolist()  # plain floats: numpy's scalars cost more
    max_tilt = reward.max_tilt
    if values[Z] < 0.0 or abs(values[ROLL]) > max_tilt or abs(values[PITCH]) > max_tilt:
        return True
    e0, e1, e2 = values[X] - tx, values[Y] - ty, values[Z] - tz
    d2 = e0 * e0 + e1 * e1 + e2 * e2
    limit = reward.max_distance**2
    if abs(d2 - limit) <= 1e-9 * limit:  # at the edge of the flight area: to the last bit, as training judges
        return bool(crashed(state[None], state[None, POS] - target, reward)[0])
    return not d2 <= limit  # NaN counts as out


class Simulator:
    """Serves `SimConfig` episodes over MAVLink. `serve()` blocks (run it in a thread if need be)
    and returns the stats; `stop()` ends it from any thread within about POLL_S."""

    def __init__(self, cfg: SimConfig, on_episode: Callable[[EpisodeRecord], None] | None = None) -> None:
        self.cfg = cfg
        self.on_episode = on_episode
        self.stats = SimStats()
        self.listener = Listener(cfg.address)
        self._stop = threading.Event()
        self._reward = RewardConfig()
        self._target = np.asarray(cfg.target, np.float64)
        self._signing = None  # signing state carried from one episode's link to the next
        self._io = Protocol(cfg, self.stats)
        self._sensors: Sensors | None = None  # this episode's sensors (and noise processes)
        # the step after which `cfg.impulse` hits (T below one step: after the first); None: no hit
        self._impulse_step = None if cfg.impulse is None else max(1, round(cfg.impulse[1] / cfg.dt))

    @property
    def address(self) -> Address | None:
        """The bound address (with the real port when 0 was asked for); None before `bind()`."""
        return self.listener.address

    def bind(self) -> Address:
        """Claim the listen address; SimulatorError if it cannot (e.g. it is in use)."""
        if self.listener.sock is None:
            self.listener.bind()
            log.info("simulator listening on %s", self.listener.address)
        return self.listener.address

    def stop(self) -> None:
        self._stop.set()

    def close(self) -> None:
        self.listener.close()

    def __enter__(self) -> Simulator:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
        self.close()

    # --- serving ---------------------------------------------------------------------------
    def serve(self) -> SimStats:
        """Bind (if not yet), serve episodes one connection at a time until `cfg.episodes` are done
        or `stop()` is called, close the sockets, and return the stats."""
        cfg = self.cfg
        try:
            self.bind()
            k = 0
            while not self._stop.is_set() and (cfg.episodes is None or k < cfg.episodes):
                link, early = self.listener.accept(POLL_S, self._stop.is_set)
                heard = False
                for msg in early:  # UDP: what arrived before (and including) the first valid message
                    heard = heard or msg.get_type() == "HEARTBEAT"
                    if self._io.dispatch(msg, None) is not None:
                        self._io.drop("before_heartbeat" if not heard else "before_first_state", None)
                if link is None:
                    break
                if cfg.signing_key is not None:
                    link.sign(cfg.signing_key, state=self._signing)
                    self._signing = link.signing_state
                try:
                    record = self._run_episode(link, k, heard)
                finally:
                    if cfg.address.protocol == "tcp":
                        link.close()
                    else:
                        link.pin(None)  # the UDP socket stays; the next first sender is the next peer
                self.stats.records.append(record)
                self.stats.episodes += 1
                log.info("%s", record.summary())
                if self.on_episode is not None:
                    self.on_episode(record)
                k += 1
        finally:
            self.listener.close()
        return self.stats

    def _run_episode(self, link, k: int, heard: bool = False) -> EpisodeRecord:
        """Episode `k` on `link`; `heard`: the peer's HEARTBEAT has arrived already (UDP: with the
        datagram that made it the peer)."""
        cfg = self.cfg
        ep = EpisodeTally(k, link.peer_label)
        ep.truth = [] if cfg.record_truth else None
        state0, rng = cfg.start_state(k)
        plant = Plant(cfg.vehicle_params, cfg.dt, cfg.wind, cfg.gust, cfg.gust_tau_s, rng)
        self._target = cfg.area_centre(k)
        plant.reset(state0)  # (a gust draw) before the sensors' noise draws from the same generator
        self._sensors = Sensors(cfg.sensor_noise, cfg.dt, rng, cfg.home.alt_m, cfg.imu_noise, cfg.estimator_noise)
        self._io.faults = FaultPlayer(cfg.sensor_faults, cfg.dt, _isa) if cfg.sensor_faults else None
        n, wall0, end = 0, time.monotonic(), "max_steps"
        try:
            end = None if heard else self._await_heartbeat(link, ep)
            if end is None:
                self._io.send_step(link, plant, 0, self._sensors)
                run = self._lockstep if cfg.lockstep else self._realtime
                n, end = run(link, plant, rng, ep)
        except PeerClosed as e:
            log.debug("episode %d: %s", k, e)
            n, end = ep.steps_done, "peer_closed"
        if hasattr(link, "foreign_datagrams"):  # UDP
            self._io.count("foreign_peer", link.foreign_datagrams, ep)
            self._io.count("truncated_datagram", link.truncated_datagrams, ep)
            self._io.count("oversized_datagram", link.oversized_datagrams, ep)
            link.foreign_datagrams = link.truncated_datagrams = link.oversized_datagrams = 0
        err = float(np.linalg.norm(plant.state[POS] - self._target))
        jitter = None
        if len(ep.step_times) > 2:
            dev = np.abs(np.diff(ep.step_times) - cfg.dt) * 1e3
            jitter = (float(np.percentile(dev, 50)), float(np.percentile(dev, 99)), float(dev.max()))
        return EpisodeRecord(
            index=k,
            peer=ep.peer,
            steps=n,
            sim_time_s=n * cfg.dt,
            wall_time_s=time.monotonic() - wall0,
            end_reason=end,
            crashed=ep.first_crash_step is not None,
            first_crash_step=ep.first_crash_step,
            final_pos_error_m=err,
            initial_state=tuple(float(v) for v in state0),
            final_state=tuple(float(v) for v in plant.state),
            dropped=dict(ep.dropped),
            esc_timeouts=ep.esc_timeouts,
            commands=ep.commands,
            esc_cut_silence_s=ep.esc_cut_silence_s,
            period_jitter_ms=jitter,
            overruns=ep.overruns,
            rate_limited_steps=plant.rate_limited_steps,
            touchdown=ep.touchdown,
            max_descent_speed=ep.max_descent_speed,
            motors_off_airborne_steps=ep.motors_off_airborne_steps,
            truth=ep.truth,
        )

    def _await_heartbeat(self, link, ep: EpisodeTally) -> str | None:
        """Wait for the peer's HEARTBEAT before the first step: None once it came, else why the
        episode ends ("no_heartbeat" after `lockstep_timeout_s`, "stopped"). What else arrives is
        counted as usual; an actuator message is dropped (`before_heartbeat`)."""
        heartbeats = self.stats.heartbeats
        deadline = time.monotonic() + self.cfg.lockstep_timeout_s
        while self.stats.heartbeats == heartbeats:
            if self._stop.is_set():
                return "stopped"
            left = deadline - time.monotonic()
            if left <= 0:
                log.info(
                    "episode %d: no HEARTBEAT from %s within %.1f s", ep.index, ep.peer, self.cfg.lockstep_timeout_s
                )
                return "no_heartbeat"
            if self._io.receive(link, min(left, POLL_S), ep) is not None:
                self._io.drop("before_heartbeat", ep)
        return None

    def _advance(self, link, plant: Plant, command: np.ndarray, n: int, rng, ep: EpisodeTally) -> int:
        """Step the plant once, send the next step's messages, then note a crash (after the send:
        the peer computes its answer meanwhile); returns the new step."""
        airborne = not plant.on_ground
        tilt = max(abs(float(plant.state[ROLL])), abs(float(plant.state[PITCH])))  # the ground levels it
        plant.step(command)
        if airborne:
            ep.max_descent_speed = max(ep.max_descent_speed, -float(plant.state[VZ]), plant.impact_speed)
            if not np.any(command):
                ep.motors_off_airborne_steps += 1
        n += 1
        if ep.truth is not None:
            ep.truth.append((n * self.cfg.dt, plant.state.tolist()))
        if n == self._impulse_step:
            plant.hit(self.cfg.impulse[0])  # before this step's messages: the peer sees it next
        ep.steps_done = n
        self.stats.steps += 1
        self._io.send_step(link, plant, n, self._sensors)
        if ep.first_crash_step is None:
            if self.cfg.start == "air":
                # The ground holds the drone at z = 0, so `crashed`'s "below ground" never fires
                # here: a flight started in the air that touches the ground has crashed (the event
                # z < 0 was before the ground plane).
                # A first contact slow and upright is a landing (the node's own, when it has lost its
                # state); staying on the ground after one is no crash either.
                if not plant.on_ground:
                    crash = crashed_one(plant.state, self._target, self._reward)
                elif ep.touchdown is None and airborne:
                    ep.touchdown = (n, plant.impact_speed, math.degrees(tilt))
                    crash = not (plant.impact_speed < TOUCHDOWN_MAX_SPEED and ep.touchdown[2] < TOUCHDOWN_MAX_TILT_DEG)
                else:
                    crash = ep.touchdown is None
            else:
                # A landed start is a commanded flight: it rests on the ground by design and goes
                # wherever the ground station sends it, so neither the ground nor the flight area
                # around the episode's target applies; a tilt beyond the limit still does.
                roll, pitch = float(plant.state[ROLL]), float(plant.state[PITCH])
                crash = max(abs(roll), abs(pitch)) > self._reward.max_tilt
            if crash:
                ep.first_crash_step = n
        return n

    def _lockstep(self, link, plant: Plant, rng, ep: EpisodeTally) -> tuple[int, str]:
        cfg = self.cfg
        held = plant.rotor.copy()  # a bad first command keeps the start's hover speed
        n = ep.steps_done = 0
        last_valid = 0  # step of the last applied command; the ESC timeout runs on simulated time here
        cut = False
        link.spin_s = spin.spin_window(cfg.spin_s)
        while n < cfg.max_steps:
            deadline = time.monotonic() + cfg.lockstep_timeout_s
            msg = None
            while msg is None:
                if self._stop.is_set():
                    return n, "stopped"
                left = deadline - time.monotonic()
                if left <= 0:
                    return n, "lockstep_timeout"
                msg = self._io.receive(link, min(left, POLL_S), ep)
            command = self._io.command(msg, ep)  # a dropped one still answers the step: the peer waits
            if command is not None:
                held, last_valid, cut = command, n, False
            elif not cut and (n - last_valid) * cfg.dt > cfg.esc_timeout_s:
                cut, held = True, np.zeros(dynamics.NUM_MOTORS)
                self._esc_cut(ep, (n - last_valid) * cfg.dt)
            n = self._advance(link, plant, held, n, rng, ep)
        return n, "max_steps"

    def _realtime(self, link, plant: Plant, rng, ep: EpisodeTally) -> tuple[int, str]:
        cfg = self.cfg
        held = plant.rotor.copy()  # the vehicle starts flying at hover until the first command
        n = ep.steps_done = 0
        last_message = last_valid = time.monotonic()
        cut = False
        tick = last_message + cfg.dt
        while n < cfg.max_steps:
            while True:  # take messages until this step's deadline
                if self._stop.is_set():
                    return n, "stopped"
                left = tick - time.monotonic()
                if left <= 0:
                    break
                msg = self._io.receive(link, min(left, POLL_S), ep)
                if msg is not None:
                    last_message = time.monotonic()
                    command = self._io.command(msg, ep)
                    if command is not None:  # only an applied command feeds the ESC timeout
                        held, last_valid, cut = command, last_message, False
            now = time.monotonic()
            if now - last_message > cfg.lockstep_timeout_s:
                return n, "peer_silent"
            silent = now - last_valid
            if not cut and silent > cfg.esc_timeout_s:
                cut, held = True, np.zeros(dynamics.NUM_MOTORS)
                self._esc_cut(ep, silent)
            ep.step_times.append(time.monotonic())
            n = self._advance(link, plant, held, n, rng, ep)
            tick += cfg.dt
            if time.monotonic() - tick > cfg.dt:  # more than a step behind: do not burst to catch up
                self.stats.overruns += 1
                ep.overruns += 1
                tick = time.monotonic() + cfg.dt
        return n, "max_steps"

    def _esc_cut(self, ep: EpisodeTally, silent: float) -> None:
        """The ESCs saw no valid command for `silent` s (more than esc_timeout_s): motors cut, counted."""
        ep.esc_timeouts += 1
        if ep.esc_cut_silence_s is None:
            ep.esc_cut_silence_s = silent
        self.stats.esc_timeouts += 1
        log.info("episode %d: no valid actuator command for %.3f s, motors cut", ep.index, silent)
