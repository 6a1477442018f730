"""The simulator side of software-in-the-loop: `core.dynamics` served over MAVLink like a PX4
simulator (PX4's "Simulator MAVLink API"; DESIGN.md "The wire").

The simulator listens (TCP 127.0.0.1:4560 by default, UDP as an option) and serves one episode per
connection. Each step it sends, in this order:

1. HIL_GPS, every `gps_every` steps (step 0 included);
2. HIL_STATE_QUATERNION, the ground truth (with the body specific force as its acceleration);
3. ODOMETRY, with `estimator_noise` only: the state estimate, "what an EKF would output" (the
   truth plus `core.sensor_noise`'s estimator errors; the node flies on it, and is judged on 2);
4. HIL_SENSOR, last, because a PX4 peer steps on it: gyro (body rates), accelerometer (specific
   force), magnetometer, barometer (with `imu_noise`: `core.sensor_noise`'s IMU model);

and then, in lockstep, waits for exactly one HIL_ACTUATOR_CONTROLS, applies it and advances the
physics by one `dt`. In realtime mode it advances on the host's monotonic clock instead, holding
the last command like an ESC and cutting the motors when valid commands stop.

Commands: `controls[0..3]` is ω/ω_max per rotor in PX4 quad-X order (`link.wire`). While the
peer is disarmed (mode bit 128 clear) the motors get 0 whatever it sends. An armed message with a
non-finite or out-of-range (outside [0, 1]) value in controls[0..3] is dropped, counted, and the
motors keep their previous command; in lockstep it still counts as the peer's answer for the step
(the peer is waiting for the next HIL_SENSOR: not stepping would stall both sides). Only applied
commands (armed and valid, or disarmed: motors 0) feed the ESC timeout: after `esc_timeout_s`
without one (host clock in realtime, simulated time in lockstep) the motors are cut, so a stream of
bad commands cannot keep the last good one alive.

Every in-range command sequence keeps the simulation finite and every message encodable, however
long it runs: the plant stays in its model's domain (`Plant`), the barometer in its atmosphere's
(`sensors.isa_pressure_hpa`), and integer wire fields saturate at their MAVLink types' limits
(`link.wire`).

Everything else that arrives is dispatched on its type at one receive point: HEARTBEAT is counted,
BAD_DATA (pymavlink's type for garbage and bad CRCs) and unknown message ids are dropped and counted
by reason, other known messages are counted as ignored. Malformed input never ends the simulator.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from quadpilot.core import dynamics
from quadpilot.core.frames import euler_to_rotmat, rotmat_to_euler
from quadpilot.core.mission import TASKS, Mission, plan_episode
from quadpilot.core.params import ParamBatch, VehicleParams, get_preset
from quadpilot.core.reward import RewardConfig, crashed
from quadpilot.core.sensor_noise import SensorNoise, SensorNoiseState, get_sensor_noise
from quadpilot.core.start import sample_start_states
from quadpilot.link import wire
from quadpilot.link.transport import (
    Address,
    Listener,
    PeerClosed,
    SigningError,
    SimulatorError,
    bad_data_reason,
    parse_address,
    read_key,
)

from . import sensors

__all__ = [
    "DEFAULT_WIND_DRAG",
    "TIME_ORIGIN_US",
    "EpisodeRecord",
    "Plant",
    "SimConfig",
    "SimStats",
    "Simulator",
    "SimulatorError",
    "main_sim_only",
]

log = logging.getLogger(__name__)

TIME_ORIGIN_US = 1_000_000
"""µs, time_usec of an episode's first messages; it then grows by dt per step. Not zero, because
some autopilots treat a zero timestamp as 'not set'."""
DEFAULT_WIND_DRAG = 0.2
"""N·s/m, linear drag used when there is wind and neither the preset nor `SimConfig.drag` gives
one. An assumed order of magnitude for a ~0.7 kg quadrotor under the linear rotor-drag model
(Faessler, Franchi and Scaramuzza, RA-L 2018), not identified for this airframe: a 5 m/s wind then
pushes with 1 N, 15 % of the seed vehicle's weight."""
POLL_S = 0.05
"""s, longest a wait goes without looking at `stop()`."""

_HALF_PI = 0.5 * math.pi

END_REASONS = ("peer_closed", "lockstep_timeout", "peer_silent", "max_steps", "stopped")


