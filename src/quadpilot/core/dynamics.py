"""Batched 12-state multirotor dynamics (NumPy only).

State, shape (N, 12), world frame ENU (z up), body frame FLU (x forward, y left, z up):

    x, y, z          position, m
    vx, vy, vz       velocity in the world frame, m/s
    roll, pitch, yaw ZYX Euler angles, rad (R = Rz(yaw)·Ry(pitch)·Rx(roll), body → world;
                     with FLU, positive pitch is nose down and accelerates the vehicle along +x)
    p, q, r          body rates, rad/s

Index it with the names of `core.state` (X … R, POS, VEL, ATT, RATES), the one place that names them.

Rotor state, shape (N, M): normalised rotor speed ω/ω_max, only dynamic when a motor time
constant is set. Command, shape (N, M): normalised rotor speed ω/ω_max in [0, 1], the
convention of PX4's HIL_ACTUATOR_CONTROLS (thrust ∝ command²), in the vehicle's actuator output
order. M is the vehicle's rotor count (`ParamBatch.n_rotors`; four for every `VehicleParams`).

Rotors and torques: the batch's layout (`ParamBatch.layout`: each rotor's position in body FLU per
metre of arm, and its spin) scaled by each drone's arm. A rotor at (x_i, y_i) lifting F_i along
+z_body makes r × F = (y_i·F_i, −x_i·F_i, 0); a rotor spinning counter-clockwise seen from above
(angular momentum +z) is driven by a +z motor torque, so its reaction on the body is −k_m·F_i about
z (`core.params.SPINS`). So τ_x = Σ y_i·F_i, τ_y = −Σ x_i·F_i, τ_z = −Σ spin_i·k_m·F_i, for any
positions and any output order (`core.params.allocation_matrix` is the same map as a matrix). For
PX4's quad-X (`MOTOR_LAYOUT`, the layout of every vehicle saved without a rotor list) this is the ENPM 667
project's roll and pitch arrangement, τ_x ∝ (−F1+F2+F3−F4), τ_y ∝ (F1−F2+F3−F4); the ENPM 667 project's yaw row
(−F1+F2−F3+F4) pairs adjacent rotors, which no X frame does, so the yaw row follows the physics.

Rotor speed: the commanded speed command·ω_max is clipped to [ω_min, ω_max] (RotorPy 3.0.0 does the
same, rotorpy/vehicles/multirotor.py, `Multirotor.step`), so an armed motor idles at ω_min. Motors
off (`armed` false: disarmed, or a simulator's motors-off state) command ω = 0 whatever ω_min: the
rotors spin down through the motor lag and stop. The rotor state itself is not clipped: a rotor
starting at rest spins up to ω_min through the lag (RotorPy also clips its state, which makes a
rotor at rest jump to ω_min in one step).

`Stepper` is the one implementation: it advances state rows (12, N) in place with buffers made
once, for a batch stepped every control period (the training environments); `step` copies its
inputs to rows, runs it, and returns new arrays.

Integration per (sub)step of length h: rotor lag exactly discretised, and the rotors' thrust over
the substep the mean of k_f·ω² along that exponential (RotorPy integrates the lag with the rest of
the state, so its thrust follows the rotor speed within the step; the end's ω² held for the whole
step would lead it by about half a step, which a high-gain policy on a slow motor turns into an
oscillation in RotorPy that it does not have here); body rates by Euler's
rotational equation with the gyroscopic term ω × (Iω), forward in time; Euler angles advanced with
the mid-step rates (exact for a constant torque about one axis); position with the constant-
acceleration formula p + h·v + h²/2·a (exact in free fall). Euler angles are singular at
pitch ±90°; the environments terminate at 60°.

Drag, two laws, each zero unless the vehicle sets it: linear in the world frame, −drag·v (PX4
SIH's SIH_KDV law; a caller with wind adds drag·wind as its external force), and quadratic per body
axis, RotorPy's parasitic drag D = −|v_a|·diag(c_dx, c_dy, c_dz)·v_a on the body airspeed
v_a = Rᵀ(v − wind) (rotorpy/vehicles/multirotor.py, `compute_body_wrench`), with R and v at the
start of the substep as for the thrust; `wind` (N, 3) world ENU gives the air's velocity (None:
still air). RotorPy's rotor aerodynamics (rotor drag, induced inflow, translational lift, blade
flapping: `core.rotor_aero`) act on the same airspeed, with the body rates at the start of the
substep and the rotor speeds at its end (after the lag's update; with a lag the thrust alone takes
the step's mean). `_air_terms` computes both from one R and one body airspeed. A vehicle
without these terms steps with the same operations as before they existed; one with them allocates
their arrays.
"""

