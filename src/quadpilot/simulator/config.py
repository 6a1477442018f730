"""What defines a simulator run (`SimConfig`): where it listens, the airframe and how it differs
from the nominal one, wind, sensor noise, the task and start states, the timing rules. Every field
has a `quad-sitl --sim-only` flag (`cli`) or a sensible default, and is checked when the config is
made (a ValueError naming the field and what it expects).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from quadpilot.core import dynamics
from quadpilot.core.mission import TASKS, Mission, plan_episode
from quadpilot.core.params import VehicleParams, checked_motor_tau
from quadpilot.core.sensor_noise import SENSOR_NOISE_PRESETS, SensorNoise, get_sensor_noise
from quadpilot.core.start import sample_start_states
from quadpilot.core.vehicle_file import get_preset
from quadpilot.link import wire
from quadpilot.link.spin import LOCKSTEP_SPIN_S, check_spin
from quadpilot.link.transport import Address, parse_address

from .faults import SensorFault
from .plant import landed_state

DEFAULT_WIND_DRAG = 0.2
"""N·s/m, linear drag used when there is wind and neither the vehicle (no drag law of its own:
linear, quadratic or rotor aerodynamics) nor `SimConfig.drag` gives one. An assumed order of
magnitude for a ~0.7 kg quadrotor under the linear rotor-drag model (Faessler, Franchi and
Scaramuzza, RA-L 2018), not identified for this airframe: a 5 m/s wind then pushes with 1 N, 15 % of
the seed vehicle's weight."""

START_MODES = ("air", "landed")
MAX_IMPULSE_MPS = 20.0  # m/s, the largest velocity jump `SimConfig.impulse` takes
"""`SimConfig.start`: where an episode starts."""


