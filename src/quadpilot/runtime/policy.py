"""The interface every policy backend implements (`Policy`), and the one check of what reaches it.

    motors = policy.act(obs)     # (obs_dim,) or (1, obs_dim) real numbers → (4,) float32
    policy.reset()               # start of an episode: recurrent state to zero

A backend (`backends.OnnxRuntimePolicy`, `backends.NumpyPolicy`, `cbackend.CPolicy`) implements
`act_unchecked` on a float32 (obs_dim,) array and, if recurrent, `reset`. `Policy.act` takes only
a real-number array of the policy's shape; anything else (strings, None, dicts, object or complex
arrays, a wrong size) raises `ObservationShapeError`, one line. `verify_golden` replays the file's
golden vectors through the backend (`backends.load_policy` decides what difference it accepts).

A module of its own so that every backend imports it and no backend imports another.
"""

from __future__ import annotations

import math

import numpy as np

from quadpilot.modelfile.contract import ModelInfo

_FLOAT32 = np.dtype(np.float32)
_REAL_KINDS = "fiu"
"""NumPy dtype kinds an observation may hold: float, signed and unsigned integer (converted to
float32). Not bool, complex, strings, bytes, objects, dates or structured records."""


class ObservationShapeError(ValueError):
    """An observation of the wrong size, or not an array of real numbers, reached a policy."""


class Policy:
    """Batch-1 policy over raw observations. Subclasses implement `act_unchecked(x)` on a float32
    (obs_dim,)."""

    backend = "?"
    own_observation = None
    """None: the node builds the observation (`observation_one.observe`) and runs the policy at its
    control period. A policy that flies through a contract of its own (`raptor.RaptorPolicy`, PX4
    mc_raptor's) sets a method (state, target, target_vel, heading, t_us) → observation, and the node
    calls it and the policy at every simulator step, as mc_raptor runs on every gyro update."""

    def __init__(self, info: ModelInfo) -> None:
        self.info = info
        self.obs_dim = info.obs_dim
        self._shape = (info.obs_dim,)

    def observation(self, obs) -> np.ndarray:
        """`obs` as the (obs_dim,) float32 array `act_unchecked` takes; accepts (obs_dim,),
        (1, obs_dim) or a sequence of real numbers, raises ObservationShapeError for anything else."""
        if type(obs) is np.ndarray and obs.dtype is _FLOAT32 and obs.shape == self._shape:
            return obs  # the control loop's case: one type check, one identity check, one compare
        return self._checked_observation(obs)

    def _checked_observation(self, obs) -> np.ndarray:
        expects = f"this policy ({self.info.layout.name}) expects ({self.obs_dim},) or (1, {self.obs_dim}) float32"
        try:
            a = obs if type(obs) is np.ndarray else np.asarray(obs)
        except Exception as e:  # ragged sequences, objects whose __array__ or __len__ raise, ...
            raise ObservationShapeError(
                f"observation of type {type(obs).__name__} is not an array of numbers ({type(e).__name__}); {expects}"
            ) from None
        if a.dtype.kind not in _REAL_KINDS:
            raise ObservationShapeError(
                f"observation of type {type(obs).__name__} holds {a.dtype} values, not real numbers; {expects}"
            )
        if a.shape != self._shape:
            if a.shape != (1, self.obs_dim):
                raise ObservationShapeError(f"observation has shape {a.shape}; {expects}")
            a = a.reshape(self.obs_dim)
        return a if a.dtype is _FLOAT32 else a.astype(np.float32)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Motor commands (4,) float32 for one observation (obs_dim,) or (1, obs_dim)."""
        return self.act_unchecked(self.observation(obs))

    def act_unchecked(self, x: np.ndarray) -> np.ndarray:
        """Motor commands (4,) float32 for `x` as `observation` returns it, unchecked: for a caller
        that checks once and calls this directly (`safety.SafetyMonitor`)."""
        raise NotImplementedError

    def reset(self) -> None:
        """Start of an episode: zero the recurrent state."""

    def verify_golden(self) -> float:
        """Replay the file's golden sequence from zero state; returns the max abs difference."""
        self.reset()
        worst = 0.0
        for obs, want in zip(self.info.golden_obs, self.info.golden_action, strict=True):
            got = self.act(obs)
            diff = float(np.max(np.abs(got - want)))  # np.max propagates a NaN
            if math.isnan(diff):  # a NaN command reproduces nothing: the worst mismatch, and final
                worst = math.nan
                break
            worst = max(worst, diff)
        self.reset()
        return worst
