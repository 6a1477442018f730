"""`core.dynamics.step` for the simulator's one drone, in scalar arithmetic (`SingleStep`).

The simulator steps one vehicle at a time, and `core.dynamics.step` on a batch of one spends most
of its time on NumPy's per-call overhead (some 60 ufunc calls on arrays of one element, and the
copies in and out), several times what the arithmetic itself costs on Python floats
(benchmarks/test_env_speed.py measures the batch of one, benchmarks/test_sitl_speed.py the
flight). This is that arithmetic, written out once more for one drone and one substep, operation
for operation in the order `core.dynamics.Stepper` does it, so that it gives the same bits: IEEE
double arithmetic on Python floats and on float64 arrays rounds alike, and neither fuses a multiply
with an add. What could differ is the trigonometry (`math.sin` is the C library's, `np.sin` may be
NumPy's own SIMD code on some CPUs): `core.frames.scalar_trig_agrees` checks the two on sample angles when the module
is loaded, and where they differ `SingleStep.step` declines and the plant takes `core.dynamics.step`
instead. tests/simulator/test_scalar_paths.py compares the two steps bit for bit over random
states, commands, airframes (quad-X, other layouts, motor lag, idle speed, drag) and external forces.

The constants are derived with the same NumPy expressions as `core.dynamics`' (on the batch of
one), and the mixer follows `core.dynamics`' compiled one: each torque row is its largest
|coefficient| times the signed sum of the rotor thrusts, other coefficients multiplied in
(`_mixer_rows`).
"""

from __future__ import annotations

import math

import numpy as np

from quadpilot.core.dynamics import lag_factors
from quadpilot.core.frames import scalar_trig_agrees
from quadpilot.core.params import ParamBatch

_TWO_PI = 2.0 * math.pi
_INV_TWO_PI = 1.0 / _TWO_PI


TRIG_AGREES = scalar_trig_agrees()
"""Whether `SingleStep` may compute (checked once, when this module is loaded)."""


def _mixer_rows(layout, scales) -> tuple:
    """Per torque row (τx, τy, τz): (factor, ((rotor, sign, coefficient or None), ...)), the rows
    `core.mixer.wrench_maker` compiles: τx = arm·Σ y_i·F_i, τy = −arm·Σ x_i·F_i, τz =
    −k_m·Σ spin_i·F_i, each row's largest |coefficient| g folded into its factor (scale / (1/g))
    and the rest left as ±F_i (coefficient ±1) or ±k·F_i."""
    lay = np.asarray(layout, dtype=np.float64)
    rows = []
    for coef, scale in zip((lay[:, 1], -lay[:, 0], -lay[:, 2]), scales, strict=True):
        g = float(np.abs(coef).max())
        if g == 0.0:
            rows.append((None, ()))
            continue
        terms = []
        for i, ci in enumerate(coef.tolist()):
            k = float(ci / g)
            if k == 0.0:
                continue
            terms.append((i, k < 0, None if k in (1.0, -1.0) else abs(k)))
        rows.append((float((scale / (1.0 / g))[0]), tuple(terms)))
    return tuple(rows)


def _clip(x: float, lo: float) -> float:
    """np.clip(x, lo, 1.0) for one float, bit for bit: NaN stays NaN, and a value equal to a bound
    keeps its own sign (−0.0 stays −0.0 at a bound of 0), as NumPy's clip does (checked against it
    by tests/simulator/test_scalar_paths.py, commands at the edges included)."""
    y = lo if x < lo else x
    return 1.0 if y > 1.0 else y


def _row(factor, terms, f) -> float:
    if factor is None:
        return 0.0
    acc = None
    for i, negative, k in terms:
        t = f[i] if k is None else k * f[i]
        if acc is None:
            acc = -t if negative else t
        else:
            acc = acc - t if negative else acc + t
    return factor * acc