from __future__ import annotations

import math

import numpy as np

from .frames import euler_to_rotmat_rows, world_to_body_rows
from .mixer import wrench_function, wrench_into_function
from .params import NUM_MOTORS as NUM_MOTORS  # re-exported: the rotor count the contract carries
from .params import ParamBatch
from .rotor_aero import rotor_aero_wrench

# The state's layout is named in one place, `core.state`; these are re-exported for the callers
# that read them here.
from .state import ATT as ATT
from .state import IDX as IDX
from .state import POS as POS
from .state import RATES as RATES
from .state import STATE_DIM as STATE_DIM
from .state import STATE_NAMES as STATE_NAMES
from .state import VEL as VEL
from .state import YAW, P, Q, R

# PX4's quad-X (`core.params.quad_x`): rotor positions as multiples of arm/√2 in the FLU body frame,
# and spin (+1 = CCW seen from above), in its output order. The layout of the presets and of every
# vehicle saved without a rotor list; the step itself reads the batch's layout.
MOTOR_LAYOUT = {
    # name: (x, y, spin)
    "front_right": (1.0, -1.0, +1),
    "rear_left": (-1.0, 1.0, +1),
    "front_left": (1.0, 1.0, -1),
    "rear_right": (-1.0, -1.0, -1),
}
MOTOR_NAMES = tuple(MOTOR_LAYOUT)
DT = 0.01  # s, the control step of the course brief
_TWO_PI = 2.0 * math.pi
_INV_TWO_PI = 1.0 / _TWO_PI


def _check(state: np.ndarray, rotor: np.ndarray, command: np.ndarray, params: ParamBatch) -> None:
    n, m = params.n, params.n_rotors
    if state.shape != (n, STATE_DIM):
        raise ValueError(f"state must have shape ({n}, {STATE_DIM}), got {state.shape}")
    if rotor.shape != (n, m) or command.shape != (n, m):
        raise ValueError(f"rotor and command must have shape ({n}, {m}), got {rotor.shape} and {command.shape}")