@dataclass(frozen=True)
class SimConfig:
    """Everything that defines a simulator run; every field has a `quad-sitl --sim-only` flag or a
    sensible default."""

    listen: str = "tcp:127.0.0.1:4560"
    """Where to listen: tcp:HOST:PORT (PX4's simulators use TCP 4560) or udp:HOST:PORT. Port 0
    picks a free port (see `Simulator.address`). Loopback by default."""
    vehicle: str = "seed"
    """Airframe preset name ("seed", "crazyflie"), see `core.params.get_preset`."""
    mass_scale: float = 1.0
    """Multiplies the preset's mass (the controller still believes the nominal one)."""
    inertia_scale: float = 1.0
    """Multiplies the preset's three principal inertias."""
    motor_scale: float = 1.0
    """Multiplies the rotor thrust coefficient k_f (weaker or stronger motors)."""
    motor_tau_s: float | None = None
    """s, first-order motor time constant replacing the preset's (0 for the shipped presets)."""
    wind: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """m/s, constant wind velocity in world ENU. It acts through linear drag, F = drag·(wind − v)."""
    gust: float = 0.0
    """m/s, standard deviation of wind gusts on each axis (0: none), added to `wind`."""
    gust_tau_s: float = 2.0
    """s, correlation time of the gusts."""
    drag: float | None = None
    """N·s/m, linear translational drag on the air-relative velocity, F = drag·(wind − v), world
    frame. None: the preset's own value (0 for the shipped presets, as in training), or
    DEFAULT_WIND_DRAG if that is 0 and there is wind, so that wind alone does something."""
    imu_noise: bool = False
    """Noisy gyro and accelerometer in HIL_SENSOR: the IMU of the vehicle's `core.sensor_noise`
    preset (seed: ADIS16448 with PX4's Gazebo IMU plugin defaults, white noise σ = density/√dt, 3.4e-3
    rad/s and 0.04 m/s² at 100 Hz, plus turn-on bias and bias random walk; crazyflie: BMI088), the
    model the training environments use. The ground truth in HIL_STATE_QUATERNION stays exact."""
    estimator_noise: bool = False
    """Also send ODOMETRY each step: the state as an estimator would report it (the vehicle's
    `core.sensor_noise` estimator model: cm-level position, velocity and attitude errors), which the
    node then flies on instead of the ground truth; HIL_STATE_QUATERNION stays exact (judging)."""
    dt: float = dynamics.DT
    """s, simulation step (0.01 s, the control step the policies were trained at)."""
    task: str = "hover"
    """hover, waypoint or circle (`core.mission`): waypoint and circle episodes start where
    `core.mission.plan_episode(task, seed, episode)` says (the autopilot draws its target from the
    same call), and `crashed` measures the flight area from that episode's target (circle: centre)."""
    target: tuple[float, float, float] = (0.0, 0.0, 2.0)
    """m, world ENU, hover: the hover target (the training environment's `home`): centre of the start
    distribution, and the point `crashed` measures the flight area from."""
    init_pos_radius: float = 1.0
    """m, start position uniform in a ball of this radius around `target`."""
    init_vel: float = 0.5
    """m/s, each start velocity component uniform in ±init_vel."""
    init_tilt_deg: float = 20.0
    """deg, start roll and pitch uniform in ±init_tilt_deg; yaw uniform in [−180°, 180°)."""
    init_rate: float = 0.0
    """rad/s, each start body rate uniform in ±init_rate."""
    seed: int = 0
    """Episode k draws its start state, then its sensor noise, from np.random.default_rng([seed, k])."""
    episodes: int | None = None
    """How many episodes (connections) to serve before `serve()` returns; None: until stopped."""
    home: wire.Home = field(default_factory=wire.Home)
    """Geodetic origin of the local frame (the default is PX4 SITL's home in Zürich)."""
    gps_every: int = 10
    """Steps between HIL_GPS messages (10 at dt 0.01 s is 10 Hz)."""
    lockstep: bool = True
    """True: one physics step per HIL_ACTUATOR_CONTROLS, as fast as the peer answers. False:
    realtime, one step per dt of the host's monotonic clock, the last command held."""
    esc_timeout_s: float = 0.1
    """s, with no valid actuator command for this long the motors are cut to 0 (an ESC's signal-loss
    behaviour): host clock in realtime mode, simulated time in lockstep (where only a stream of
    dropped commands can cause it); counted in `SimStats.esc_timeouts`."""
    lockstep_timeout_s: float = 5.0
    """s, an episode ends when no actuator message has arrived for this long (lockstep never
    waits for ever; in realtime mode it ends an episode whose peer fell silent)."""
    max_steps: int = 360_000
    """Safety bound on the steps of one episode (360 000 × 0.01 s = one hour)."""
    initial_state: tuple[float, ...] | None = None
    """Explicit 12-state (ENU/FLU, SI) every episode starts from, instead of sampling one."""
    signing_key: bytes | None = field(default=None, repr=False)
    """MAVLink 2 signing key (32 bytes): sign every message and accept only authentic, fresh,
    signed ones (`link.transport.SigningMAVLink`); the replay window carries over between episodes."""

    def __post_init__(self) -> None:
        parse_address(self.listen)
        get_preset(self.vehicle)
        if self.task not in TASKS:
            raise ValueError(f"task must be one of {TASKS}, got {self.task!r}")
        for name in (
            "mass_scale",
            "inertia_scale",
            "motor_scale",
            "dt",
            "esc_timeout_s",
            "lockstep_timeout_s",
            "gust_tau_s",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        for name in ("init_pos_radius", "init_vel", "init_tilt_deg", "init_rate", "gust"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number ≥ 0, got {v!r}")
        for name in ("wind", "target"):
            v = getattr(self, name)
            if len(v) != 3 or not all(math.isfinite(float(x)) for x in v):
                raise ValueError(f"{name} must be three finite numbers (x, y, z), got {v!r}")
        if self.motor_tau_s is not None and not (math.isfinite(self.motor_tau_s) and self.motor_tau_s >= 0):
            raise ValueError(f"motor_tau_s must be a finite number ≥ 0 (s), got {self.motor_tau_s!r}")
        if self.drag is not None and not (math.isfinite(self.drag) and self.drag >= 0):
            raise ValueError(f"drag must be a finite number ≥ 0 (N·s/m), got {self.drag!r}")
        for name, lo in (("gps_every", 1), ("max_steps", 1), ("seed", 0)):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < lo:
                raise ValueError(f"{name} must be an integer ≥ {lo}, got {v!r}")
        if self.episodes is not None and (not isinstance(self.episodes, int) or self.episodes < 1):
            raise ValueError(f"episodes must be an integer ≥ 1 or None (for ever), got {self.episodes!r}")
        if self.signing_key is not None and (not isinstance(self.signing_key, bytes) or len(self.signing_key) != 32):
            raise ValueError("signing_key must be 32 bytes")
        if self.initial_state is not None:
            s = np.asarray(self.initial_state, dtype=np.float64)
            if s.shape != (dynamics.STATE_DIM,) or not np.all(np.isfinite(s)):
                raise ValueError(
                    f"initial_state must be {dynamics.STATE_DIM} finite numbers {dynamics.STATE_NAMES}, "
                    f"got {self.initial_state!r}"
                )

    @property
    def address(self) -> Address:
        return parse_address(self.listen)

    @property
    def effective_drag(self) -> float:
        """N·s/m, the drag coefficient the plant uses (see `drag`)."""
        if self.drag is not None:
            return float(self.drag)
        own = get_preset(self.vehicle).drag
        return DEFAULT_WIND_DRAG if own == 0 and (any(self.wind) or self.gust > 0) else own

    @property
    def vehicle_params(self) -> VehicleParams:
        """The simulated airframe: the preset with the scales and the drag applied."""
        s = self.inertia_scale
        scaled = get_preset(self.vehicle).scaled(mass=self.mass_scale, ixx=s, iyy=s, izz=s, k_f=self.motor_scale)
        if self.motor_tau_s is not None:
            scaled = dataclasses.replace(scaled, motor_tau=self.motor_tau_s)
        return dataclasses.replace(scaled, drag=self.effective_drag)

    @property
    def sensor_noise(self) -> SensorNoise | None:
        """The `core.sensor_noise` model in force: the vehicle's preset with the parts switched on."""
        if not (self.imu_noise or self.estimator_noise):
            return None
        return get_sensor_noise(self.vehicle).with_parts(imu=self.imu_noise, estimator=self.estimator_noise)

    @property
    def gyro_noise_std(self) -> float:
        """rad/s per sample (white part), 0 without `imu_noise`."""
        imu = get_sensor_noise(self.vehicle).imu
        return imu.gyro_noise_density / math.sqrt(self.dt) if self.imu_noise and imu else 0.0

    @property
    def accel_noise_std(self) -> float:
        """m/s² per sample (white part), 0 without `imu_noise`."""
        imu = get_sensor_noise(self.vehicle).imu
        return imu.accel_noise_density / math.sqrt(self.dt) if self.imu_noise and imu else 0.0

    def mission(self, episode: int) -> Mission:
        return plan_episode(self.task, self.seed, episode, self.dt)

    def area_centre(self, episode: int) -> np.ndarray:
        """m, world ENU: the point `crashed` measures the flight area (5 m) from."""
        if self.task == "hover":
            return np.asarray(self.target, np.float64)
        m = self.mission(episode)
        return np.asarray(m.home if self.task == "circle" else m.target, np.float64)

    def start_state(self, episode: int) -> tuple[np.ndarray, np.random.Generator]:
        """(12-state, generator) of episode `episode`: `initial_state`, or a draw from the training
        start distribution with np.random.default_rng([seed, episode]); the generator then feeds
        the sensor noise."""
        rng = np.random.default_rng([self.seed, episode])
        if self.initial_state is not None:
            return np.array(self.initial_state, dtype=np.float64), rng
        if self.task != "hover":
            s = self.mission(episode).start_state(rng, self.init_vel, self.init_tilt_deg, self.init_rate)
            return s, rng
        centre = np.asarray(self.target, np.float64)[None, :]
        s = sample_start_states(rng, centre, self.init_pos_radius, self.init_vel, self.init_tilt_deg, self.init_rate)
        return s[0], rng


class Plant:
    """One simulated vehicle: `core.dynamics.step` on a batch of one, plus the constant part of
    the wind force. State (12,) ENU/FLU and rotor (4,) ω/ω_max, float64.

    Kept inside the domain the model holds in, whatever the commands (a peer may hold any in-range
    command for an hour): body rates are saturated at `link.wire.MAX_BODY_RATE` (counted in
    `rate_limited_steps`), because beyond it no multirotor is flying any more and the explicit
    integration of Euler's equation in `core.dynamics` amplifies the gyroscopic term ω × (Iω) by
    about √(1 + (dt·ω·ΔI/I)²) per step, which overflows to Inf within a few hundred steps of a
    tumble. Roll and pitch are kept in [−π, π] and [−π/2, π/2] (the same attitude: `core.frames`'
    ZYX angles of its rotation matrix) so that a tumble through pitch ±90° does not wind them up.
    Position and velocity need nothing: thrust and gravity are bounded, so they grow at most
    linearly and quadratically in time."""

    def __init__(
        self,
        vehicle: VehicleParams,
        dt: float,
        wind=(0.0, 0.0, 0.0),
        gust_std: float = 0.0,
        gust_tau_s: float = 2.0,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.vehicle = vehicle
        self.params = ParamBatch.from_preset(vehicle, 1)
        self.dt = dt
        self.wind = np.asarray(wind, np.float64)
        # F = drag·(wind − v): core.dynamics applies −drag·v itself (params.drag) and takes the
        # drag·wind part as its external force, as the training environments' wind does.
        self._wind_force = vehicle.drag * self.wind  # N, world ENU
        # Gusts: each axis a first-order Gauss-Markov (Ornstein-Uhlenbeck) velocity with standard
        # deviation gust_std and correlation time gust_tau_s, discretised exactly per step (the
        # first-order shaping filter behind the Dryden model's low-frequency part, MIL-F-8785C).
        self.gust_std = float(gust_std)
        self._gust_decay = math.exp(-dt / gust_tau_s)
        self._gust_kick = self.gust_std * math.sqrt(1.0 - self._gust_decay**2)
        self._rng = rng if rng is not None else np.random.default_rng(0)
        self.gust = np.zeros(3)
        self._f_max = vehicle.k_f * vehicle.omega_max**2  # N per rotor at command 1
        self.hover_command = float(vehicle.hover_command)
        self.state = np.zeros(dynamics.STATE_DIM)
        self.rotor = np.full(dynamics.NUM_MOTORS, self.hover_command)
        self.rate_limited_steps = 0
        """Steps whose body rates had to be saturated at MAX_BODY_RATE (see the class docstring)."""

    def reset(self, state: np.ndarray) -> None:
        """Start from `state` (12,) with the rotors at hover speed."""
        self.state = np.array(state, dtype=np.float64).reshape(dynamics.STATE_DIM)
        self.rotor = np.full(dynamics.NUM_MOTORS, self.hover_command)
        self.rate_limited_steps = 0
        self.gust = self._rng.normal(0.0, self.gust_std, 3) if self.gust_std > 0 else np.zeros(3)

    @property
    def air(self) -> np.ndarray:
        """m/s, world ENU: the wind now (constant part plus gust)."""
        return self.wind + self.gust

    def step(self, command: np.ndarray) -> None:
        """Advance one dt with `command` (4,) in [0, 1] held."""
        force = self._wind_force
        if self.gust_std > 0:
            self.gust = self._gust_decay * self.gust + self._gust_kick * self._rng.normal(size=3)
            force = self.vehicle.drag * self.air
        s, w = dynamics.step(
            self.state[None],
            self.rotor[None],
            np.asarray(command, np.float64)[None],
            self.params,
            self.dt,
            force=force[None] if force.any() else None,
        )
        self.state, self.rotor = s[0], w[0]
        self._keep_in_domain(self.state)

    def _keep_in_domain(self, s: np.ndarray) -> None:
        """Saturate the body rates and canonicalise roll and pitch, in place (class docstring)."""
        roll, pitch, _, p, q, r = s[6:12].tolist()  # plain floats: comparisons cheaper than numpy's
        lim = wire.MAX_BODY_RATE
        if not (-lim <= p <= lim and -lim <= q <= lim and -lim <= r <= lim):
            np.clip(s[9:12], -lim, lim, out=s[9:12])
            self.rate_limited_steps += 1
        if not (-math.pi <= roll <= math.pi and -_HALF_PI <= pitch <= _HALF_PI):
            angles = rotmat_to_euler(euler_to_rotmat(s[6], s[7], s[8]))
            s[6:9] = [float(a) for a in angles]

    @property
    def thrust_n(self) -> float:
        """N, total rotor thrust at the current rotor speeds."""
        return float(self._f_max * np.sum(self.rotor * self.rotor))

    def specific_force_flu(self) -> np.ndarray:
        """m/s², body FLU, what an ideal accelerometer reads now."""
        return sensors.specific_force_flu(self.state, self.thrust_n, self.vehicle.mass, self.vehicle.drag, self.air)


@dataclass
class EpisodeRecord:
    """What one episode (one connection) did."""

    index: int
    peer: str
    steps: int
    sim_time_s: float
    wall_time_s: float
    end_reason: str
    """One of END_REASONS: peer_closed (TCP EOF), lockstep_timeout, peer_silent (realtime),
    max_steps, stopped."""
    crashed: bool
    """`core.reward.crashed` (below ground, tilt > 60° or > 5 m from `target`) at any step."""
    first_crash_step: int | None
    final_pos_error_m: float
    initial_state: tuple[float, ...]
    final_state: tuple[float, ...]
    dropped: dict[str, int]
    esc_timeouts: int
    commands: int = 0
    """HIL_ACTUATOR_CONTROLS messages applied (armed and valid, or disarmed: motors 0)."""
    esc_cut_silence_s: float | None = None
    """How long valid commands had been missing when the ESCs cut the motors, s (host clock in realtime,
    simulated time in lockstep; None: never)."""
    period_jitter_ms: tuple[float, float, float] | None = None
    """Realtime: |step period − dt| in ms over the episode, (p50, p99, max)."""
    overruns: int = 0
    """Realtime: steps that started more than one dt late."""
    rate_limited_steps: int = 0
    """Steps whose body rates the plant had to saturate at `link.wire.MAX_BODY_RATE` (a tumble)."""

    def summary(self) -> str:
        dropped = sum(self.dropped.values())
        crash = f"crashed at step {self.first_crash_step}" if self.crashed else "no crash"
        return (
            f"episode {self.index}: {self.steps} steps ({self.sim_time_s:.2f} s simulated, "
            f"{self.wall_time_s:.2f} s wall), ended by {self.end_reason}, {crash}, "
            f"final error {self.final_pos_error_m:.3f} m, dropped {dropped} packets"
            + (f", {self.esc_timeouts} ESC timeouts" if self.esc_timeouts else "")
        )


@dataclass
class SimStats:
    """Counters over all episodes; `records` has one entry per finished episode."""

    steps: int = 0
    episodes: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    """Packets thrown away, by reason: garbage (a run of stray bytes without a MAVLink start
    marker, as pymavlink reports it), bad_crc, bad_data (other framing errors), unknown_message_id,
    signature_unsigned / signature_bad / signature_replayed / signature_stale (signing on),
    parser_error, non_finite_control, out_of_range_control, before_first_state (UDP: an actuator
    message in the datagram that opened the episode), foreign_peer (UDP: a datagram from anyone but
    the pinned peer), truncated_datagram (UDP: a datagram that ended inside a message),
    oversized_datagram (UDP: longer than link.transport.MAX_DATAGRAM, dropped unparsed)."""
    ignored: dict[str, int] = field(default_factory=dict)
    """Well-formed messages the simulator has no use for, by type."""
    heartbeats: int = 0
    esc_timeouts: int = 0
    """Times the motors were cut because valid commands stopped (see `SimConfig.esc_timeout_s`)."""
    overruns: int = 0
    """Realtime mode: steps that started more than one dt late (the clock was then re-synchronised)."""
    records: list[EpisodeRecord] = field(default_factory=list)


class _Episode:
    """Per-episode bookkeeping."""

    def __init__(self, index: int, peer: str) -> None:
        self.index, self.peer = index, peer
        self.dropped: dict[str, int] = {}
        self.esc_timeouts = 0
        self.esc_cut_silence_s: float | None = None
        self.commands = 0
        self.step_times: list[float] = []
        self.overruns = 0
        self.steps_done = 0
        self.first_crash_step: int | None = None


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
        self._noise: SensorNoiseState | None = None  # this episode's sensor noise processes

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
                for msg in early:  # UDP: what arrived before (and including) the first valid message
                    if self._dispatch(msg, None) is not None:
                        self._drop("before_first_state", None)
                if link is None:
                    break
                if cfg.signing_key is not None:
                    link.sign(cfg.signing_key, state=self._signing)
                    self._signing = link.signing_state
                try:
                    record = self._run_episode(link, k)
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

    def _run_episode(self, link, k: int) -> EpisodeRecord:
        cfg = self.cfg
        ep = _Episode(k, link.peer_label)
        state0, rng = cfg.start_state(k)
        plant = Plant(cfg.vehicle_params, cfg.dt, cfg.wind, cfg.gust, cfg.gust_tau_s, rng)
        self._target = cfg.area_centre(k)
        plant.reset(state0)
        spec = cfg.sensor_noise
        self._noise = None if spec is None else SensorNoiseState(spec, 1, cfg.dt, rng)
        if self._noise is not None:
            self._noise.reset()
            self._variances = self._estimate_variances(spec) if spec.estimator is not None else None
        n, wall0, end = 0, time.monotonic(), "max_steps"
        try:
            self._send_step(link, plant, 0, rng)
            run = self._lockstep if cfg.lockstep else self._realtime
            n, end = run(link, plant, rng, ep)
        except PeerClosed as e:
            log.debug("episode %d: %s", k, e)
            n, end = ep.steps_done, "peer_closed"
        if hasattr(link, "foreign_datagrams"):  # UDP
            self._count("foreign_peer", link.foreign_datagrams, ep)
            self._count("truncated_datagram", link.truncated_datagrams, ep)
            self._count("oversized_datagram", link.oversized_datagrams, ep)
            link.foreign_datagrams = link.truncated_datagrams = link.oversized_datagrams = 0
        err = float(np.linalg.norm(plant.state[0:3] - self._target))
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
        )

    def _advance(self, link, plant: Plant, command: np.ndarray, n: int, rng, ep: _Episode) -> int:
        """Step the plant once, send the next step's messages, then note a crash (after the send:
        the peer computes its answer meanwhile); returns the new step."""
        plant.step(command)
        n += 1
        ep.steps_done = n
        self.stats.steps += 1
        self._send_step(link, plant, n, rng)
        if ep.first_crash_step is None:
            s = plant.state[None]
            if crashed(s, s[:, 0:3] - self._target, self._reward)[0]:
                ep.first_crash_step = n
        return n

    def _lockstep(self, link, plant: Plant, rng, ep: _Episode) -> tuple[int, str]:
        cfg = self.cfg
        held = plant.rotor.copy()  # a bad first command keeps the start's hover speed
        n = ep.steps_done = 0
        last_valid = 0  # step of the last applied command; the ESC timeout runs on simulated time here
        cut = False
        while n < cfg.max_steps:
            deadline = time.monotonic() + cfg.lockstep_timeout_s
            msg = None
            while msg is None:
                if self._stop.is_set():
                    return n, "stopped"
                left = deadline - time.monotonic()
                if left <= 0:
                    return n, "lockstep_timeout"
                msg = self._receive(link, min(left, POLL_S), ep)
            command = self._command(msg, ep)  # a dropped one still answers the step: the peer waits
            if command is not None:
                held, last_valid, cut = command, n, False
            elif not cut and (n - last_valid) * cfg.dt > cfg.esc_timeout_s:
                cut, held = True, np.zeros(dynamics.NUM_MOTORS)
                self._esc_cut(ep, (n - last_valid) * cfg.dt)
            n = self._advance(link, plant, held, n, rng, ep)
        return n, "max_steps"

    def _realtime(self, link, plant: Plant, rng, ep: _Episode) -> tuple[int, str]:
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
                msg = self._receive(link, min(left, POLL_S), ep)
                if msg is not None:
                    last_message = time.monotonic()
                    command = self._command(msg, ep)
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

    def _esc_cut(self, ep: _Episode, silent: float) -> None:
        """The ESCs saw no valid command for `silent` s (more than esc_timeout_s): motors cut, counted."""
        ep.esc_timeouts += 1
        if ep.esc_cut_silence_s is None:
            ep.esc_cut_silence_s = silent
        self.stats.esc_timeouts += 1
        log.info("episode %d: no valid actuator command for %.3f s, motors cut", ep.index, silent)

    # --- messages --------------------------------------------------------------------------
    def _send_step(self, link, plant: Plant, n: int, rng: np.random.Generator) -> None:
        cfg = self.cfg
        t_us = TIME_ORIGIN_US + round(n * cfg.dt * 1e6)
        state = plant.state
        if n % cfg.gps_every == 0:
            link.mav.hil_gps_send(**wire.hil_gps_fields(state, cfg.home, t_us))
        accel = plant.specific_force_flu()
        link.mav.hil_state_quaternion_send(**wire.hil_state_quaternion_fields(state, cfg.home, t_us, accel))
        gyro = state[9:12].copy()
        noise = self._noise
        if noise is not None:  # core.sensor_noise, as in training: advance one dt, then measure
            if n > 0:
                noise.step()
            if cfg.imu_noise:
                gyro, accel = noise.gyro(gyro[None])[0], noise.accel(accel[None])[0]
            if cfg.estimator_noise:
                estimate = noise.estimate(state[None])[0]
                link.mav.odometry_send(**wire.odometry_fields(estimate, t_us, *self._variances))
        alt = cfg.home.alt_m + float(state[2])
        link.mav.hil_sensor_send(
            **wire.hil_sensor_fields(
                t_us,
                gyro,
                accel,
                sensors.magnetometer_flu(state),
                sensors.isa_pressure_hpa(alt),
                alt,
                sensors.isa_temperature_c(alt),
            )
        )
        link.flush()

    def _estimate_variances(self, spec: SensorNoise) -> tuple[list[float], list[float]]:
        """Stationary variances of the estimate (pose x, y, z, roll, pitch, yaw; velocity and rates),
        NED order, for ODOMETRY's covariance diagonals."""
        est, imu = spec.estimator, spec.imu
        p = est.pos_white**2 + est.pos_drift**2
        v = est.vel_white**2 + est.vel_drift**2
        g = (imu.gyro_noise_density**2 / self.cfg.dt + imu.gyro_turn_on_bias**2) if imu else 0.0
        return [p, p, p, est.tilt_drift**2, est.tilt_drift**2, est.yaw_drift**2], [v, v, v, g, g, g]

    def _receive(self, link, timeout: float, ep: _Episode | None):
        """The one receive point: the next message, dispatched; returns it if it is a
        HIL_ACTUATOR_CONTROLS, else None. PeerClosed propagates."""
        try:
            msg = link.recv(timeout)
        except PeerClosed:
            raise
        except Exception as e:  # a parser failure on hostile bytes must not end the simulator
            log.debug("parser error: %r", e)
            self._drop("parser_error", ep)
            return None
        return None if msg is None else self._dispatch(msg, ep)

    def _dispatch(self, msg, ep: _Episode | None):
        kind = msg.get_type()
        if kind == "HIL_ACTUATOR_CONTROLS":
            return msg
        if kind == "HEARTBEAT":
            self.stats.heartbeats += 1
        elif kind == "BAD_DATA":
            self._drop(bad_data_reason(msg), ep)
        elif kind.startswith("UNKNOWN_"):
            self._drop("unknown_message_id", ep)
        else:
            self.stats.ignored[kind] = self.stats.ignored.get(kind, 0) + 1
        return None

    def _command(self, msg, ep: _Episode) -> np.ndarray | None:
        """Motor command (4,) from an actuator message; None if it must be dropped."""
        try:
            motors, armed, _ = wire.motors_from_actuator_controls(msg)
        except (TypeError, IndexError, ValueError):
            self._drop("bad_data", ep)
            return None
        if not armed:
            ep.commands += 1
            return np.zeros(dynamics.NUM_MOTORS)
        values = motors.tolist()  # plain floats: four comparisons are cheaper than numpy calls
        if not all(math.isfinite(v) for v in values):
            self._drop("non_finite_control", ep)
            return None
        if not all(0.0 <= v <= 1.0 for v in values):
            self._drop("out_of_range_control", ep)
            return None
        ep.commands += 1
        return motors

    def _drop(self, reason: str, ep: _Episode | None) -> None:
        self._count(reason, 1, ep)

    def _count(self, reason: str, k: int, ep: _Episode | None = None) -> None:
        if k:
            self.stats.dropped[reason] = self.stats.dropped.get(reason, 0) + k
            if ep is not None:
                ep.dropped[reason] = ep.dropped.get(reason, 0) + k


# --- quad-sitl --sim-only -------------------------------------------------------------------
class UsageError(Exception):
    """A bad flag: exit code 2 with one line on stderr."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        raise UsageError(message)


def _wind(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(
            f"expected three comma-separated numbers (m/s east,north,up), e.g. 2,0,0; got {text!r}"
        )
    return values  # type: ignore[return-value]


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return v


def _non_negative(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"expected a finite number ≥ 0, got {text!r}")
    return v


def _int_at_least(lo: int):
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"must be ≥ {lo}, got {v}")
        return v

    return parse


def _listen(text: str) -> str:
    try:
        parse_address(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def build_sim_parser(prog: str = "quad-sitl --sim-only") -> argparse.ArgumentParser:
    d = SimConfig()
    p = _Parser(
        prog=prog, description="Run only the simulator: core dynamics served over MAVLink like a PX4 simulator."
    )
    p.add_argument("--sim-only", action="store_true", help=argparse.SUPPRESS)
    p.add_argument(
        "--listen", type=_listen, default=d.listen, help=f"tcp:HOST:PORT or udp:HOST:PORT (default {d.listen})"
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--lockstep", dest="lockstep", action="store_true", default=True, help="one step per actuator message (default)"
    )
    mode.add_argument("--realtime", dest="lockstep", action="store_false", help="one step per dt of wall-clock time")
    p.add_argument("--vehicle", default=d.vehicle, help=f"airframe preset (default {d.vehicle})")
    p.add_argument("--task", choices=TASKS, default=d.task, help="where episodes start (core.mission; default hover)")
    p.add_argument("--mass-scale", type=_positive, default=d.mass_scale, help="multiplies the mass")
    p.add_argument("--inertia-scale", type=_positive, default=d.inertia_scale, help="multiplies the inertias")
    p.add_argument("--motor-scale", type=_positive, default=d.motor_scale, help="multiplies the thrust coefficient k_f")
    p.add_argument("--motor-tau", type=_non_negative, default=None, metavar="S", help="motor time constant, s")
    p.add_argument("--wind", type=_wind, default=d.wind, metavar="E,N,U", help="constant wind, m/s world ENU")
    p.add_argument("--gust", type=_non_negative, default=d.gust, metavar="M/S", help="gust std per axis, m/s")
    p.add_argument("--gust-tau", type=_positive, default=d.gust_tau_s, metavar="S", help="gust correlation time, s")
    p.add_argument(
        "--init-pos-radius", type=_non_negative, default=d.init_pos_radius, metavar="M", help="start ball radius"
    )
    p.add_argument("--init-vel", type=_non_negative, default=d.init_vel, metavar="M/S", help="start velocity range ±")
    p.add_argument("--init-tilt", type=_non_negative, default=d.init_tilt_deg, metavar="DEG", help="start roll/pitch ±")
    p.add_argument("--init-rate", type=_non_negative, default=d.init_rate, metavar="RAD/S", help="start body rates ±")
    p.add_argument(
        "--drag",
        type=float,
        default=None,
        help=f"N·s/m linear drag (default: preset's, or {DEFAULT_WIND_DRAG} with wind)",
    )
    p.add_argument(
        "--imu-noise",
        action="store_true",
        help="IMU noise (core.sensor_noise, the vehicle's IMU): white noise, turn-on bias and bias random walk",
    )
    p.add_argument(
        "--estimator-noise",
        action="store_true",
        help="send ODOMETRY, the state as an EKF would output it (cm-level errors, core.sensor_noise); the "
        "node flies on it, and is judged on the exact HIL_STATE_QUATERNION",
    )
    p.add_argument(
        "--rate",
        type=_positive,
        default=1.0 / d.dt,
        metavar="HZ",
        help=f"simulation steps per second (default {1 / d.dt:g})",
    )
    p.add_argument("--seed", type=_int_at_least(0), default=d.seed, help="seed of the start states and the noise")
    p.add_argument("--episodes", type=_int_at_least(1), default=None, help="serve this many connections, then exit")
    p.add_argument("--gps-every", type=_int_at_least(1), default=d.gps_every, help="steps between HIL_GPS messages")
    p.add_argument(
        "--esc-timeout",
        type=_positive,
        default=d.esc_timeout_s,
        help="s, motors cut after this long without a valid command",
    )
    p.add_argument(
        "--lockstep-timeout", type=_positive, default=d.lockstep_timeout_s, help="s, an episode ends after this silence"
    )
    p.add_argument("--max-steps", type=_int_at_least(1), default=d.max_steps, help="step bound of one episode")
    p.add_argument("--json", metavar="OUT", default=None, help="write the stats and episode records as JSON on exit")
    p.add_argument(
        "--key",
        metavar="FILE",
        default=None,
        help="MAVLink 2 signing key (32 raw bytes or 64 hex digits): sign, and accept only signed messages",
    )
    return p


def config_from_args(args: argparse.Namespace) -> SimConfig:
    try:
        return SimConfig(
            listen=args.listen,
            task=args.task,
            vehicle=args.vehicle,
            mass_scale=args.mass_scale,
            inertia_scale=args.inertia_scale,
            motor_scale=args.motor_scale,
            motor_tau_s=args.motor_tau,
            wind=args.wind,
            gust=args.gust,
            gust_tau_s=args.gust_tau,
            init_pos_radius=args.init_pos_radius,
            init_vel=args.init_vel,
            init_tilt_deg=args.init_tilt,
            init_rate=args.init_rate,
            drag=args.drag,
            imu_noise=args.imu_noise,
            estimator_noise=args.estimator_noise,
            dt=1.0 / args.rate,
            seed=args.seed,
            episodes=args.episodes,
            gps_every=args.gps_every,
            lockstep=args.lockstep,
            esc_timeout_s=args.esc_timeout,
            lockstep_timeout_s=args.lockstep_timeout,
            max_steps=args.max_steps,
            signing_key=read_key(args.key) if args.key else None,
        )
    except (ValueError, SigningError) as e:
        raise UsageError(str(e)) from None


def _write_stats(path: str, stats: SimStats) -> None:
    import json

    try:
        with open(path, "w") as f:
            json.dump(dataclasses.asdict(stats), f, indent=1)
    except OSError as e:
        print(f"quad-sitl: cannot write {path}: {e.strerror or e}", file=sys.stderr)


def main_sim_only(argv: list[str] | None = None, prog: str = "quad-sitl") -> int:
    """`quad-sitl --sim-only [...]`: serve episodes, one line per episode on stdout. Returns the
    exit code: 0 done, 1 the simulator could not run (e.g. port taken), 2 bad flags, 130 Ctrl-C."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_sim_parser(f"{prog} --sim-only").parse_args(argv)
        cfg = config_from_args(args)
    except SystemExit as e:  # --help
        return e.code if isinstance(e.code, int) else 0
    except UsageError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 2
    sim = Simulator(cfg, on_episode=lambda r: print(r.summary(), flush=True))
    try:
        address = sim.bind()
        mode = "lockstep" if cfg.lockstep else "realtime"
        print(f"{prog}: simulator listening on {address} ({mode}, vehicle {cfg.vehicle}, seed {cfg.seed})", flush=True)
        stats = sim.serve()
    except SimulatorError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"\n{prog}: interrupted", file=sys.stderr)
        return 130
    finally:
        sim.close()
        if args.json:
            _write_stats(args.json, sim.stats)
    dropped = sum(stats.dropped.values())
    print(f"{prog}: served {stats.episodes} episodes, {stats.steps} steps, dropped {dropped} packets", flush=True)
    return 0
