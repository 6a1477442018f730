"""Classical fallback controller: what flies the vehicle when the learned policy may not.

The safety monitor hands control here when the policy's output is non-finite or the state has left
the policy's envelope. The job is to bring the vehicle back to the target and hold it there, from
any attitude the policy could plausibly have left it in, without a model of its own beyond the
nominal `VehicleParams`. NumPy and `quadpilot.core` only (see docs/architecture.md, import direction).

Structure, a cascade from the slow loop to the fast one, each stage saturated before the next:

1. Position P → velocity set-point (clipped to a maximum speed, so a far start cruises instead of
   accelerating for ever).
2. Velocity PI → desired acceleration (clipped vertically and horizontally, tilt ≤ `max_tilt_deg`).
   The integral of the velocity error is the integral action on position: with v_sp = −k_p·e,
   ∫(v_sp − v) dt = −k_p·∫e dt − (e − e₀). At rest it can only settle where e = 0, so a thrust or
   mass mismatch (a constant force) leaves no steady position error. Placed on the velocity error
   rather than directly on e, it needs no overshoot to unwind after an offset start: a plain
   position PID starting with an empty integrator must return ∫e to its final value, so an offset
   start always overshoots (25 % for a triple real pole); here ∫(v_sp − v) stays near zero whenever
   the vehicle follows its velocity set-point. This is the structure of PX4's multicopter position
   controller (mc_pos_control: position P, velocity PID).
3. Geometric attitude control on SO(3) after Lee, Leok & McClamroch, "Geometric tracking control of
   a quadrotor UAV on SE(3)", CDC 2010 (arXiv:1003.2005), section III: desired body z axis along
   the desired force, thrust = that force projected on the current body z axis, desired x axis from
   the held heading, attitude error e_R = ½(R_dᵀR − RᵀR_d)^∨, moment
   M = −k_R·e_R − k_Ω·Ω + Ω × JΩ (desired body rates taken as zero: a hover controller).
4. Mixing: total thrust and body moments → per-rotor thrusts through the inverse of the vehicle's
   allocation matrix (`core.params.allocation_matrix`: its rotor positions, spins and output order,
   the same map the model integrates), roll/pitch before collective thrust before yaw when a rotor
   saturates, then ω = √(F/k_f) and the command ω/ω_max in [0, 1] (PX4 HIL_ACTUATOR_CONTROLS
   convention, the vehicle's output order).

Frames as in `core`: world ENU (z up), body FLU. A version-1 observation carries no target heading,
so the controller holds the heading it found on its first call after construction or `reset()`, and
damps the yaw rate; a version-2 observation's attitude is relative to the commanded heading, and
with `heading_frame=True` the controller holds that heading (yaw 0 in the observation). The
integrator and the held heading are the only state; `reset()` clears both, and the first `act`
after it latches the heading (unless `heading_frame`). Reset at the start of each flight and call `act` only
while the fallback flies (as `runtime.safety` does): then the heading is latched at the hand-over.
A fallback stepped in the background ("shadow mode") would need a `reset()` at the hand-over.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from quadpilot.core.observation import HOVER_LAYOUT, TRACK_LAYOUT
from quadpilot.core.params import VehicleParams
from quadpilot.core.params import allocation_matrix as allocation_matrix  # re-exported: the mixer's matrix
from quadpilot.core.vehicle_file import get_preset

_HOVER_SLICES = HOVER_LAYOUT.slices()
_TRACK_SLICES = TRACK_LAYOUT.slices()
_POS, _VEL, _ROT, _RATES = (_HOVER_SLICES[k] for k in ("pos_error", "vel", "rot", "rates"))
_TARGET_VEL = _TRACK_SLICES["target_vel"]
_MAX_ABS_OBS = 1e6  # see `FallbackController.act`
if any(_TRACK_SLICES[k] != _HOVER_SLICES[k] for k in _HOVER_SLICES):
    raise ImportError("fallback: the track observation layout no longer extends the hover layout; update the slices")


@dataclass(frozen=True)
class FallbackGains:
    """Gains and limits of the fallback controller for one airframe, in physical units.

    Build with `FallbackGains.for_vehicle`, which derives them from closed-loop frequencies and the
    vehicle's mass, inertia and rotor authority; any field can be overridden with
    `dataclasses.replace`.
    """

    pos_p: float
    """1/s, position error → velocity set-point (the position loop's bandwidth)."""
    vel_p: float
    """N·s/m, velocity error → force (mass × the velocity loop's bandwidth)."""
    vel_i: float
    """N/m, integrated velocity error (m) → force; the integral action on position."""
    integral_limit_xy: float
    """N, anti-windup clamp on the horizontal magnitude of the integral force."""
    integral_limit_z: float
    """N, anti-windup clamp on the vertical integral force; must exceed the worst weight mismatch
    to be absorbed (0.2·m·g for ±20 % mass)."""
    max_speed_xy: float
    """m/s, horizontal speed set-point limit (a far start cruises at this speed)."""
    max_speed_z: float
    """m/s, vertical speed set-point limit, up and down."""
    max_accel_xy: float
    """m/s², horizontal acceleration command limit (before the tilt limit, which may be tighter)."""
    max_accel_up: float
    """m/s², upward acceleration command limit (on top of gravity compensation)."""
    max_accel_down: float
    """m/s², downward acceleration command limit; below g so the rotors keep some thrust, and with
    it attitude authority, while descending."""
    max_tilt_deg: float
    """deg, limit on the angle between the commanded thrust direction and world up."""
    att_p: tuple[float, float, float]
    """N·m/rad, attitude error → moment about body x, y, z (k_R of Lee et al. 2010, per axis)."""
    rate_d: tuple[float, float, float]
    """N·m·s/rad, body rate → damping moment about body x, y, z (k_Ω of Lee et al. 2010)."""

    @classmethod
    def for_vehicle(
        cls,
        vehicle: VehicleParams,
        dt: float = 0.01,
        *,
        att_damping: float = 0.8,
        att_ref_angle: float = 0.6,
        yaw_ref_angle: float = 0.5,
        max_att_freq_dt: float = 0.2,
        vel_to_att_ratio: float = 0.4,
        pos_to_vel_ratio: float = 0.25,
        integral_zero_ratio: float = 0.25,
        max_tilt_deg: float = 35.0,
    ) -> FallbackGains:
        """Gains for `vehicle` at control period `dt` from closed-loop frequencies.

        Attitude, per axis: J·ë = −k_R·e − k_Ω·ė closes to ω_n² = k_R/J and 2ζω_n = k_Ω/J, so
        k_R = J·ω_n², k_Ω = 2ζ·J·ω_n. ω_n is chosen per axis as the smaller of two bounds:
        - authority: a step of `att_ref_angle` rad (about the 35° tilt limit) should ask for no more
          angular acceleration than the rotors give at hover without losing collective thrust:
          α_max = ΔF·Σ_i lever_i/J with ΔF = min over rotors of min(F_hover,i, F_max − F_hover,i)
          and lever_i = |y_i| for roll, |x_i| for pitch (FLU), k_m for yaw: 4·arm/√2 and 4·k_m for
          a quad-X; so ω_n = √(α_max/ref). The yaw lever k_m is about a tenth of the arm,
          so yaw gets the lower bandwidth, most of all on the seed vehicle;
        - sampling: ω_n·dt ≤ `max_att_freq_dt` keeps the zero-order hold's phase lag (ω·dt/2 rad)
          near 6°, where the continuous-time design still holds.
        Seed vehicle at 100 Hz: roll/pitch ≈ 18.7 rad/s (authority), yaw ≈ 5.4 rad/s. Crazyflie: 20
        rad/s on all three axes (sampling), its rotors having ~3× the angular authority per inertia.

        Translation, per axis, in acceleration units (then × mass, so a heavier preset gets
        proportionally larger force gains): velocity P bandwidth k_v = `vel_to_att_ratio`·ω_att, so
        the attitude loop is ~2.5× faster and looks nearly instantaneous to it; the PI zero at
        k_i/k_v = `integral_zero_ratio`·k_v; position bandwidth k_p = `pos_to_vel_ratio`·k_v. The
        closed loop s³ + k_v·s² + (k_v·k_p + k_i)·s + k_i·k_p has its poles at −1.27 and
        −2.96 ± 3.09j rad/s for the seed vehicle (k_v 7.2/s, k_i 12.9/s², k_p 1.8/s) and −1.41 and
        −3.30 ± 3.44j for the Crazyflie (8, 16, 2). Measured on the full model: no overshoot on a
        1 m step, within 2 cm after 2.8 s (seed) and 2.5 s (Crazyflie).
        """
        if not (dt > 0 and math.isfinite(dt)):
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        trim, f_max = vehicle.hover_thrusts, vehicle.max_thrust
        if not f_max > float(trim.max()):
            raise ValueError(
                f"vehicle {vehicle.name!r} cannot hover: a rotor's full thrust {f_max:.3g} N is at most its hover "
                f"thrust {float(trim.max()):.3g} N (weight {vehicle.weight:.3g} N)"
            )
        df = float(np.minimum(trim, f_max - trim).min())  # N, per-rotor differential available around hover
        a = allocation_matrix(vehicle)  # rows: thrust, τx, τy, τz per newton of each rotor
        inertia = (vehicle.ixx, vehicle.iyy, vehicle.izz)
        levers = tuple(float(np.abs(a[k]).sum()) for k in (1, 2, 3))  # m, Σ_i lever_i about x, y, z
        refs = (att_ref_angle, att_ref_angle, yaw_ref_angle)
        w_cap = max_att_freq_dt / dt
        w_att = [min(math.sqrt(df * lv / j / ref), w_cap) for j, lv, ref in zip(inertia, levers, refs, strict=True)]
        att_p = tuple(j * w * w for j, w in zip(inertia, w_att, strict=True))
        rate_d = tuple(2.0 * att_damping * j * w for j, w in zip(inertia, w_att, strict=True))

        m, g = vehicle.mass, vehicle.gravity
        k_v = vel_to_att_ratio * min(w_att[0], w_att[1])  # 1/s
        k_i = integral_zero_ratio * k_v * k_v  # 1/s²
        k_p = pos_to_vel_ratio * k_v  # 1/s
        return cls(
            pos_p=k_p,
            vel_p=m * k_v,
            vel_i=m * k_i,
            # ±35 % of weight vertically absorbs ±20 % mass with room to spare; horizontally 20 % of
            # weight (≈11° of tilt) covers a centre-of-mass offset or a steady wind.
            integral_limit_xy=0.2 * m * g,
            integral_limit_z=0.35 * m * g,
            max_speed_xy=2.0,
            max_speed_z=1.5,
            # horizontal acceleration: g·tan(30°) ≈ 5.7 m/s², inside the tilt limit at hover thrust
            max_accel_xy=g * math.tan(math.radians(30.0)),
            max_accel_up=0.5 * g,
            max_accel_down=0.5 * g,
            max_tilt_deg=max_tilt_deg,
            att_p=att_p,
            rate_d=rate_d,
        )


class FallbackController:
    """Cascaded position/velocity/attitude hover controller with motor mixing (one drone).

    `act(obs)` takes one observation in the `core.observation` hover (18) or track (21) layout and
    returns float32 (M,) rotor commands ω/ω_max in [0, 1] in the vehicle's output order, always
    finite. Stateful: a velocity-error integrator and the held heading; `reset()` clears both.
    """

    def __init__(
        self, vehicle: VehicleParams, dt: float = 0.01, gains: FallbackGains | None = None, heading_frame: bool = False
    ) -> None:
        """heading_frame: the observation's attitude is relative to the commanded heading (the
        version-2 layouts, `core.observation`): hold that heading, yaw 0 in the observation, instead
        of the heading found at the first call."""
        if not (dt > 0 and math.isfinite(dt)):
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        self.vehicle = vehicle
        self.dt = float(dt)
        self.gains = FallbackGains.for_vehicle(vehicle, dt) if gains is None else gains
        g = self.gains
        m = vehicle.mass

        # Translational gains per unit mass (acceleration units); the force is m·a at the end.
        self._k_p = g.pos_p
        self._k_v = g.vel_p / m
        self._k_i = g.vel_i / m
        self._i_max_xy = g.integral_limit_xy / g.vel_i if g.vel_i > 0 else 0.0  # m, on the integrator state
        self._i_max_z = g.integral_limit_z / g.vel_i if g.vel_i > 0 else 0.0
        self._tan_tilt = math.tan(math.radians(g.max_tilt_deg))
        self._mass = m
        self._gravity = vehicle.gravity
        self._k_r = np.array(g.att_p, dtype=np.float64)
        self._k_w = np.array(g.rate_d, dtype=np.float64)
        self._inertia = np.array([vehicle.ixx, vehicle.iyy, vehicle.izz])

        # Mixing: split the inverse allocation into the collective, roll/pitch and yaw columns, so
        # saturation can give way in order of importance.
        inv = np.linalg.inv(allocation_matrix(vehicle))  # four rotors: square, and invertible (VehicleParams)
        self._mix_f = inv[:, 0].copy()  # per-rotor thrust per newton of collective (¼ each on a balanced frame)
        self._mix_rp = inv[:, 1:3].copy()
        self._mix_yaw = inv[:, 3].copy()
        self._f_max = vehicle.max_thrust  # N per rotor at command 1
        self._hover = np.asarray(vehicle.hover_commands, dtype=np.float32)

        self._integral = np.zeros(3)  # m, ∫(v_sp − v) dt in the world frame
        self._heading: tuple[float, float] | None = None  # (cos ψ, sin ψ) held
        self.heading_frame = bool(heading_frame)
        self.reset()

    @classmethod
    def for_preset(cls, name: str, dt: float = 0.01) -> FallbackController:
        """Controller with the derived gains for a `core.params` preset ("seed", "crazyflie")."""
        return cls(get_preset(name), dt)

    @property
    def hover_command(self) -> np.ndarray:
        """float32 (M,): the nominal hover trim per rotor, returned for any non-finite observation."""
        return self._hover.copy()

    def reset(self) -> None:
        """Clear the integrator and the held heading: the next `act` behaves like a fresh controller's."""
        self._integral[:] = 0.0
        self._heading = (1.0, 0.0) if self.heading_frame else None

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Rotor commands for one observation.

        obs: float (18,) hover layout or (21,) track layout (`core.observation`): position error
        Rᵀ(p − p_target), velocity Rᵀv, R body→world row-major, body rates [, target velocity Rᵀv_t].
        Returns float32 (M,) in [0, 1], ω/ω_max per rotor in the vehicle's output order.
        A non-finite observation (or one with a value beyond ±1e6) returns the hover trim and
        leaves the integrator and the held heading untouched.
        """
        obs = np.asarray(obs, dtype=np.float64)
        if obs.shape != (HOVER_LAYOUT.dim,) and obs.shape != (TRACK_LAYOUT.dim,):
            raise ValueError(
                f"observation must have shape ({HOVER_LAYOUT.dim},) ({HOVER_LAYOUT.name}) or "
                f"({TRACK_LAYOUT.dim},) ({TRACK_LAYOUT.name}), got {obs.shape}"
            )
        # NaN fails the comparison too. Beyond 1e6 (m, m/s, rad/s) no value describes a flying
        # vehicle, and products of such values could overflow: treat them as invalid as well.
        if not np.abs(obs).max() <= _MAX_ABS_OBS:
            return self._hover.copy()
        cmd = self._act(obs)
        if not np.isfinite(cmd).all():  # degenerate geometry; never hand a NaN to the motors
            return self._hover.copy()
        return cmd

    def _act(self, obs: np.ndarray) -> np.ndarray:
        rot = obs[_ROT].reshape(3, 3)  # body → world
        err = rot @ obs[_POS]  # world, p − p_target
        vel = rot @ obs[_VEL]  # world
        rates = obs[_RATES]

        if self._heading is None:
            # Hold the heading found at hand-over: yaw of the body x axis (ZYX: atan2(R21, R11)).
            psi = math.atan2(rot[1, 0], rot[0, 0])
            self._heading = (math.cos(psi), math.sin(psi))

        # 1. position P → velocity set-point, saturated (horizontal magnitude, vertical each way)
        v_sp = -self._k_p * err
        if obs.shape[0] == TRACK_LAYOUT.dim:
            v_sp += rot @ obs[_TARGET_VEL]  # feed the target's velocity forward
        return self._track(rot, vel, rates, v_sp)

    def track_velocity(self, rot: np.ndarray, vel: np.ndarray, rates: np.ndarray, v_sp: np.ndarray) -> np.ndarray:
        """Rotor commands that fly the velocity set-point `v_sp` (m/s, world ENU): stages 2 to 4 alone,
        for a caller with no position to hold (`autopilot.state_loss`: height held, or a descent).
        rot (3, 3) body → world, vel (3,) m/s world, rates (3,) rad/s body FLU. Saturated as in `act`;
        the hover trim for anything non-finite."""
        rot, vel, rates = (np.asarray(a, np.float64) for a in (rot, vel, rates))
        v_sp = np.array(v_sp, np.float64)
        if not all(np.isfinite(a).all() for a in (rot, vel, rates, v_sp)):
            return self._hover.copy()
        if self._heading is None:
            psi = math.atan2(rot[1, 0], rot[0, 0])
            self._heading = (math.cos(psi), math.sin(psi))
        cmd = self._track(rot, vel, rates, v_sp)
        return cmd if np.isfinite(cmd).all() else self._hover.copy()

    def _track(self, rot: np.ndarray, vel: np.ndarray, rates: np.ndarray, v_sp: np.ndarray) -> np.ndarray:
        g, dt = self._gravity, self.dt
        v_sp[:2] = _clip_norm(v_sp[:2], self.gains.max_speed_xy)
        v_sp[2] = min(max(v_sp[2], -self.gains.max_speed_z), self.gains.max_speed_z)

        # 2. velocity PI → acceleration, saturated: vertical first, then horizontal within the
        # tilt the vertical command leaves (tan θ = |a_xy| / (g + a_z)).
        ev = v_sp - vel
        acc = self._k_v * ev + self._k_i * self._integral
        az = min(max(acc[2], -self.gains.max_accel_down), self.gains.max_accel_up)
        sat_z = az != acc[2]
        a_xy_max = min(self.gains.max_accel_xy, (g + az) * self._tan_tilt)
        a_xy_norm = math.hypot(acc[0], acc[1])
        sat_xy = a_xy_norm > a_xy_max
        if sat_xy:
            acc[:2] *= a_xy_max / a_xy_norm
        acc[2] = az
        # Anti-windup: integrate only along axes whose command is not saturated (conditional
        # integration), and clamp what has been integrated.
        if not sat_xy:
            self._integral[:2] = _clip_norm(self._integral[:2] + dt * ev[:2], self._i_max_xy)
        if not sat_z:
            self._integral[2] = min(max(self._integral[2] + dt * ev[2], -self._i_max_z), self._i_max_z)

        # 3. geometric attitude control (Lee, Leok & McClamroch 2010)
        force = self._mass * acc
        force[2] += self._mass * g  # desired force, world; force[2] ≥ m·(g − max_accel_down) > 0
        b3 = rot[:, 2]  # current body z axis in the world
        thrust = max(float(force @ b3), 0.0)  # f = F·R e3; no thrust while pointing away from F
        b3d = force / math.sqrt(float(force @ force))
        c, s = self._heading
        b2d = _cross(b3d, (c, s, 0.0))  # b1c = held heading; |b3d × b1c| > 0 as the tilt is < 90°
        b2d /= math.sqrt(float(b2d @ b2d))
        b1d = _cross(b2d, b3d)
        rd_t_r = np.array((b1d, b2d, b3d)) @ rot  # R_dᵀR (rows of R_dᵀ are b1d, b2d, b3d)
        # e_R = ½(R_dᵀR − RᵀR_d)^∨, and RᵀR_d = (R_dᵀR)ᵀ
        e_r = 0.5 * np.array((rd_t_r[2, 1] - rd_t_r[1, 2], rd_t_r[0, 2] - rd_t_r[2, 0], rd_t_r[1, 0] - rd_t_r[0, 1]))
        moment = -self._k_r * e_r - self._k_w * rates + _cross(rates, self._inertia * rates)

        # 4. mixing
        return self._mix(thrust, moment)

    def _mix(self, thrust: float, moment: np.ndarray) -> np.ndarray:
        """Collective thrust (N) and body moment (N·m) → float32 rotor commands in [0, 1].

        When rotors saturate, roll/pitch are kept (scaled only if their spread alone exceeds the
        rotor range), the collective gives way to them, and yaw takes whatever margin is left: a
        vehicle that holds its attitude can recover height, one that does not cannot.
        """
        f_max = self._f_max
        d_rp = self._mix_rp @ moment[:2]
        spread = float(d_rp.max() - d_rp.min())
        if spread > f_max:
            d_rp *= f_max / spread
        # collective T with rotor i at T·c_i + d_i: keep every rotor in [0, f_max] where some T can
        # (c_i > 0: a flyable vehicle's hover trim is positive on every rotor)
        c = self._mix_f
        lo, hi = float((-d_rp / c).max()), float(((f_max - d_rp) / c).min())
        t = min(max(thrust, lo), hi) if lo <= hi else lo
        per_rotor = t * c + d_rp
        d_yaw = self._mix_yaw * moment[2]
        # largest scale s ∈ [0, 1] keeping per_rotor + s·d_yaw within [0, f_max]
        scale = 1.0
        for f, dy in zip(per_rotor.tolist(), d_yaw.tolist(), strict=True):
            room = f_max - f if dy > 0 else f  # N this rotor can still go up (dy > 0) or down
            if abs(dy) * scale > room:
                scale = max(room, 0.0) / abs(dy)
        per_rotor += scale * d_yaw
        # F = k_f·ω² and f_max = k_f·ω_max², so ω/ω_max = √(F/f_max); clip only rounding
        cmd = np.sqrt(np.minimum(np.maximum(per_rotor * (1.0 / f_max), 0.0), 1.0))
        return cmd.astype(np.float32)


def _clip_norm(v: np.ndarray, limit: float) -> np.ndarray:
    n = math.hypot(*v)
    return v * (limit / n) if n > limit else v


def _cross(a, b) -> np.ndarray:
    """3-vector cross product; np.cross costs ~10 µs on 3-vectors, this ~1 µs."""
    return np.array((a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]))
