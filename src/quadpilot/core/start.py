"""Start-state distributions, shared by the training environments and the SITL simulator so that
"the same initial state ranges" means the same code."""

from __future__ import annotations

import math

import numpy as np

from .state import POS, RATES, ROLL_PITCH, STATE_DIM, VEL, YAW


def sample_ball(rng: np.random.Generator, n: int, radius: float) -> np.ndarray:
    """(n, 3) points uniform in a ball."""
    v = rng.normal(size=(n, 3))
    v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    return v * (radius * rng.random((n, 1)) ** (1.0 / 3.0))


def sample_start_states(
    rng: np.random.Generator,
    centres: np.ndarray,
    pos_radius: float,
    vel: float,
    tilt_deg: float,
    rate: float = 0.0,
) -> np.ndarray:
    """(k, 12) start states (ENU/FLU, float64) around `centres` (k, 3): position uniform in a ball
    of `pos_radius`, each velocity component uniform in ±vel, roll and pitch uniform in
    ±tilt_deg, yaw uniform in [−π, π), each body rate uniform in ±rate."""
    k = centres.shape[0]
    tilt = math.radians(tilt_deg)
    s = np.zeros((k, STATE_DIM))
    s[:, POS] = centres + sample_ball(rng, k, pos_radius)
    s[:, VEL] = rng.uniform(-vel, vel, (k, 3))
    s[:, ROLL_PITCH] = rng.uniform(-tilt, tilt, (k, 2))
    s[:, YAW] = rng.uniform(-np.pi, np.pi, k)
    s[:, RATES] = rng.uniform(-rate, rate, (k, 3)) if rate > 0 else 0.0
    return s