def step(
    state: np.ndarray,
    rotor: np.ndarray,
    command: np.ndarray,
    params: ParamBatch,
    dt: float = DT,
    substeps: int = 1,
    force: np.ndarray | None = None,
    torque: np.ndarray | None = None,
    armed: np.ndarray | None = None,
    wind: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Advance N drones by `dt` with the motor command held; returns new (state, rotor).

    state (N, 12), rotor (N, M), command (N, M) in [0, 1] (clipped here, and to ω_min/ω_max from
    below), all of one float dtype; params holds (N,) arrays. Inputs are not modified. Elementwise
    NumPy only (no BLAS), so drone i of a batch gets bit for bit the result of stepping it alone.

    force (N, 3), N, world ENU, and torque (N, 3), N·m, body FLU: optional external force and
    moment held over the step (wind through drag, a push; `core.randomization`), added to the
    rotors' and gravity's. None (the default) costs nothing.

    armed (N,) bool: False turns a drone's motors off (commanded speed 0, see the module docstring);
    None (the default) is every drone armed.

    wind (N, 3), m/s world ENU: the air's velocity, which the quadratic drag acts on (module
    docstring); None: still air. (The linear drag takes wind as the external force drag·wind.)

    The arithmetic is `Stepper`'s, the one implementation of the model: the inputs are copied to
    rows, advanced in place and copied out.
    """
    _check(state, rotor, command, params)
    dtype = state.dtype
    if dtype not in _FLOATS:
        raise ValueError(f"state must be float32 or float64, got {dtype}")
    # the rows (12, N), (M, N) of `Stepper`, copied: the inputs are not modified
    s = np.array(state.T, order="C")
    w = np.array(rotor.T, dtype, order="C")
    u = np.array(command.T, dtype, order="C")
    stepper = _stepper(params.n, params.n_rotors, dtype)
    stepper.step(s, w, u, params, dt, substeps, force, torque, armed=armed, wind=wind)
    return np.ascontiguousarray(s.T), np.ascontiguousarray(w.T)


_FLOATS = (np.dtype(np.float32), np.dtype(np.float64))
_STEPPERS: dict = {}
_MAX_STEPPERS = 16  # batch shapes kept per process; a caller steps one or two


def _stepper(n: int, m: int, dtype) -> Stepper:
    """A `Stepper` for `step`, made once per batch shape and dtype (its buffers are scratch: `step`
    copies in and out, so one serves every call of that shape; NumPy code here is single-threaded)."""
    key = (n, m, np.dtype(dtype).str)
    hit = _STEPPERS.get(key)
    if hit is None:
        if len(_STEPPERS) >= _MAX_STEPPERS:
            _STEPPERS.clear()
        hit = _STEPPERS[key] = Stepper(n, m, dtype)
    return hit


def _derived(params: ParamBatch, h: float, dtype) -> _Derived:
    """Derived constants, cached on the (immutable) ParamBatch per step length and dtype."""
    cache = params.__dict__.setdefault("_derived_cache", {})
    key = (h, np.dtype(dtype).str)
    if key not in cache:
        cache[key] = _Derived(params, h, dtype)
    return cache[key]


def lag_factors(motor_tau, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(decay, 2A, B), float64 per drone, of the motor lag `motor_tau` (s, per drone) over a substep
    of h s; every plant step (this module's and the simulator's `single_step`) takes them from here.

    Exact discretisation of dω/dt = (ω_cmd − ω)/τ over h: ω ← ω_cmd + decay·(ω − ω_cmd), decay =
    e^(−h/τ). τ = 0 gives a decay of exactly 0, so ω = ω_cmd bit for bit, as for a lag-free batch
    (the form ω + (1 − e^(−h/τ))·(ω_cmd − ω) rounds to one ulp away from ω_cmd). The thrust over the
    substep is the mean of ω² along that exponential, not the end's ω² (module docstring): with
    d = ω − ω_cmd at the start, ω(t) = ω_cmd + d·e^(−t/τ) and mean ω² = ω_cmd² + 2·A·ω_cmd·d + B·d²,
    A = τ/h·(1 − e^(−h/τ)), B = τ/2h·(1 − e^(−2h/τ)); τ = 0: A = B = 0, the command's ω² at once."""
    tau = np.asarray(motor_tau, dtype=np.float64)
    e = np.exp(-h / np.where(tau > 0, tau, 1.0))
    decay = np.where(tau > 0, e, 0.0)
    over = np.where(tau > 0, tau / h, 0.0)
    return decay, 2.0 * over * (1.0 - e), 0.5 * over * (1.0 - e * e)


