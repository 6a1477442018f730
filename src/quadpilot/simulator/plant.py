"""The simulated vehicle's physics (`Plant`): `core.dynamics.step` on a batch of one, with wind and
gusts as its external force, a ground plane under it, kept inside the domain the model holds in.

The ground is the simulator's alone (the training environments have none: `core.dynamics` is
free flight). It is the plane z = GROUND_Z of the world ENU frame, at the home position's altitude,
and the vehicle touches it with its centre of mass (the state's position): landed means z = 0.
"""

from __future__ import annotations

import math

import numpy as np

from quadpilot.core import dynamics
from quadpilot.core.frames import euler_to_rotmat, rotmat_to_euler
from quadpilot.core.params import ParamBatch, VehicleParams
from quadpilot.core.state import ATT, PITCH, RATES, ROLL, VEL, VX, VY, VZ, YAW, R, X, Y, Z
from quadpilot.link import wire

from . import sensors
from .single_step import SingleStep

_HALF_PI = 0.5 * math.pi
_MOTORS_OFF = np.zeros(1, bool)  # core.dynamics.step's `armed` for the batch of one, motors off

GROUND_Z = 0.0
"""m, world ENU: height of the ground plane (the home position's altitude, `SimConfig.home`)."""

GROUND_FRICTION = 0.5
"""Coulomb friction coefficient between the vehicle's feet and the ground, one value for sticking
and sliding. PX4's SIH uses 0.5 (static) and 0.4 (kinetic) for its rover's wheels on the ground
(PX4-Autopilot src/modules/simulation/simulator_sih/sih.cpp, generate_rover_ackermann_dynamics,
MU_S and MU_K); this model takes the static one. With 0.5 a vehicle sliding on the ground with
its motors off decelerates at 0.5·g ≈ 4.9 m/s², and a level one at rest holds against a side force
of up to half its weight."""


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
    linearly and quadratically in time.

    The ground (`_touch_ground`) is a unilateral contact resolved once per step on velocities, the
    time-stepping form of rigid contact with Coulomb friction (Stewart and Trinkle, "An implicit
    time-stepping scheme for rigid body dynamics with inelastic collisions and Coulomb friction",
    IJNME 39(15), 1996), for one contact point, the centre of mass. When the free-flight step
    (`core.dynamics.step`) would carry the vehicle from above the plane to below it, the ground
    applies the smallest upward impulse that stops the descent (an inelastic impact: no bounce) and a
    horizontal friction impulse of at most GROUND_FRICTION times it (Coulomb: it stops the sliding
    when it can, so a vehicle at rest stays at rest and one sliding decelerates at μ·g); the
    vehicle ends the step on the plane, never below it. Roll, pitch and the body rates are set to
    zero on contact, keeping the yaw: the landing gear stands level on flat ground, as RotorPy 3.0.0
    does (rotorpy/vehicles/multirotor.py, `_handle_vehicle_on_ground`, whose per-step velocity
    damping this Coulomb law replaces). PX4's SIH (sih.cpp, `equations_of_motion`, "fake ground")
    cancels the net force once the vehicle is already below the ground and stops it in one step,
    which lets it sink by up to one step of travel (6 cm at 6 m/s and 100 Hz): the impulse here acts
    in the step that would cross the plane instead. Lift-off needs nothing: with thrust above the
    weight the free step ends above the plane and no contact is made. The model has no tipping over
    and no bounce; a vehicle that starts below the plane (only an explicit `SimConfig.initial_state`
    can put it there) is under the ground and falls freely."""

    def __init__(
        self,
        vehicle: VehicleParams,
        dt: float,
        wind=(0.0, 0.0, 0.0),
        gust_std: float = 0.0,
        gust_tau_s: float = 2.0,
        rng: np.random.Generator | None = None,
        ground_friction: float = GROUND_FRICTION,
    ) -> None:
        self.vehicle = vehicle
        self.params = ParamBatch.from_preset(vehicle, 1)
        self.dt = dt
        self._single = SingleStep(self.params, dt)  # core.dynamics.step for one drone, same bits
        self.wind = np.asarray(wind, np.float64)
        # F = drag·(wind − v): core.dynamics applies −drag·v itself (params.drag) and takes the
        # drag·wind part as its external force, as the training environments' wind does.
        self._wind_force = vehicle.drag * self.wind  # N, world ENU
        self._windy = bool(self._wind_force.any())
        # the quadratic body drag (`VehicleParams.c_dx` ...) and the rotor aerodynamics (k_d ...)
        # act on the airspeed: core.dynamics takes the wind itself for them
        terms = (vehicle.c_dx, vehicle.c_dy, vehicle.c_dz, vehicle.k_d, vehicle.k_z, vehicle.k_h, vehicle.k_flap)
        self._quadratic = any(terms)
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
        self.ground_friction = float(ground_friction)
        self.state = np.zeros(dynamics.STATE_DIM)
        self.rotor = np.full(dynamics.NUM_MOTORS, self.hover_command)
        self.rate_limited_steps = 0
        """Steps whose body rates had to be saturated at MAX_BODY_RATE (see the class docstring)."""
        self.on_ground = False
        """The ground held the vehicle in the last step (or it starts resting on it)."""
        self.impact_speed = 0.0
        """m/s, the downward speed the ground took away in the last step (0 in the air; at rest g·dt)."""
        self._contact_acc: np.ndarray | None = None  # m/s², world ENU: the ground's force / mass

    def reset(self, state: np.ndarray, rotor: np.ndarray | None = None) -> None:
        """Start from `state` (12,) with the rotors at `rotor` (4,) ω/ω_max; None: at rest for a
        vehicle resting on the ground (`resting_on_ground`: a landed start), at hover speed otherwise."""
        self.state = np.array(state, dtype=np.float64).reshape(dynamics.STATE_DIM)
        resting = resting_on_ground(self.state)
        if rotor is None:
            self.rotor = np.full(dynamics.NUM_MOTORS, 0.0 if resting else self.hover_command)
        else:
            self.rotor = np.array(rotor, dtype=np.float64).reshape(dynamics.NUM_MOTORS)
        self.rate_limited_steps = 0
        self.gust = self._rng.normal(0.0, self.gust_std, 3) if self.gust_std > 0 else np.zeros(3)
        self.impact_speed = 0.0
        self._contact_acc = self._support() if resting else None
        self.on_ground = self._contact_acc is not None

    @property
    def air(self) -> np.ndarray:
        """m/s, world ENU: the wind now (constant part plus gust)."""
        return self.wind + self.gust

    def step(self, command: np.ndarray, armed: bool | None = None) -> None:
        """Advance one dt with `command` (4,) in [0, 1] held. `armed` False: the motors are off, and
        the rotors spin down to a stop even on a vehicle whose armed motors idle at ω_min > 0
        (`core.dynamics`, `armed`). None: off when every command is exactly 0, which is what the
        simulator holds for a disarmed peer (`protocol`, a disarmed HIL_ACTUATOR_CONTROLS) and after
        the ESC timeout (`process`); an armed peer commanding 0 on every motor is then read as off
        too. With ω_min = 0 (the shipped vehicles) off and a zero command are the same step."""
        command = np.asarray(command, np.float64)
        if armed is None:
            armed = bool(command.any())
        force = self._wind_force if self._windy else None
        if self.gust_std > 0:
            self.gust = self._gust_decay * self.gust + self._gust_kick * self._rng.normal(size=3)
            force = self.vehicle.drag * self.air
            force = force if force.any() else None
        before = self.state
        out = self._single.step(before, self.rotor, command, force, armed)  # the same bits, in scalar arithmetic
        if out is None:  # a step the scalar code declines (see `single_step`): core.dynamics' own
            s, w = dynamics.step(
                before[None],
                self.rotor[None],
                command[None],
                self.params,
                self.dt,
                force=None if force is None else force[None],
                armed=None if armed else _MOTORS_OFF,
                wind=self.air[None] if self._quadratic else None,
            )
            out = s[0], w[0]
        self.state, self.rotor = out
        if before[Z] >= GROUND_Z > self.state[Z]:  # the free step would cross the plane downwards
            self._touch_ground(before, self.state)
            if resting_on_ground(before) and resting_on_ground(self.state):
                # still standing: the ground's force now holds it under the rotors' thrust now, which
                # a spinning-up rotor has raised above the step's mean (none once it passes the weight)
                self._contact_acc = self._support()
        elif self.on_ground:
            self.on_ground, self.impact_speed, self._contact_acc = False, 0.0, None
        self._keep_in_domain(self.state)

    def hit(self, dv_east: float) -> None:
        """An impulse: the velocity jumps by `dv_east` m/s towards east (world +x) now."""
        self.state = self.state.copy()
        self.state[VX] += dv_east

    def _touch_ground(self, before: np.ndarray, s: np.ndarray) -> None:
        """Resolve the contact of the step from `before` whose free-flight end is `s`, in place (see
        the class docstring): velocity impulses, then the position they give, then the level stance."""
        vx, vy, vz = v_free = s[VEL].tolist()
        normal = max(-vz, 0.0)  # m/s, the normal impulse per unit mass: it stops the descent
        slip = math.hypot(vx, vy)
        limit = self.ground_friction * normal  # m/s, Coulomb: friction impulse ≤ μ · normal impulse
        if slip <= limit:
            vx = vy = 0.0  # friction stops the sliding (and keeps a vehicle at rest where it is)
        else:
            keep = 1.0 - limit / slip
            vx, vy = vx * keep, vy * keep
        h = self.dt
        # The velocity changed by a constant impulse over the step: the position moves by the mean of
        # the start and end velocities (core.dynamics' constant-acceleration formula, with the
        # friction added); the height is the plane's.
        s[X] = before[X] + 0.5 * h * (before[VX] + vx)
        s[Y] = before[Y] + 0.5 * h * (before[VY] + vy)
        s[Z] = GROUND_Z
        s[VX], s[VY], s[VZ] = vx, vy, vz + normal
        s[ROLL] = s[PITCH] = 0.0  # standing level on its landing gear; the yaw stays
        s[RATES] = 0.0
        self.on_ground = True
        self.impact_speed = normal
        self._contact_acc = (s[VEL] - np.asarray(v_free)) / h

    def _support(self) -> np.ndarray | None:
        """m/s², world ENU: the ground's force / mass holding a resting vehicle where it is, under
        its rotors, gravity and the air: the normal force cancels the net downward force, friction the
        horizontal one up to μ times the normal force. None when nothing presses it down."""
        v = self.vehicle
        thrust_up = euler_to_rotmat(*self.state[ATT])[:, 2] * (self.thrust_n / v.mass)
        net = thrust_up + v.drag * (self.air - self.state[VEL]) / v.mass
        if self._quadratic:
            net = net + sensors.rotation(self.state) @ sensors.air_force_flu(self.state, self.rotor, v, self.air)
        net[2] -= v.gravity
        if net[2] >= 0.0:
            return None
        normal = -net[2]
        side = math.hypot(net[0], net[1])
        grip = 1.0 if side <= self.ground_friction * normal else self.ground_friction * normal / side
        return np.array([-net[0] * grip, -net[1] * grip, normal])

    def _keep_in_domain(self, s: np.ndarray) -> None:
        """Saturate the body rates and canonicalise roll and pitch, in place (class docstring)."""
        roll, pitch, _, p, q, r = s[ROLL : R + 1].tolist()  # plain floats: comparisons cheaper than numpy's
        lim = wire.MAX_BODY_RATE
        if not (-lim <= p <= lim and -lim <= q <= lim and -lim <= r <= lim):
            np.clip(s[RATES], -lim, lim, out=s[RATES])
            self.rate_limited_steps += 1
        if not (-math.pi <= roll <= math.pi and -_HALF_PI <= pitch <= _HALF_PI):
            angles = rotmat_to_euler(euler_to_rotmat(s[ROLL], s[PITCH], s[YAW]))
            s[ATT] = [float(a) for a in angles]

    @property
    def thrust_n(self) -> float:
        """N, total rotor thrust at the current rotor speeds."""
        return float(self._f_max * np.add.reduce(self.rotor * self.rotor))  # np.sum's reduction, without its wrapper

    def specific_force_flu(self, rot: np.ndarray | None = None) -> np.ndarray:
        """m/s², body FLU, what an ideal accelerometer reads now (with the ground's force while the
        vehicle is on it: (0, 0, +g) at rest there, as a real IMU reads). `rot`: the state's body →
        world rotation, if known (`sensors.rotation`)."""
        v = self.vehicle
        if not v.drag and not self._quadratic and self._contact_acc is None:  # nothing but thrust
            return np.array([0.0, 0.0, self.thrust_n / v.mass])
        f = sensors.specific_force_flu(self.state, self.thrust_n, v.mass, v.drag, self.air, self._contact_acc, rot)
        if self._quadratic:
            f += sensors.air_force_flu(self.state, self.rotor, v, self.air, rot)
        return f


def resting_on_ground(state: np.ndarray) -> bool:
    """A 12-state standing still on the ground plane: at its height, with no velocity (a landed start)."""
    return bool(state[Z] == GROUND_Z and not np.any(state[VEL]))


def landed_state(yaw: float = 0.0) -> np.ndarray:
    """(12,) at rest on the ground at the home position (the local origin), level, heading `yaw` (rad, ENU)."""
    s = np.zeros(dynamics.STATE_DIM)
    s[Z], s[YAW] = GROUND_Z, yaw
    return s
