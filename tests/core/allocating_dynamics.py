"""The plant step in its allocating form: the reference `core.dynamics.Stepper` is checked against.

`core.dynamics.step` used to be this code: one NumPy expression per line of the model, each making
a new array, on the state's rows. The in-place `Stepper` (which `core.dynamics.step` now calls, and
with it training, evaluation, the studies and the simulator's fallback) writes the same operations
in the same order into buffers. Kept here, in the form a reader checks against the module docstring
of `core.dynamics`, so that tests/core/test_inplace_equivalence.py compares the two bit for bit on
whatever machine it runs on; tests/oracle checks the physics itself against an independent model.
"""

from __future__ import annotations

import numpy as np

from quadpilot.core import dynamics

_TWO_PI = dynamics._TWO_PI
_INV_TWO_PI = dynamics._INV_TWO_PI


def allocating_step(
    state: np.ndarray,
    rotor: np.ndarray,
    command: np.ndarray,
    params,
    dt: float = dynamics.DT,
    substeps: int = 1,
    force: np.ndarray | None = None,
    torque: np.ndarray | None = None,
    armed: np.ndarray | None = None,
    wind: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """`core.dynamics.step`'s arguments and results, each operation allocating its result."""
    ext = None if force is None and torque is None else _external(force, torque, params, state.dtype)
    h = dt / substeps
    d = dynamics._derived(params, h, state.dtype)
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
    air = None if wind is None else np.ascontiguousarray(np.asarray(wind).T, dtype=state.dtype)
    for _ in range(substeps):
        s, w = _substep(s, w, u, d, h, ext, air)
    return np.stack(s, axis=1), np.stack(w, axis=1)


def _external(force, torque, params, dtype) -> tuple:
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


def _substep(s, w, u, d, h: float, ext: tuple | None = None, air: list | None = None):
    x, y, z, vx, vy, vz, phi, th, psi, p, q, r = s
    if d.lag:  # F = k_f·(mean ω² over the substep), N; ω at its end
        gap = [wi - ui for wi, ui in zip(w, u, strict=True)]
        f = [d.f_max * ui * ui + d.f_max * ((d.lag_b * di + d.lag_2a * ui) * di) for di, ui in zip(gap, u, strict=True)]
        w = [ui + d.decay * di for di, ui in zip(gap, u, strict=True)]
    else:
        w = list(u)
        f = [d.f_max * wi * wi for wi in w]  # F = k_f·ω², N
    thrust, tx, ty, tz = d.wrench(f)  # N, and N·m in body FLU (module docstring)
    if ext is not None and ext[1] is not None:  # external moment, body FLU
        tx, ty, tz = tx + ext[1][0], ty + ext[1][1], tz + ext[1][2]
    air_acc = None
    if d.air_terms:  # core.dynamics._air_terms: RotorPy's drag and rotor aerodynamics, from this state
        trig = (np.sin(phi), np.sin(th), np.sin(psi)), (np.cos(phi), np.cos(th), np.cos(psi))
        air_acc, moment = dynamics._air_terms(*trig, np.stack([vx, vy, vz]), np.stack([p, q, r]), np.stack(w), air, d)
        if moment is not None:
            tx, ty, tz = tx + moment[0], ty + moment[1], tz + moment[2]

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
    if air_acc is not None:
        ax, ay, az = ax + air_acc[0], ay + air_acc[1], az + air_acc[2]
    if ext is not None and ext[0] is not None:  # external force / m, world ENU
        ax, ay, az = ax + ext[0][0], ay + ext[0][1], az + ext[0][2]
    hh = 0.5 * h * h
    x1, y1, z1 = x + h * vx + hh * ax, y + h * vy + hh * ay, z + h * vz + hh * az
    vx1, vy1, vz1 = vx + h * ax, vy + h * ay, vz + h * az
    return [x1, y1, z1, vx1, vy1, vz1, phi1, th1, psi1, p1, q1, r1], w