class _Derived:
    """Per-drone constants used by every substep, cast to the state dtype once per call."""

    def __init__(self, p: ParamBatch, h: float, dtype) -> None:
        c = lambda a: np.asarray(a, dtype=dtype)  # noqa: E731
        self.f_max = c(p.k_f * p.omega_max**2)  # N per rotor at command 1
        self.inv_m = c(1.0 / p.mass)
        # τ_x = arm·Σ y_i·F_i, τ_y = −arm·Σ x_i·F_i, τ_z = −k_m·Σ spin_i·F_i (module docstring)
        self.wrench = wrench_function(p.layout, (p.arm, p.arm, p.k_m), c)
        self.inv_ixx, self.inv_iyy, self.inv_izz = c(1 / p.ixx), c(1 / p.iyy), c(1 / p.izz)
        self.izz_iyy, self.ixx_izz, self.iyy_ixx = c(p.izz - p.iyy), c(p.ixx - p.izz), c(p.iyy - p.ixx)
        self.g = np.dtype(dtype).type(p.gravity)
        # lowest commanded ω/ω_max of an armed motor: ω_min/ω_max per drone, or 0 (no idle speed)
        self.u_min = c(p.omega_min / p.omega_max)[:, None] if np.any(p.omega_min > 0) else 0.0
        self.lag = bool(np.any(p.motor_tau > 0))
        if self.lag:
            self.decay, self.lag_2a, self.lag_b = (c(a) for a in lag_factors(p.motor_tau, h))
        self.drag = bool(np.any(p.drag > 0))
        if self.drag:
            self.drag_over_m = c(p.drag / p.mass)
        self.quadratic_drag = bool(np.any(p.c_dx > 0) or np.any(p.c_dy > 0) or np.any(p.c_dz > 0))
        if self.quadratic_drag:  # per body axis, over the mass: (3, N)
            self.c_over_m = c(np.stack([p.c_dx / p.mass, p.c_dy / p.mass, p.c_dz / p.mass]))
        self.rotor_aero = bool(any(np.any(a > 0) for a in (p.k_d, p.k_z, p.k_h, p.k_flap)))
        if self.rotor_aero:
            lay = np.asarray(p.layout, dtype=np.float64)
            self.omega_max = c(p.omega_max)
            self.rotor_x = c(lay[:, 0:1] * p.arm[None, :])  # (M, N) m, body FLU
            self.rotor_y = c(lay[:, 1:2] * p.arm[None, :])
            self.aero = tuple(c(a) for a in (p.k_d, p.k_z, p.k_h, p.k_flap))
        self.air_terms = self.quadratic_drag or self.rotor_aero


def _air_terms(sin, cos, vel, rates, w, air, d: _Derived) -> tuple[np.ndarray, np.ndarray | None]:
    """(acceleration (3, N) world ENU, moment (3, N) body FLU or None) of the air on the airframe:
    RotorPy's parasitic drag and its rotor aerodynamics (module docstring), both on the body airspeed
    v_a = Rᵀ(v − wind), from the sines and cosines of the attitude (rows, as `frames.
    euler_to_rotmat_rows` takes them), the velocity and body rates at the start of a substep, the
    normalised rotor speeds w (M, N) at its end, and the air's velocity (None: still air). Allocating: only a vehicle
    with these terms pays for them."""
    n = vel.shape[-1]
    rot = euler_to_rotmat_rows(sin, cos, np.empty((3, 3, n), vel.dtype), np.empty(n, vel.dtype))
    body_air = world_to_body_rows(rot, vel if air is None else vel - air, np.empty((3, n), vel.dtype))
    acc = np.zeros_like(body_air)  # body FLU, over the mass
    moment = None
    if d.quadratic_drag:  # −|v_a|·diag(c)·v_a / m
        speed = np.sqrt(body_air[0] * body_air[0] + body_air[1] * body_air[1] + body_air[2] * body_air[2])
        acc -= d.c_over_m * body_air * speed
    if d.rotor_aero:
        force, moment = rotor_aero_wrench(body_air, rates, w * d.omega_max, d.rotor_x, d.rotor_y, *d.aero)
        acc += force * d.inv_m
    return np.einsum("ijn,jn->in", rot, acc), moment