@dataclass(frozen=True)
class SimConfig:
    """Everything that defines a simulator run; every field has a `quad-sitl --sim-only` flag or a
    sensible default."""

    listen: str = "tcp:127.0.0.1:4560"
    """Where to listen: tcp:HOST:PORT (PX4's simulators use TCP 4560) or udp:HOST:PORT. Port 0
    picks a free port (see `Simulator.address`). Loopback by default."""
    vehicle: str = "seed"
    """Airframe preset name ("seed", "crazyflie", "px4_sih_quadx"), see `core.vehicle_file.get_preset`."""
    mass_scale: float = 1.0
    """Multiplies the preset's mass (the controller still believes the nominal one)."""
    inertia_scale: float = 1.0
    """Multiplies the preset's three principal inertias."""
    motor_scale: float = 1.0
    """Multiplies the rotor thrust coefficient k_f (weaker or stronger motors)."""
    motor_tau: float | None = None
    """s, first-order motor time constant replacing the preset's (0 for the shipped presets)."""
    wind: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """m/s, constant wind velocity in world ENU. It acts through linear drag, F = drag·(wind − v)."""
    gust: float = 0.0
    """m/s, standard deviation of wind gusts on each axis (0: none), added to `wind`."""
    gust_tau_s: float = 2.0
    """s, correlation time of the gusts."""
    impulse: tuple[float, float] | None = None
    """(m/s, s): a hit, once per episode: at this time into the episode the vehicle's velocity jumps by
    this much towards east (world +x), the momentum mass × it delivered in one step. None: none."""
    drag: float | None = None
    """N·s/m, linear translational drag on the air-relative velocity, F = drag·(wind − v), world
    frame. None: the preset's own value (0 for the shipped presets, as in training), or
    DEFAULT_WIND_DRAG if that is 0 and there is wind, so that wind alone does something."""
    imu_noise: bool = False
    """Noisy gyro and accelerometer in HIL_SENSOR: the IMU of the vehicle's `core.sensor_noise`
    preset (seed: ADIS16448 with PX4's Gazebo IMU plugin defaults, white noise σ = density/√dt, 3.4e-3
    rad/s and 0.04 m/s² at 100 Hz, plus turn-on bias and bias random walk; crazyflie: BMI088), the
    model the training environments use; refused for a vehicle without one (px4_sih_quadx). The
    ground truth in HIL_STATE_QUATERNION stays exact."""
    estimator_noise: bool = False
    """Also send ODOMETRY each step: the state as an estimator would report it (the vehicle's
    `core.sensor_noise` estimator model: cm-level position, velocity and attitude errors), which the
    node then flies on instead of the ground truth; HIL_STATE_QUATERNION stays exact (judging)."""
    record_truth: bool = False
    """Keep the ground truth of every step in the episode's record (`EpisodeRecord.truth`): what a
    benchmark plots when the node itself had no state to log."""
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
    spin_s: float = LOCKSTEP_SPIN_S
    """s, in lockstep: poll for the peer's actuator message this long before sleeping
    (`link.transport.Link.spin_s`; 0: sleep at once, off with one usable CPU)."""
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
    start: str = "air"
    """air: each episode starts in flight, rotors at hover speed (`initial_state`, or a draw from the
    training start distribution). landed: at rest on the ground (`plant.GROUND_Z`) at the home
    position (the local origin), level, nose east (yaw 0), rotors at rest (`plant.landed_state`)."""
    signing_key: bytes | None = field(default=None, repr=False)
    """MAVLink 2 signing key (32 bytes): sign every message and accept only authentic, fresh,
    signed ones (`link.transport.SigningMAVLink`); the replay window carries over between episodes."""
    airframe: VehicleParams | None = None
    """The airframe read from a vehicle file (`core.vehicle_file`), flown instead of the preset
    `vehicle` names, with the same scales, motor time constant and drag rules; `vehicle` then names
    the preset whose sensor models (`core.sensor_noise`) the noise flags use, and the noise flags
    are refused when the file's vehicle is not that preset. None: the preset itself."""
    airframe_source: str = ""
    """Where `airframe` came from (a path, shown in messages)."""
    sensor_faults: tuple[SensorFault, ...] = ()
    """Sensor faults injected at a set simulated time of every episode (`faults`, `--sensor-fault`)."""

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
        check_spin(self.spin_s)
        if self.impulse is not None:
            dv, at = self.impulse
            if not (math.isfinite(dv) and abs(dv) <= MAX_IMPULSE_MPS and math.isfinite(at) and at >= 0):
                raise ValueError(f"impulse must be (m/s within ±{MAX_IMPULSE_MPS:g}, s ≥ 0), got {self.impulse!r}")
        for name in ("wind", "target"):
            v = getattr(self, name)
            if len(v) != 3 or not all(math.isfinite(float(x)) for x in v):
                raise ValueError(f"{name} must be three finite numbers (x, y, z), got {v!r}")
        if self.motor_tau is not None:
            checked_motor_tau(self.motor_tau)
        if self.drag is not None and not (math.isfinite(self.drag) and self.drag >= 0):
            raise ValueError(f"drag must be a finite number ≥ 0 (N·s/m), got {self.drag!r}")
        for name, lo in (("gps_every", 1), ("max_steps", 1), ("seed", 0)):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < lo:
                raise ValueError(f"{name} must be an integer ≥ {lo}, got {v!r}")
        if self.episodes is not None and (not isinstance(self.episodes, int) or self.episodes < 1):
            raise ValueError(f"episodes must be an integer ≥ 1 or None (for ever), got {self.episodes!r}")
        if not all(isinstance(f, SensorFault) for f in self.sensor_faults):
            raise ValueError(f"sensor_faults must be SensorFault values (faults.parse_faults): {self.sensor_faults!r}")
        if self.signing_key is not None and (not isinstance(self.signing_key, bytes) or len(self.signing_key) != 32):
            raise ValueError("signing_key must be 32 bytes")
        if self.airframe is not None and not isinstance(self.airframe, VehicleParams):
            raise ValueError(f"airframe must be a VehicleParams, got {type(self.airframe).__name__}")
        # the noise models belong to an airframe preset (`core.sensor_noise`), and not every preset has
        # them (px4_sih_quadx has none): asked for noise, a vehicle without them is refused here, once
        flown = self.airframe.name if self.airframe is not None else self.vehicle
        if (self.imu_noise or self.estimator_noise) and (flown != self.vehicle or flown not in SENSOR_NOISE_PRESETS):
            raise ValueError(
                f"--imu-noise/--estimator-noise: no sensor model for vehicle {flown!r} "
                f"(sensor models exist for {', '.join(sorted(SENSOR_NOISE_PRESETS))})"
            )
        if self.start not in START_MODES:
            raise ValueError(f"start must be one of {START_MODES}, got {self.start!r}")
        if self.start == "landed" and self.initial_state is not None:
            raise ValueError("start 'landed' puts the vehicle on the ground: give it or initial_state, not both")
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
        v = self.base_vehicle
        # a vehicle with a drag law of its own (linear, or RotorPy's quadratic drag and rotor
        # aerodynamics, which act on the wind themselves) gets no assumed one added
        own_law = v.drag > 0 or any((v.c_dx, v.c_dy, v.c_dz, v.k_d, v.k_z, v.k_h, v.k_flap))
        return DEFAULT_WIND_DRAG if not own_law and (any(self.wind) or self.gust > 0) else v.drag

    @property
    def base_vehicle(self) -> VehicleParams:
        """The airframe before scaling: the file's (`airframe`), else the preset `vehicle`."""
        return self.airframe if self.airframe is not None else get_preset(self.vehicle)

    @property
    def vehicle_params(self) -> VehicleParams:
        """The simulated airframe: `base_vehicle` with the scales and the drag applied."""
        s = self.inertia_scale
        scaled = self.base_vehicle.scaled(mass=self.mass_scale, ixx=s, iyy=s, izz=s, k_f=self.motor_scale)
        if self.motor_tau is not None:
            scaled = dataclasses.replace(scaled, motor_tau=self.motor_tau)
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
        imu = get_sensor_noise(self.vehicle).imu if self.imu_noise else None  # only then has a model
        return imu.gyro_noise_density / math.sqrt(self.dt) if imu else 0.0

    @property
    def accel_noise_std(self) -> float:
        """m/s² per sample (white part), 0 without `imu_noise`."""
        imu = get_sensor_noise(self.vehicle).imu if self.imu_noise else None  # only then has a model
        return imu.accel_noise_density / math.sqrt(self.dt) if imu else 0.0

    def mission(self, episode: int) -> Mission:
        return plan_episode(self.task, self.seed, episode, self.dt)

    def area_centre(self, episode: int) -> np.ndarray:
        """m, world ENU: the point `crashed` measures the flight area (5 m) from."""
        if self.task == "hover":
            return np.asarray(self.target, np.float64)
        m = self.mission(episode)
        return np.asarray(m.home if self.task == "circle" else m.target, np.float64)

    def start_state(self, episode: int) -> tuple[np.ndarray, np.random.Generator]:
        """(12-state, generator) of episode `episode`: landed (`start`), `initial_state`, or a draw
        from the training start distribution with np.random.default_rng([seed, episode]); the
        generator then feeds the sensor noise."""
        rng = np.random.default_rng([self.seed, episode])
        if self.start == "landed":
            return landed_state(), rng
        if self.initial_state is not None:
            return np.array(self.initial_state, dtype=np.float64), rng
        if self.task != "hover":
            s = self.mission(episode).start_state(rng, self.init_vel, self.init_tilt_deg, self.init_rate)
            return s, rng
        centre = np.asarray(self.target, np.float64)[None, :]
        s = sample_start_states(rng, centre, self.init_pos_radius, self.init_vel, self.init_tilt_deg, self.init_rate)
        return s[0], rng
