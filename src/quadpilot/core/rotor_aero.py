"""RotorPy's rotor aerodynamics: rotor drag (H force), induced inflow, translational lift and blade
flapping, as rotorpy/vehicles/multirotor.py (`compute_body_wrench`) models them.

Each rotor i sits at r_i = (x_i, y_i, 0) in body FLU and spins at ω_i rad/s. Its local airspeed is
the body airspeed plus the frame's rotation, v_i = v_a + Ω × r_i (v_a = Rᵀ(v − wind), Ω the body
rates). At its hub act
- the rotor drag H_i = −ω_i·diag(k_d, k_d, k_z)·v_i,
- the translational lift k_h·(v_i,x² + v_i,y²) along +z (added to the rotor's thrust),
- the flapping moment −k_flap·ω_i·(v_i × e_z) = −k_flap·ω_i·(v_i,y, −v_i,x, 0),
and the forces at the hub make the moment r_i × F_i. `core.dynamics` adds the sums to the rotors'
thrust and mixer moments; a vehicle with all four coefficients 0 never calls this.
"""

from __future__ import annotations

import numpy as np


def rotor_aero_wrench(
    body_air: np.ndarray,
    rates: np.ndarray,
    omega: np.ndarray,
    rx: np.ndarray,
    ry: np.ndarray,
    k_d: np.ndarray,
    k_z: np.ndarray,
    k_h: np.ndarray,
    k_flap: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """(force (3, N) N, moment (3, N) N·m), body FLU, from the body airspeed (3, N) m/s, the body
    rates (3, N) rad/s, the rotor speeds omega (M, N) rad/s, the rotor positions rx, ry (M, N) m in
    FLU, and the per-drone coefficients (N,) (module docstring)."""
    p, q, r = rates
    force = np.zeros_like(body_air)
    moment = np.zeros_like(body_air)
    for i in range(omega.shape[0]):
        x, y, w = rx[i], ry[i], omega[i]
        # v_i = v_a + Ω × r_i, with r_i = (x, y, 0): Ω × r_i = (−r·y, r·x, p·y − q·x)
        vx = body_air[0] - r * y
        vy = body_air[1] + r * x
        vz = body_air[2] + (p * y - q * x)
        hx, hy = -w * k_d * vx, -w * k_d * vy
        fz = -w * k_z * vz + k_h * (vx * vx + vy * vy)  # induced inflow and translational lift
        force[0] += hx
        force[1] += hy
        force[2] += fz
        # r_i × (hx, hy, fz) = (y·fz, −x·fz, x·hy − y·hx), and the flapping moment
        moment[0] += y * fz - k_flap * w * vy
        moment[1] += -x * fz + k_flap * w * vx
        moment[2] += x * hy - y * hx
    return force, moment