class Stepper:
    """`step` in place, for a batch stepped every control period: the state and rotor rows are
    advanced where they lie and every intermediate lives in rows allocated here once, so a step
    allocates no array (`train.envs.QuadBatch` steps this way); a vehicle with RotorPy's drag or rotor
    aerodynamics allocates those terms' arrays (`_air_terms`). The state, rotor and command rows must
    not share memory.

    The arithmetic is `_substep`'s, operation for operation and in the same order, each NumPy ufunc
    writing into a buffer instead of a new array: a ufunc computes the same bits wherever it writes,
    sin, cos and floor give each element the same bits at any position and stride, and a Python
    float meets an array as that array's dtype (NEP 50), so the constants are cast once. Drone i
    gets bit for bit what `step` gives it (tests/core/test_inplace_equivalence.py checks this
    against `step` over rotor layouts, lags, drag, idle speeds, external forces, substeps and both
    dtypes).

    Speed: a NumPy call costs about a microsecond at N = 4096 whatever it computes, so the calls are
    few: a quantity computed once per axis is one call over a (3, N) block where `_substep` makes
    three, and per-drone constants that meet a block are stored at the block's shape (a broadcast
    (N,) operand costs a call per row). The sines, cosines and thrust direction of the state at the
    start of a step may be handed in (`trig`) by a caller that has them: `ObservationBuilder`
    computes the same numbers from the same state."""

    def __init__(self, n: int, n_rotors: int, dtype) -> None:
        self.n, self.m, self.dtype = int(n), int(n_rotors), np.dtype(dtype)
        rows = lambda k: np.empty((k, self.n), self.dtype)  # noqa: E731
        self.f = rows(self.m)  # rotor thrusts F_i, N
        self.fu = rows(self.m)  # scratch for the lagged rotors' mean ω²
        self.wrench = rows(4)  # thrust, τx, τy, τz
        self.gyro = rows(3)  # the gyroscopic terms, then the rate increments
        self.rates1 = rows(3)  # p, q, r at the end of the substep
        self.mid = rows(3)  # p, q, r at mid-step
        self.sin, self.cos = rows(3), rows(3)  # of roll, pitch, yaw at the start of the substep
        self.zaxis = rows(3)  # R·e3: the thrust direction, world ENU
        self.inc = rows(3)  # roll, pitch, yaw increments
        self.acc = rows(3)  # m/s², world ENU
        self.block = rows(3)  # scratch for a (3, N) product
        self.acc_ext, self.mom_ext = rows(3), rows(3)  # external force / m and moment, in the state dtype
        self.t = rows(3)
        # the rows as views made once (making a view costs a fraction of a microsecond)
        self._f_rows, self._wr_rows, self._acc_rows = tuple(self.f), tuple(self.wrench), tuple(self.acc)
        self._rows = (*self.sin, *self.cos, *self.mid, *self.gyro, *self.t, *self.inc, *self.zaxis)
        self._state_views: tuple = (None, None)
        self._constants: tuple = (None, None, None, None)  # (params, h, _Derived, _StepperConstants) of the last step

    def _views(self, s: np.ndarray) -> tuple:
        """The views of the state rows the substep reads, made once per state array."""
        if self._state_views[0] is not s:
            self._state_views = (s, (s[POS], s[VEL], s[ATT], s[RATES], s[YAW], s[P], s[Q], s[R]))
        return self._state_views[1]

    def step(
        self,
        s: np.ndarray,
        w: np.ndarray,
        u: np.ndarray,
        params: ParamBatch,
        dt: float = DT,
        substeps: int = 1,
        force: np.ndarray | None = None,
        torque: np.ndarray | None = None,
        trig: tuple | None = None,
        armed: np.ndarray | None = None,
        wind: np.ndarray | None = None,
    ) -> None:
        """Advance N drones by `dt` in place: s (12, N) state rows (`core.state` order), w (M, N)
        rotor rows; u (M, N) commanded speeds, clipped to [ω_min/ω_max, 1] as `step` clips them, in
        place with a motor lag, else into w (no lag: w = u from the first substep on); force and
        torque (N, 3) as `step` takes them (None: none). s, w and u in the dtype this Stepper was
        made for. trig: None, or (sin, cos, zaxis) of the state s holds now, each (3, N) or its
        three rows: sin and cos of roll, pitch, yaw, and (R02, R12, R22) as
        `frames.euler_to_rotmat_rows` computes them (the same operations as `_substep`'s
        acceleration terms), used for the first substep instead of computing them again.
        armed: None (every drone armed), or (N,) bool: False turns a drone's motors off, its
        command 0 after the clip (`step`'s `armed`). wind: None, or (N, 3) m/s world ENU, `step`'s."""
        n, m = self.n, self.m
        if s.shape != (STATE_DIM, n) or w.shape != (m, n) or u.shape != (m, n):
            raise ValueError(
                f"state, rotor and command rows must have shapes ({STATE_DIM}, {n}), ({m}, {n}) and ({m}, {n}), "
                f"got {s.shape}, {w.shape} and {u.shape}"
            )
        h = dt / substeps
        last_params, last_h, d, k = self._constants
        if params is not last_params or h != last_h:  # a new batch of parameters (or step length)
            if params.n != n or params.n_rotors != m:  # (checked once: a ParamBatch does not change)
                raise ValueError(f"params hold {params.n} drones of {params.n_rotors} rotors, expected {n} of {m}")
            d = _derived(params, h, self.dtype)
            k = d.__dict__.get("stepper")
            if k is None:  # what the in-place substep adds to the derived constants, once per batch and h
                k = d.stepper = _StepperConstants(d, h, self.dtype, m)
            self._constants = (params, h, d, k)
        acc = mom = None
        if force is not None:  # `_external`: force/m, computed in the pair's type, cast to the state dtype
            force = np.asarray(force)
            if force.shape != (n, 3):
                raise ValueError(f"force must have shape ({n}, 3) (N, world ENU), got {force.shape}")
            acc = self.acc_ext
            for i in range(3):
                np.divide(force[:, i], params.mass, acc[i], casting="unsafe")
        if torque is not None:
            torque = np.asarray(torque)
            if torque.shape != (n, 3):
                raise ValueError(f"torque must have shape ({n}, 3) (N·m, body FLU), got {torque.shape}")
            mom = self.mom_ext
            np.copyto(mom, torque.T, casting="unsafe")
        air = None
        if wind is not None and d.air_terms:  # the terms that read the air's velocity
            wind = np.asarray(wind)
            if wind.shape != (n, 3):
                raise ValueError(f"wind must have shape ({n}, 3) (m/s, world ENU), got {wind.shape}")
            air = np.ascontiguousarray(wind.T, dtype=self.dtype)
        clipped = u if d.lag else w  # without a lag the rotor speed is the clipped command (w = u)
        _clip(u, k.u_min, 1.0, clipped)
        if armed is not None:  # motors off command 0, below any idle speed (module docstring)
            armed = np.asarray(armed)
            if armed.shape != (n,):
                raise ValueError(f"armed must have shape ({n},), got {armed.shape}")
            np.copyto(clipped, 0.0, where=~armed.astype(bool))
        for i in range(substeps):
            self._substep(s, w, u, d, k, acc, mom, trig if i == 0 else None, air)

    def _substep(self, s, w, u, d: _Derived, k: _StepperConstants, acc, mom, trig, air=None) -> None:
        """`_substep` in place; each comment gives the line of `_substep` the calls below it compute."""
        mul, add, sub = np.multiply, np.add, np.subtract
        pos, vel, att, rates, psi, p, q, r = self._views(s)
        sphi, sth, spsi, cphi, cth, cpsi, pm, qm, rm, g0, g1, g2, t1, t2, t3, i0, i1, i2, z0, z1, z2 = self._rows
        f = self.f
        if d.lag:  # di = wi − ui; f = f_max·ui·ui + f_max·((B·di + 2A·ui)·di); w = ui + decay·di
            sub(w, u, w)  # (a lag-free drone, A = B = 0, gets f_max·ui·ui bit for bit, as alone)
            fu = self.fu
            mul(k.lag_b, w, f)
            mul(k.lag_2a, u, fu)
            add(f, fu, f)
            mul(f, w, f)
            mul(k.f_max, f, f)
            mul(k.f_max, u, fu)
            mul(fu, u, fu)
            add(fu, f, f)
            mul(k.decay, w, w)
            add(u, w, w)
        else:  # f = f_max·wi·wi; w = u, clipped into w by `step`
            mul(k.f_max, w, f)
            mul(f, w, f)
        k.wrench_into(self._f_rows, self._wr_rows, t1)  # thrust, tx, ty, tz = wrench(f)
        torque = self.wrench[1:4]
        if mom is not None:  # tx, ty, tz = tx + m_x, ...
            add(torque, mom, torque)
        air_acc = None
        if d.air_terms:  # the air on the airframe at the start of the substep: a moment now, a force below
            if trig is None:  # the sines and cosines of the attitude (not advanced yet), for both
                np.sin(att, self.sin)
                np.cos(att, self.cos)
                trig = (self.sin, self.cos, None)
            air_acc, air_moment = _air_terms(trig[0], trig[1], vel, rates, w, air, d)
            if air_moment is not None:
                add(torque, air_moment, torque)

        # p1 = p + h·(tx − izz_iyy·q·r)·inv_ixx; q1 = q + h·(ty − ixx_izz·p·r)·inv_iyy; r1 alike
        gyro = self.gyro
        mul(k.izz_iyy, q, g0)
        mul(g0, r, g0)
        mul(k.ixx_izz, p, g1)
        mul(g1, r, g1)
        mul(k.iyy_ixx, p, g2)
        mul(g2, q, g2)
        sub(torque, gyro, gyro)
        mul(k.h, gyro, gyro)
        mul(gyro, k.inv_inertia, gyro)
        rates1 = self.rates1
        add(rates, gyro, rates1)
        mid = self.mid  # pm, qm, rm = 0.5·(p + p1), ...
        add(rates, rates1, mid)
        mul(k.half, mid, mid)

        if trig is None:  # sin and cos of φ, θ, ψ (sphi … cpsi are the rows of self.sin and self.cos)
            np.sin(att, self.sin)
            np.cos(att, self.cos)
            za = None
        else:
            (sphi, sth, spsi), (cphi, cth, cpsi), za = trig

        qs = t3
        mul(qm, sphi, qs)  # qs_rc = qm·sphi + rm·cphi
        mul(rm, cphi, t1)
        add(qs, t1, qs)
        # phi1, th1, psi1 = phi + h·(pm + qs_rc·sth/cth), th + h·(qm·cphi − rm·sphi), psi + h·(qs_rc/cth)
        inc = self.inc
        mul(qs, sth, t1)
        np.divide(t1, cth, t1)
        add(pm, t1, i0)
        mul(qm, cphi, t1)
        mul(rm, sphi, t2)
        sub(t1, t2, i1)
        np.divide(qs, cth, i2)
        mul(k.h, inc, inc)
        add(att, inc, att)
        add(psi, k.pi, t1)  # psi1 = psi1 − 2π·floor((psi1 + π)/(2π))
        mul(t1, k.inv_two_pi, t1)
        np.floor(t1, t1)
        mul(k.two_pi, t1, t1)
        sub(psi, t1, psi)

        # ax, ay, az = t_m·(cpsi·sth·cphi + spsi·sphi), t_m·(spsi·sth·cphi − cpsi·sphi), t_m·(cth·cphi) − g
        if za is None:
            za = (z0, z1, z2)
            mul(cpsi, sth, t1)
            mul(t1, cphi, t1)
            mul(spsi, sphi, t2)
            add(t1, t2, z0)
            mul(spsi, sth, t1)
            mul(t1, cphi, t1)
            mul(cpsi, sphi, t2)
            sub(t1, t2, z1)
            mul(cth, cphi, z2)
        x = self.acc
        mul(self._wr_rows[0], d.inv_m, t1)  # t_m = thrust·inv_m
        for xi, zi in zip(self._acc_rows, za, strict=True):  # by row: a broadcast (N,) operand allocates
            mul(t1, zi, xi)
        sub(x[2], d.g, x[2])
        blk = self.block
        if d.drag:  # ax = ax − drag_over_m·vx, ...
            mul(k.drag_over_m, vel, blk)
            sub(x, blk, x)
        if air_acc is not None:  # ax = ax + the air's force / m, ...
            add(x, air_acc, x)
        if acc is not None:  # ax = ax + force_x/m, ...
            add(x, acc, x)
        mul(k.h, vel, blk)  # x1 = x + h·vx + hh·ax, ...
        add(pos, blk, pos)
        mul(k.hh, x, blk)
        add(pos, blk, pos)
        mul(k.h, x, blk)  # vx1 = vx + h·ax, ...
        add(vel, blk, vel)
        np.copyto(rates, rates1)


