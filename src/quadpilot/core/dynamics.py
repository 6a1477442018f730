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
PX4's quad-X (`MOTOR_LAYOUT`, the layout of every vehicle saved without a rotor list) this is seed
001's roll and pitch arrangement, τ_x ∝ (−F1+F2+F3−F4), τ_y ∝ (F1−F2+F3−F4); seed 001's yaw row
(−F1+F2−F3+F4) pairs adjacent rotors, which no X frame does, so the yaw row follows the physics.

Rotor speed: the commanded speed command·ω_max is clipped to [ω_min, ω_max] (RotorPy 3.0.0 does the
same, rotorpy/vehicles/multirotor.py, `Multirotor.step`), so an armed motor idles at ω_min. Motors
off (`armed` false: disarmed, or a simulator's motors-off state) command ω = 0 whatever ω_min: the
rotors spin down through the motor lag and stop. The rotor state itself is not clipped: a rotor
starting at rest spins up to ω_min through the lag (RotorPy also clips its state, which makes a
rotor at rest jump to ω_min in one step).

Integration per (sub)step of length h: rotor lag exactly discretised; body rates by Euler's
rotational equation with the gyroscopic term ω × (Iω), forward in time; Euler angles advanced with
the mid-step rates (exact for a constant torque about one axis); position with the constant-
acceleration formula p + h·v + h²/2·a (exact in free fall). Euler angles are singular at
pitch ±90°; the environments terminate at 60°.
"""

from __future__ import annotations

import math

import numpy as np

from .params import NUM_MOTORS as NUM_MOTORS  # re-exported: the rotor count the contract carries
from .params import ParamBatch

# The state's layout is named in one place, `core.state`; these are re-exported for the callers
# that read them here.
from .state import ATT as ATT
from .state import IDX as IDX
from .state import POS as POS
from .state import RATES as RATES
from .state import STATE_DIM as STATE_DIM
from .state import STATE_NAMES as STATE_NAMES
from .state import VEL as VEL

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
DT = 0.01  # s, the control step of seed 000
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
    """
    _check(state, rotor, command, params)
    ext = None if force is None and torque is None else _external(force, torque, params, state.dtype)
    h = dt / substeps
    d = _derived(params, h, state.dtype)
    cmd = np.clip(command, d.u_min, 1.0)
    if armed is not None:
        armed = np.asarray(armed)
        if armed.shape != (params.n,):
            raise ValueError(f"armed must have shape ({params.n},), got {armed.shape}")
        cmd = np.where(armed[:, None], cmd, 0.0).astype(cmd.dtype, copy=False)
    # Work on rows (12, N): contiguous per quantity, which is what elementwise NumPy is fast on.
    s = list(np.ascontiguousarray(state.T))
    w = list(np.ascontiguousarray(rotor.T))
    u = list(np.ascontiguousarray(cmd.T))
    for _ in range(substeps):
        s, w = _substep(s, w, u, d, h, ext)
    return np.stack(s, axis=1), np.stack(w, axis=1)


def _external(force, torque, params: ParamBatch, dtype) -> tuple:
    """Rows of the external acceleration (force/m, m/s²) and moment (N·m), in the state dtype;
    None for a part not given."""
    n = params.n
    acc = mom = None
    if force is not None:
        force = np.asarray(force)
        if force.shape != (n, 3):
            raise ValueError(f"force must have shape ({n}, 3) (N, world ENU), got {force.shape}")
        acc = tuple(np.ascontiguousarray((force / params.mass[:, None]).T, dtype=dtype))
    if torque is not None:
        torque = np.asarray(torque)
        if torque.shape != (n, 3):
            raise ValueError(f"torque must have shape ({n}, 3) (N·m, body FLU), got {torque.shape}")
        mom = tuple(np.ascontiguousarray(torque.T, dtype=dtype))
    return acc, mom


def _derived(params: ParamBatch, h: float, dtype) -> _Derived:
    """Derived constants, cached on the (immutable) ParamBatch per step length and dtype."""
    cache = params.__dict__.setdefault("_derived_cache", {})
    key = (h, np.dtype(dtype).str)
    if key not in cache:
        cache[key] = _Derived(params, h, dtype)
    return cache[key]


class _Derived:
    """Per-drone constants used by every substep, cast to the state dtype once per call."""

    def __init__(self, p: ParamBatch, h: float, dtype) -> None:
        c = lambda a: np.asarray(a, dtype=dtype)  # noqa: E731
        self.f_max = c(p.k_f * p.omega_max**2)  # N per rotor at command 1
        self.inv_m = c(1.0 / p.mass)
        # τ_x = arm·Σ y_i·F_i, τ_y = −arm·Σ x_i·F_i, τ_z = −k_m·Σ spin_i·F_i (module docstring)
        self.wrench = _wrench_function(p.layout, (p.arm, p.arm, p.k_m), c)
        self.inv_ixx, self.inv_iyy, self.inv_izz = c(1 / p.ixx), c(1 / p.iyy), c(1 / p.izz)
        self.izz_iyy, self.ixx_izz, self.iyy_ixx = c(p.izz - p.iyy), c(p.ixx - p.izz), c(p.iyy - p.ixx)
        self.g = np.dtype(dtype).type(p.gravity)
        # lowest commanded ω/ω_max of an armed motor: ω_min/ω_max per drone, or 0 (no idle speed)
        self.u_min = c(p.omega_min / p.omega_max)[:, None] if np.any(p.omega_min > 0) else 0.0
        self.lag = bool(np.any(p.motor_tau > 0))
        if self.lag:
            tau = np.asarray(p.motor_tau, dtype=np.float64)
            # exact discretisation of dω/dt = (ω_cmd − ω)/τ over h: ω ← ω_cmd + e^(−h/τ)·(ω − ω_cmd).
            # τ = 0 gives a decay of exactly 0, so ω = ω_cmd bit for bit, as for a lag-free batch
            # (the form ω + (1 − e^(−h/τ))·(ω_cmd − ω) rounds to one ulp away from ω_cmd).
            self.decay = c(np.where(tau > 0, np.exp(-h / np.where(tau > 0, tau, 1.0)), 0.0))
        self.drag = bool(np.any(p.drag > 0))
        if self.drag:
            self.drag_over_m = c(p.drag / p.mass)


def _wrench_function(layout: tuple, scales: tuple, cast):
    """f ↦ (thrust, τx, τy, τz) for a batch's layout (`ParamBatch.layout`: x/arm, y/arm, spin in
    FLU per rotor), with τx = arm·Σ y_i·F_i, τy = −arm·Σ x_i·F_i, τz = −k_m·Σ spin_i·F_i (module
    docstring); `scales` the per-drone (arm, arm, k_m)."""
    make, factors, coefs = _wrench_maker(layout)
    consts = [cast(scale / (1.0 / g)) for scale, g in zip(scales, factors, strict=True) if g]
    fn = make(*consts, *(cast(k)[()] for k in coefs))
    fn.source = make.source
    return fn


_WRENCH_MAKERS: dict = {}
_MAX_WRENCH_MAKERS = 64  # layouts compiled per process; a batch has one, a run a handful


def _wrench_maker(layout: tuple):
    """(make, row factors g, other coefficients) for a layout, compiled once per layout.

    The mixer is written out as one expression per row and compiled, so that stepping costs what a
    hand-written mixer costs: each row's largest |coefficient| g goes into a per-drone factor, so
    the rows of a symmetric frame (every |coefficient| equal or 0: quad-X, "+") are sums and
    differences of the rotor thrusts times one factor, exactly the quad-X rows seed 001 writes out;
    any other coefficient is one more multiplication. `make(a0, a1, a2, k...)` binds the per-drone
    factors (arm·g, k_m·g) and coefficients of a batch without compiling again (domain randomisation
    makes a new batch at every reset). The source holds only rotor indices, signs and names made
    here, never text from a vehicle file."""
    hit = _WRENCH_MAKERS.get(layout)
    if hit is not None:
        return hit
    lay = np.asarray(layout, dtype=np.float64)
    factors, coefs, params, rows = [], [], [], []
    for r, coef in enumerate((lay[:, 1], -lay[:, 0], -lay[:, 2])):
        g = float(np.abs(coef).max())
        factors.append(g)
        if g == 0.0:
            rows.append("0.0")  # no rotor makes this torque (VehicleParams refuses such layouts)
            continue
        params.append(f"a{r}")
        expr = ""
        for i, ci in enumerate(coef):
            k = float(ci / g)
            if k == 0.0:
                continue
            if k in (1.0, -1.0):
                term = f"f[{i}]"
            else:
                coefs.append(abs(k))
                term = f"k{len(coefs) - 1} * f[{i}]"
            expr += (" - " if k < 0 else " + ") + term if expr else ("-" if k < 0 else "") + term
        rows.append(f"a{r} * ({expr})")
    params += [f"k{j}" for j in range(len(coefs))]
    thrust = " + ".join(f"f[{i}]" for i in range(len(lay)))
    src = (
        f"def make({', '.join(params)}):\n"
        f"    def wrench(f):\n        return {thrust}, {rows[0]}, {rows[1]}, {rows[2]}\n"
        "    return wrench\n"
    )
    namespace: dict = {}
    exec(compile(src, "<core.dynamics wrench>", "exec"), namespace)  # the source is built above, from numbers
    make = namespace["make"]
    make.source = src  # what was compiled, for a reader (and the tests)
    if len(_WRENCH_MAKERS) >= _MAX_WRENCH_MAKERS:
        _WRENCH_MAKERS.clear()
    _WRENCH_MAKERS[layout] = hit = (make, tuple(factors), tuple(coefs))
    return hit


def _substep(s, w, u, d: _Derived, h: float, ext: tuple | None = None):
    x, y, z, vx, vy, vz, phi, th, psi, p, q, r = s
    if d.lag:
        w = [ui + d.decay * (wi - ui) for wi, ui in zip(w, u, strict=True)]
    else:
        w = list(u)
    f = [d.f_max * wi * wi for wi in w]  # F = k_f·ω², N
    thrust, tx, ty, tz = d.wrench(f)  # N, and N·m in body FLU (module docstring)
    if ext is not None and ext[1] is not None:  # external moment, body FLU
        tx, ty, tz = tx + ext[1][0], ty + ext[1][1], tz + ext[1][2]

    # Euler's rotational equation I·ω̇ = τ − ω × (I·ω), diagonal I.
    p1 = p + h * (tx - d.izz_iyy * q * r) * d.inv_ixx
    q1 = q + h * (ty - d.ixx_izz * p * r) * d.inv_iyy
    r1 = r + h * (tz - d.iyy_ixx * p * q) * d.inv_izz
    pm, qm, rm = 0.5 * (p + p1), 0.5 * (q + q1), 0.5 * (r + r1)

    sphi, cphi = np.sin(phi), np.cos(phi)
    sth, cth = np.sin(th), np.cos(th)
    spsi, cpsi = np.sin(psi), np.cos(psi)

    # ZYX Euler kinematics: [φ̇, θ̇, ψ̇] = W(φ, θ)·[p, q, r]
    qs_rc = qm * sphi + rm * cphi
    phi1 = phi + h * (pm + qs_rc * sth / cth)
    th1 = th + h * (qm * cphi - rm * sphi)
    psi1 = psi + h * (qs_rc / cth)
    psi1 = psi1 - _TWO_PI * np.floor((psi1 + np.pi) * _INV_TWO_PI)  # keep yaw in [−π, π)

    # Thrust along the body z axis, R·e3 = third column of Rz·Ry·Rx.
    t_m = thrust * d.inv_m
    ax = t_m * (cpsi * sth * cphi + spsi * sphi)
    ay = t_m * (spsi * sth * cphi - cpsi * sphi)
    az = t_m * (cth * cphi) - d.g
    if d.drag:
        ax = ax - d.drag_over_m * vx
        ay = ay - d.drag_over_m * vy
        az = az - d.drag_over_m * vz
    if ext is not None and ext[0] is not None:  # external force / m, world ENU
        ax, ay, az = ax + ext[0][0], ay + ext[0][1], az + ext[0][2]
    hh = 0.5 * h * h
    x1, y1, z1 = x + h * vx + hh * ax, y + h * vy + hh * ay, z + h * vz + hh * az
    vx1, vy1, vz1 = vx + h * ax, vy + h * ay, vz + h * az
    return [x1, y1, z1, vx1, vy1, vz1, phi1, th1, psi1, p1, q1, r1], w


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