class SingleStep:
    """One drone's `core.dynamics.step(state[None], rotor[None], command[None], params, dt,
    force=force[None], armed=...)` with one substep, for a ParamBatch of one drone."""

    def __init__(self, params: ParamBatch, dt: float) -> None:
        if params.n != 1:
            raise ValueError(f"SingleStep steps one drone; the batch has {params.n}")
        self.params, self.dt = params, dt
        p, h = params, dt / 1  # one substep, as core.dynamics.step(substeps=1)
        self.h = h
        one = lambda a: float(np.asarray(a, np.float64)[0])  # noqa: E731
        self.f_max = one(p.k_f * p.omega_max**2)
        self.inv_m = one(1.0 / p.mass)
        self.mass = one(p.mass)
        self.inv_ixx, self.inv_iyy, self.inv_izz = one(1 / p.ixx), one(1 / p.iyy), one(1 / p.izz)
        self.izz_iyy, self.ixx_izz, self.iyy_ixx = one(p.izz - p.iyy), one(p.ixx - p.izz), one(p.iyy - p.ixx)
        self.g = float(np.float64(p.gravity))
        self.u_min = one(p.omega_min / p.omega_max) if np.any(p.omega_min > 0) else 0.0
        self.lag = bool(np.any(p.motor_tau > 0))
        if self.lag:
            self.decay, self.lag_2a, self.lag_b = (one(a) for a in lag_factors(p.motor_tau, h))
        self.drag = bool(np.any(p.drag > 0))
        self.drag_over_m = one(p.drag / p.mass) if self.drag else 0.0
        # the quadratic body drag and the rotor aerodynamics need the air's velocity and a rotation
        # this step does not compute: a vehicle with them takes core.dynamics.step (`step` returns None)
        self.quadratic_drag = any(bool(np.any(a > 0)) for a in (p.c_dx, p.c_dy, p.c_dz, p.k_d, p.k_z, p.k_h, p.k_flap))
        self.rows = _mixer_rows(p.layout, (p.arm, p.arm, p.k_m))
        self.n_rotors = p.n_rotors

    def step(
        self, state: np.ndarray, rotor: np.ndarray, command: np.ndarray, force: np.ndarray | None, armed: bool
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """(new state (12,), new rotor (M,)) from state (12,), rotor (M,), command (M,) float64, an
        external force (3,) N world ENU or None, and whether the motors are on; None where the caller
        must take `core.dynamics.step` itself: a non-finite angle (math.sin raises where np.sin
        gives NaN), or a machine whose NumPy trigonometry is not the C library's (`TRIG_AGREES`)."""
        if not TRIG_AGREES or self.quadratic_drag:
            return None
        try:
            return self._step(state, rotor, command, force, armed)
        except (ValueError, ZeroDivisionError, OverflowError):
            return None

    def _step(self, state, rotor, command, force, armed):
        if armed:
            lo = self.u_min
            u = [_clip(c, lo) for c in command.tolist()]  # as core.dynamics.step clips it
        else:
            u = [0.0] * self.n_rotors  # motors off: commanded speed 0
        x, y, z, vx, vy, vz, phi, th, psi, p, q, r = state.tolist()
        h = self.h
        # --- core.dynamics.Stepper's substep, operation for operation ---
        f_max = self.f_max
        if self.lag:
            decay, a2, b = self.decay, self.lag_2a, self.lag_b
            gap = [wi - ui for wi, ui in zip(rotor.tolist(), u, strict=True)]
            f = [f_max * ui * ui + f_max * ((b * di + a2 * ui) * di) for di, ui in zip(gap, u, strict=True)]
            w = [ui + decay * di for di, ui in zip(gap, u, strict=True)]
        else:
            w = u
            f = [f_max * wi * wi for wi in w]
        thrust = f[0]
        for fi in f[1:]:
            thrust = thrust + fi
        (ax_, tx_terms), (ay_, ty_terms), (az_, tz_terms) = self.rows
        tx, ty, tz = _row(ax_, tx_terms, f), _row(ay_, ty_terms, f), _row(az_, tz_terms, f)

        p1 = p + h * (tx - self.izz_iyy * q * r) * self.inv_ixx
        q1 = q + h * (ty - self.ixx_izz * p * r) * self.inv_iyy
        r1 = r + h * (tz - self.iyy_ixx * p * q) * self.inv_izz
        pm, qm, rm = 0.5 * (p + p1), 0.5 * (q + q1), 0.5 * (r + r1)

        sphi, cphi = math.sin(phi), math.cos(phi)
        sth, cth = math.sin(th), math.cos(th)
        spsi, cpsi = math.sin(psi), math.cos(psi)

        qs_rc = qm * sphi + rm * cphi
        phi1 = phi + h * (pm + qs_rc * sth / cth)
        th1 = th + h * (qm * cphi - rm * sphi)
        psi1 = psi + h * (qs_rc / cth)
        psi1 = psi1 - _TWO_PI * math.floor((psi1 + math.pi) * _INV_TWO_PI)

        t_m = thrust * self.inv_m
        ax = t_m * (cpsi * sth * cphi + spsi * sphi)
        ay = t_m * (spsi * sth * cphi - cpsi * sphi)
        az = t_m * (cth * cphi) - self.g
        if self.drag:
            k = self.drag_over_m
            ax = ax - k * vx
            ay = ay - k * vy
            az = az - k * vz
        if force is not None:
            m = self.mass
            fx, fy, fz = force.tolist()
            ax, ay, az = ax + fx / m, ay + fy / m, az + fz / m
        hh = 0.5 * h * h
        new = np.array(
            [
                x + h * vx + hh * ax,
                y + h * vy + hh * ay,
                z + h * vz + hh * az,
                vx + h * ax,
                vy + h * ay,
                vz + h * az,
                phi1,
                th1,
                psi1,
                p1,
                q1,
                r1,
            ]
        )
        return new, np.array(w, np.float64)