class _StepperConstants:
    """What `Stepper` needs beyond `_Derived`: per-drone constants at the shape of the blocks they
    multiply (the same numbers, repeated), the inertia terms, the Python-float constants of
    `_substep` in the state dtype (what NumPy casts them to there), and the layout's mixer in place."""

    def __init__(self, d: _Derived, h: float, dtype, m: int) -> None:
        t = np.dtype(dtype).type
        n = d.inv_m.shape[0]
        rows = lambda a, k: np.ascontiguousarray(np.broadcast_to(a, (k, n)))  # noqa: E731
        self.f_max = rows(d.f_max, m)
        self.u_min = d.u_min if np.isscalar(d.u_min) else rows(d.u_min[:, 0], m)
        self.decay = rows(d.decay, m) if d.lag else None
        self.lag_2a = rows(d.lag_2a, m) if d.lag else None
        self.lag_b = rows(d.lag_b, m) if d.lag else None
        self.drag_over_m = rows(d.drag_over_m, 3) if d.drag else None
        self.izz_iyy, self.ixx_izz, self.iyy_ixx = d.izz_iyy, d.ixx_izz, d.iyy_ixx
        self.inv_inertia = np.stack([d.inv_ixx, d.inv_iyy, d.inv_izz])
        self.h, self.half, self.hh = t(h), t(0.5), t(0.5 * h * h)
        self.pi, self.two_pi, self.inv_two_pi = t(np.pi), t(_TWO_PI), t(_INV_TWO_PI)
        self.wrench_into = wrench_into_function(d.wrench.rows, m)


try:  # the ufunc np.clip calls, without np.clip's dispatch (a microsecond a call); the same values
    from numpy._core.umath import clip as _clip
except ImportError:  # pragma: no cover - a NumPy that moved it
    _clip = np.clip


def hover_command(params) -> np.ndarray | float:
    """Normalised rotor command ω/ω_max that holds hover with the weight shared equally by the
    rotors, for a preset or a ParamBatch (the trim of any balanced layout; `VehicleParams.hover_commands`
    gives the per-rotor trim of any layout)."""
    return np.sqrt(params.mass * params.gravity / float(params.n_rotors) / params.k_f) / params.omega_max


def action_to_command(action: np.ndarray, u_hover) -> np.ndarray:
    """Map policy actions in [−1, 1] (clipped) to rotor commands in [0, 1].

    The action is thrust relative to hover trim, linear in thrust: a = −1 is zero thrust, 0 hover,
    +1 twice hover thrust. Thrust ∝ ω², so the command is u_hover·√(1 + a). `u_hover` is the
    nominal vehicle's hover command (what the controller believes), scalar or (N, 1).
    """
    a = np.clip(action, -1.0, 1.0)
    return np.clip(u_hover * np.sqrt(1.0 + a), 0.0, 1.0)
