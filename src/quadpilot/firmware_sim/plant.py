"""The simulated vehicle's physics (`Plant`): `core.dynamics.step` on a batch of one, with wind and
gusts as its external force, kept inside the domain the model holds in.
"""

from __future__ import annotations

import math

import numpy as np

from quadpilot.core import dynamics
from quadpilot.core.frames import euler_to_rotmat, rotmat_to_euler
from quadpilot.core.params import ParamBatch, VehicleParams
from quadpilot.link import wire

from . import sensors

_HALF_PI = 0.5 * math.pi


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
    linearly and quadratically in time."""

    def __init__(
        self,
        vehicle: VehicleParams,
        dt: float,
        wind=(0.0, 0.0, 0.0),
        gust_std: float = 0.0,
        gust_tau_s: float = 2.0,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.vehicle = vehicle
        self.params = ParamBatch.from_preset(vehicle, 1)
        self.dt = dt
        self.wind = np.asarray(wind, np.float64)
        # F = drag·(wind − v): core.dynamics applies −drag·v itself (params.drag) and takes the
        # drag·wind part as its external force, as the training environments' wind does.
        self._wind_force = vehicle.drag * self.wind  # N, world ENU
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
        self.state = np.zeros(dynamics.STATE_DIM)
        self.rotor = np.full(dynamics.NUM_MOTORS, self.hover_command)
        self.rate_limited_steps = 0
        """Steps whose body rates had to be saturated at MAX_BODY_RATE (see the class docstring)."""

    def reset(self, state: np.ndarray) -> None:
        """Start from `state` (12,) with the rotors at hover speed."""
        self.state = np.array(state, dtype=np.float64).reshape(dynamics.STATE_DIM)
        self.rotor = np.full(dynamics.NUM_MOTORS, self.hover_command)
        self.rate_limited_steps = 0
        self.gust = self._rng.normal(0.0, self.gust_std, 3) if self.gust_std > 0 else np.zeros(3)

    @property
    def air(self) -> np.ndarray:
        """m/s, world ENU: the wind now (constant part plus gust)."""
        return self.wind + self.gust

    def step(self, command: np.ndarray) -> None:
        """Advance one dt with `command` (4,) in [0, 1] held."""
        force = self._wind_force
        if self.gust_std > 0:
            self.gust = self._gust_decay * self.gust + self._gust_kick * self._rng.normal(size=3)
            force = self.vehicle.drag * self.air
        s, w = dynamics.step(
            self.state[None],
            self.rotor[None],
            np.asarray(command, np.float64)[None],
            self.params,
            self.dt,
            force=force[None] if force.any() else None,
        )
        self.state, self.rotor = s[0], w[0]
        self._keep_in_domain(self.state)

    def _keep_in_domain(self, s: np.ndarray) -> None:
        """Saturate the body rates and canonicalise roll and pitch, in place (class docstring)."""
        roll, pitch, _, p, q, r = s[6:12].tolist()  # plain floats: comparisons cheaper than numpy's
        lim = wire.MAX_BODY_RATE
        if not (-lim <= p <= lim and -lim <= q <= lim and -lim <= r <= lim):
            np.clip(s[9:12], -lim, lim, out=s[9:12])
            self.rate_limited_steps += 1
        if not (-math.pi <= roll <= math.pi and -_HALF_PI <= pitch <= _HALF_PI):
            angles = rotmat_to_euler(euler_to_rotmat(s[6], s[7], s[8]))
            s[6:9] = [float(a) for a in angles]

    @property
    def thrust_n(self) -> float:
        """N, total rotor thrust at the current rotor speeds."""
        return float(self._f_max * np.sum(self.rotor * self.rotor))

    def specific_force_flu(self) -> np.ndarray:
        """m/s², body FLU, what an ideal accelerometer reads now."""
        return sensors.specific_force_flu(self.state, self.thrust_n, self.vehicle.mass, self.vehicle.drag, self.air)
