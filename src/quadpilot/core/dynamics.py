"""Batched 12-state quadrotor dynamics (NumPy only).

State, shape (N, 12), world frame ENU (z up), body frame FLU (x forward, y left, z up):

    x, y, z          position, m
    vx, vy, vz       velocity in the world frame, m/s
    roll, pitch, yaw ZYX Euler angles, rad (R = Rz(yaw)·Ry(pitch)·Rx(roll), body → world;
                     with FLU, positive pitch is nose down and accelerates the vehicle along +x)
    p, q, r          body rates, rad/s

Rotor state, shape (N, 4): normalised rotor speed ω/ω_max, only dynamic when a motor time
constant is set. Command, shape (N, 4): normalised rotor speed ω/ω_max in [0, 1], the
convention of PX4's HIL_ACTUATOR_CONTROLS (thrust ∝ command²).

Motors are numbered in PX4's quad-X order (PX4 `ROMFS/.../airframes` "Quadrotor x" geometry):
0 front-right CCW, 1 rear-left CCW, 2 front-left CW, 3 rear-right CW. Read in FRD this is exactly
the roll and pitch arrangement of seed 001's torque equation, τ_x ∝ (−F1+F2+F3−F4),
τ_y ∝ (F1−F2+F3−F4). Seed 001's yaw row (−F1+F2−F3+F4) pairs adjacent rotors, which no X frame
does; the yaw row here follows from the physics: a rotor spinning counter-clockwise seen from above
(angular momentum +z) is driven by a +z motor torque, so its reaction on the body is −z.

Integration per (sub)step of length h: rotor lag exactly discretised; body rates by Euler's
rotational equation with the gyroscopic term ω × (Iω), forward in time; Euler angles advanced with
the mid-step rates (exact for a constant torque about one axis); position with the constant-
acceleration formula p + h·v + h²/2·a (exact in free fall). Euler angles are singular at
pitch ±90°; the environments terminate at 60°.
"""

from __future__ import annotations

import math

import numpy as np

from .params import ParamBatch

STATE_DIM = 12
STATE_NAMES = ("x", "y", "z", "vx", "vy", "vz", "roll", "pitch", "yaw", "p", "q", "r")
POS = slice(0, 3)
VEL = slice(3, 6)
ATT = slice(6, 9)
RATES = slice(9, 12)
IDX = {name: i for i, name in enumerate(STATE_NAMES)}

NUM_MOTORS = 4
# Rotor positions as multiples of arm/√2 in the FLU body frame, and spin (+1 = CCW seen from
# above). The torque rows in `_substep` are these columns written out: τ_x = Σ y_i·F_i,
# τ_y = −Σ x_i·F_i, τ_z = −Σ spin_i·k_m·F_i.
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
    n = params.n
    if state.shape != (n, STATE_DIM):
        raise ValueError(f"state must have shape ({n}, {STATE_DIM}), got {state.shape}")
    if rotor.shape != (n, NUM_MOTORS) or command.shape != (n, NUM_MOTORS):
        raise ValueError(
            f"rotor and command must have shape ({n}, {NUM_MOTORS}), got {rotor.shape} and {command.shape}"
        )


def step(
    state: np.ndarray,
    rotor: np.ndarray,
    command: np.ndarray,
    params: ParamBatch,
    dt: float = DT,
    substeps: int = 1,
    force: np.ndarray | None = None,
    torque: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Advance N drones by `dt` with the motor command held; returns new (state, rotor).

    state (N, 12), rotor (N, 4), command (N, 4) in [0, 1] (clipped here), all of one float dtype;
    params holds (N,) arrays. Inputs are not modified. Elementwise NumPy only (no BLAS), so drone i
    of a batch gets bit for bit the result of stepping it alone.

    force (N, 3), N, world ENU, and torque (N, 3), N·m, body FLU: optional external force and
    moment held over the step (wind through drag, a push; `core.randomization`), added to the
    rotors' and gravity's. None (the default) costs nothing.
    """
    _check(state, rotor, command, params)
    ext = None if force is None and torque is None else _external(force, torque, params, state.dtype)
    h = dt / substeps
    # Work on rows (12, N): contiguous per quantity, which is what elementwise NumPy is fast on.
    s = list(np.ascontiguousarray(state.T))
    w = list(np.ascontiguousarray(rotor.T))
    u = list(np.ascontiguousarray(np.clip(command, 0.0, 1.0).T))
    d = _derived(params, h, state.dtype)
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
        self.a = c(p.arm / math.sqrt(2.0))  # moment arm of each rotor about x and y, X frame
        self.k_m = c(p.k_m)
        self.inv_ixx, self.inv_iyy, self.inv_izz = c(1 / p.ixx), c(1 / p.iyy), c(1 / p.izz)
        self.izz_iyy, self.ixx_izz, self.iyy_ixx = c(p.izz - p.iyy), c(p.ixx - p.izz), c(p.iyy - p.ixx)
        self.g = np.dtype(dtype).type(p.gravity)
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


def _substep(s, w, u, d: _Derived, h: float, ext: tuple | None = None):
    x, y, z, vx, vy, vz, phi, th, psi, p, q, r = s
    if d.lag:
        w = [ui + d.decay * (wi - ui) for wi, ui in zip(w, u, strict=True)]
    else:
        w = list(u)
    f0, f1, f2, f3 = (d.f_max * wi * wi for wi in w)  # F = k_f·ω², N
    thrust = f0 + f1 + f2 + f3
    tx = d.a * (-f0 + f1 + f2 - f3)  # thrust on the left rotors (1, 2) lifts the left side: +x
    ty = d.a * (-f0 + f1 - f2 + f3)  # rear rotors (1, 3) pitch the nose down (+y in FLU)
    tz = d.k_m * (-f0 - f1 + f2 + f3)  # CCW rotors (0, 1) push the body clockwise (−z)
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
    """Normalised rotor command ω/ω_max that holds hover, for a preset or a ParamBatch."""
    return np.sqrt(params.mass * params.gravity / 4.0 / params.k_f) / params.omega_max


def action_to_command(action: np.ndarray, u_hover) -> np.ndarray:
    """Map policy actions in [−1, 1] (clipped) to rotor commands in [0, 1].

    The action is thrust relative to hover trim, linear in thrust: a = −1 is zero thrust, 0 hover,
    +1 twice hover thrust. Thrust ∝ ω², so the command is u_hover·√(1 + a). `u_hover` is the
    nominal vehicle's hover command (what the controller believes), scalar or (N, 1).
    """
    a = np.clip(action, -1.0, 1.0)
    return np.clip(u_hover * np.sqrt(1.0 + a), 0.0, 1.0)
