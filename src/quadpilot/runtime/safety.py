"""The safety monitor: every observation is checked before it reaches the policy, every command
after, and anything outside what the policy was trained for goes to the classical fallback.

    monitor = SafetyMonitor(load_policy("policy.onnx"))   # fallback built for the file's vehicle
    motors = monitor.act(obs)                             # (4,) float32, finite, in [0, 1]
    monitor.events                                        # counts by reason

Per call, in order:

1. Observation: every value finite and within a physically possible magnitude for its field
   (`ObservationLimits`), and the attitude block a rotation matrix (columns of unit length and
   orthogonal, determinant +1, to within `ObservationLimits.rot_orthonormal`; entries in [−1, 1]
   alone admit a matrix of all 0.5, or a reflection). +Inf passed to the network goes through tanh
   to a saturated, full-thrust command without any error, so this is checked first. A bad
   observation is never given to the policy, and the step is flown blind at hover thrust (equal
   motors: no moment; `blind`). Not the fallback on the last good observation: it would correct a
   frozen attitude error open loop, measured to flip the vehicle within a 0.2 s dropout. From the
   next good observation the fallback flies.
2. Envelope: distance to the target and roll/pitch within what the file's metadata says the
   policy was trained in (training episodes ended beyond them, so the policy never learned to act
   there). Outside it, the fallback flies.
3. Command: a non-finite command hands over to the fallback; a finite one outside [0, 1] is
   clamped and counted (the exported graph clamps already, so this means a foreign graph).

Hand-over and hand-back (simplex): the fallback takes over at once and the policy gets the vehicle
back once the state has been valid and inside the recovery envelope (RECOVERY_FRACTION of the exit
envelope's distance and tilt) for HAND_BACK_HOLD_S of consecutive policy ticks; a bad observation
restarts that time. The recovery envelope is smaller than the exit envelope so that a vehicle at the
edge of the exit envelope does not switch controllers every step. What still latches until
`reset()` (a deliberate re-arm), and why: a non-finite command (the policy itself computed
nonsense: nothing says it will not again), and the MAX_ENVELOPE_EXITS-th envelope exit of one
flight (a policy that keeps leaving its envelope does not fly this vehicle). Every hand-over and
hand-back is counted in `events` (`fallback_engaged`, `handed_back`, `fallback_latched`) and
queued in `transitions` for whoever logs them (`autopilot.node`). `source` says who flew the last
step: "policy", "fallback", or "recovering" (the fallback, after bad input, while the hand-back
time runs inside the recovery envelope: the price of the hand-back rule, not a failure of the
policy; `sitl.node_only` does not count those steps against the flight).
"""

from __future__ import annotations

import math
import operator
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

from quadpilot.core.params import NUM_MOTORS

from .policy import Policy

HAND_BACK_HOLD_S = 0.2
"""s of consecutive valid observations inside the recovery envelope before the policy flies again.
The fallback's attitude loop closes at about 19 rad/s on the seed vehicle (`runtime.fallback`,
`FallbackGains`: a time constant near 0.05 s), so 0.2 s is four of its time constants: the attitude
transient of the hand-over has decayed to a few per cent, and a vehicle merely passing through the
recovery envelope (at 12.5 m/s it crosses the hover policy's 2.5 m radius in 0.2 s) is not handed
back. It also bounds switching to 5 Hz. Longer holds cost flight time for nothing after a single
dropped packet (1 in 50 states bad leaves the policy 29 of every 50 steps with 0.2 s)."""
RECOVERY_FRACTION = 0.5
"""The recovery envelope: this fraction of the exit envelope's distance and tilt (for the hover
policy 2.5 m and 30°, against 5 m and 60°). It holds the training start distribution (within 1 m and
±20° of roll and pitch, `train.envs.EnvConfig`) with margin, and the gap to the exit envelope is the
hysteresis that keeps a vehicle at the edge from switching every step."""
MAX_ENVELOPE_EXITS = 3
"""The third envelope exit of one flight latches the fallback: a policy that keeps leaving the
envelope it was trained in does not fly this vehicle."""
BAD_INPUT = "input"
"""`SafetyMonitor` hand-over cause: a bad observation or a dropped state (flown blind)."""


@dataclass(frozen=True)
class ObservationLimits:
    """Largest magnitude believed per observation field; beyond it the value is a fault, not a state."""

    pos_error: float = 1000.0
    """m. A kilometre from the target is no hover any controller should trust."""
    vel: float = 100.0
    """m/s. Well beyond any small multirotor."""
    rot: float = 1.0 + 1e-3
    """Rotation-matrix entries lie in [−1, 1]; the margin allows float32 rounding."""
    rot_orthonormal: float = 1e-3
    """Largest deviation of the attitude block from a rotation: the sum of the first two columns'
    |squared length − 1|, of |their dot product|, and of the third column's components' distance
    from the cross product of the first two (which also makes the determinant +1, not −1). float32
    rounding of a rotation is ~1e-7."""
    rates: float = 70.0
    """rad/s, twice a 2000 °/s gyro's full scale (the usual MEMS range)."""
    target_vel: float = 100.0
    """m/s."""
    prev_action: float = 1.0 + 1e-3
    """The previous action of the px4-raptor contract: clamped to [−1, 1] (a mean of such values)."""

    def vector(self, layout) -> np.ndarray:
        """(obs_dim,) float64 bound per value, in the layout's order."""
        out = np.empty(layout.dim)
        for name, sl in layout.slices().items():
            out[sl] = getattr(self, name)
        return out


class SafetyMonitor:
    """Wraps a runtime policy (any backend) with checks and a classical fallback that hands back."""

    def __init__(self, policy: Policy, fallback=None, limits: ObservationLimits | None = None) -> None:
        from .fallback import FallbackController

        self.policy = policy
        self._policy_act = policy.act_unchecked
        self._observation = policy.observation
        info = policy.info
        make = getattr(policy, "make_fallback", None)  # a policy with an observation of its own brings its fallback
        if fallback is None:
            fallback = make() if make is not None else None
        self.fallback = (
            fallback
            if fallback is not None
            else FallbackController(info.vehicle, info.control_period_s, heading_frame=info.layout.heading_frame)
        )
        self.limits = limits or ObservationLimits()
        self._bound = self.limits.vector(info.layout).tolist()
        sl = info.layout.slices()
        self._pos = sl["pos_error"].start
        rot = sl["rot"].start
        self._rot = slice(rot, rot + 9)
        self._rot_tol = float(self.limits.rot_orthonormal)
        self._r31, self._r32, self._r33 = rot + 6, rot + 7, rot + 8  # row-major R, third row
        self._max_dist_sq = float(info.envelope["max_distance_m"]) ** 2
        max_tilt = math.radians(float(info.envelope["max_tilt_deg"]))  # in (0°, 90°): read_model checks
        self._sin_max_tilt = math.sin(max_tilt)
        self._cos2_max_tilt = math.cos(max_tilt) ** 2
        self._max_dist_sq_back = (RECOVERY_FRACTION * float(info.envelope["max_distance_m"])) ** 2
        tilt_back = RECOVERY_FRACTION * max_tilt
        self._sin_tilt_back, self._cos2_tilt_back = math.sin(tilt_back), math.cos(tilt_back) ** 2
        self.hold_ticks = max(1, math.ceil(HAND_BACK_HOLD_S / float(info.control_period_s) - 1e-9))
        self.transitions: deque[tuple[str, str]] = deque(maxlen=256)
        """("hand-over" | "hand-back" | "latched", why), oldest first, for the caller to log and clear
        (bounded: a caller that never reads them keeps only the last 256)."""
        self.events: Counter[str] = Counter()
        self.source = "policy"
        self._engaged = False  # the fallback flies
        self._latched = False  # ... until reset()
        self._cause = BAD_INPUT  # why it was engaged: BAD_INPUT or the policy's reason
        self._inside = 0  # consecutive ticks valid and inside the recovery envelope
        self._exits = 0  # envelope exits this flight
        self._hover = np.full(NUM_MOTORS, info.vehicle.hover_command, np.float32)

    def replace_policy(self, policy: Policy) -> None:
        """Fly `policy` instead, from now on, with this monitor's fallback and limits: it must observe
        the same layout at the same rate as the one it replaces (ValueError otherwise). Reset, as for
        a new flight: call it between flights (the node does while disarmed)."""
        old, new = self.policy.info, policy.info
        if new.layout != old.layout or new.control_period_s != old.control_period_s:
            raise ValueError(f"{new.path}: a different observation or rate than {old.path}; expected the same contract")
        self.policy, self._policy_act, self._observation = policy, policy.act_unchecked, policy.observation
        self.reset()

    @property
    def in_fallback(self) -> bool:
        """The fallback has the vehicle (for now, or latched)."""
        return self._engaged

    @property
    def latched(self) -> bool:
        """The fallback keeps the vehicle until `reset()`."""
        return self._latched

    def reset(self) -> None:
        """New episode or explicit re-arm: the policy flies again, recurrent state and fallback
        integrators cleared. Event counts are kept (they are a log, not a state)."""
        self.policy.reset()
        self.fallback.reset()
        self._engaged = self._latched = False
        self._inside = self._exits = 0
        self.transitions.clear()
        self.source = "policy"

    def _outside_envelope(self, vals: list, recovery: bool = False) -> bool:
        """Beyond the exit envelope (or, `recovery`, the smaller recovery envelope)."""
        max_dist_sq, sin_tilt, cos2_tilt = (
            (self._max_dist_sq_back, self._sin_tilt_back, self._cos2_tilt_back)
            if recovery
            else (self._max_dist_sq, self._sin_max_tilt, self._cos2_max_tilt)
        )
        p = self._pos
        e0, e1, e2 = vals[p], vals[p + 1], vals[p + 2]
        if e0 * e0 + e1 * e1 + e2 * e2 > max_dist_sq:
            return True
        # ZYX Euler as in core.frames (the angles training terminated on): pitch = −asin(R31), and
        # roll = atan2(R32, R33) with (R32, R33) = cos(pitch)·(sin roll, cos roll), so
        # |roll| ≤ θ ⟺ R33 ≥ 0 and R33² ≥ cos²θ·(R32² + R33²), without a trigonometric call
        if abs(vals[self._r31]) > sin_tilt:
            return True
        r32, r33 = vals[self._r32], vals[self._r33]
        return r33 < 0.0 or r33 * r33 < cos2_tilt * (r32 * r32 + r33 * r33)

    def _not_a_rotation(self, vals: list) -> bool:
        """The observation's attitude block (row-major R) is no rotation within `rot_orthonormal`.
        Scalar arithmetic on plain floats, one sum and one comparison: this runs every call (see
        the benchmarks)."""
        a, b, c, d, e, f, g, h, i = vals[self._rot]  # columns (a, d, g), (b, e, h), (c, f, i)
        deviation = (
            abs(a * a + d * d + g * g - 1.0)  # first two columns of unit length
            + abs(b * b + e * e + h * h - 1.0)
            + abs(a * b + d * e + g * h)  # and orthogonal
            + abs(d * h - g * e - c)  # third column = first × second: right-handed, determinant +1
            + abs(g * b - a * h - f)
            + abs(a * e - d * b - i)
        )
        return not deviation <= self._rot_tol  # True for NaN too

    def blind(self, reason: str) -> np.ndarray:
        """The command for a step with nothing trustworthy to fly on (a bad observation, or a state
        the node had to drop): hover thrust on every motor, no moment. Counted under `reason` and
        in `blind_steps`; hands over to the fallback like every bad observation, and restarts the
        hand-back time."""
        self._hand_over(reason, BAD_INPUT)
        self._inside = 0
        self.events["blind_steps"] += 1
        self.source = "fallback"
        return self._hover.copy()

    def take_over(self, reason: str) -> None:
        """Another controller flies for now (the node's hold or landing while the state is lost): the
        fallback is engaged as for bad input, so the policy flies again by the usual hand-back once
        valid observations have stayed inside the recovery envelope for HAND_BACK_HOLD_S."""
        self._hand_over(reason, BAD_INPUT)
        self._inside = 0
        self.source = "fallback"

    def _hand_over(self, reason: str, cause: str, latch: bool = False) -> None:
        self.events[reason] += 1
        if not self._engaged:
            self._engaged, self._cause, self._inside = True, cause, 0
            self.events["fallback_engaged"] += 1
            self.transitions.append(("hand-over", reason))
        if latch and not self._latched:
            self._latched = True
            self.events["fallback_latched"] += 1
            self.transitions.append(("latched", reason))

    def _hand_back(self) -> None:
        """The policy flies again: its recurrent state (stale by the fallback's steps) and the
        fallback's integrators are cleared, as for a new flight."""
        self.policy.reset()
        self.fallback.reset()
        self._engaged, self._inside = False, 0
        self.events["handed_back"] += 1
        self.transitions.append(("hand-back", f"{HAND_BACK_HOLD_S:g} s in recovery envelope"))  # fits STATUSTEXT

    def _fly_fallback(self, obs: np.ndarray, source: str = "fallback") -> np.ndarray:
        self.events["fallback_steps"] += 1
        self.source = source
        cmd = np.asarray(self.fallback.act(obs), np.float32)
        if not np.all(np.isfinite(cmd)):  # belt and braces: never send NaN (PX4 reads it as stop)
            self.events["fallback_nonfinite"] += 1
            return self._hover.copy()
        return np.clip(cmd, 0.0, 1.0)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Motor commands (4,) float32 in [0, 1], finite, for one raw observation (obs_dim,)."""
        obs = self._observation(obs)
        vals = obs.tolist()
        # |v| ≤ bound for every value, in C (this runs at the control rate and every call costs, see
        # benchmarks); False for NaN too. The first value out of bounds names the reason.
        if not all(map(operator.le, map(abs, vals), self._bound)):
            for v, b in zip(vals, self._bound, strict=False):  # lengths equal: checked above
                if not -b <= v <= b:
                    return self.blind("obs_out_of_range" if math.isfinite(v) else "obs_nonfinite")
        if self._not_a_rotation(vals):
            return self.blind("obs_not_rotation")
        if self._engaged:
            if self._latched or self._outside_envelope(vals, recovery=True):
                self._inside = 0
                return self._fly_fallback(obs)
            self._inside += 1
            if self._inside <= self.hold_ticks:
                return self._fly_fallback(obs, "recovering" if self._cause == BAD_INPUT else "fallback")
            self._hand_back()  # and the policy flies this step
        if self._outside_envelope(vals):
            self._exits += 1
            self._hand_over("out_of_envelope", "out_of_envelope", latch=self._exits >= MAX_ENVELOPE_EXITS)
            return self._fly_fallback(obs)
        cmd = self._policy_act(obs)
        self.source = "policy"
        for v in cmd.tolist():
            if not 0.0 <= v <= 1.0:  # False for NaN too (min/max of a list would skip a NaN)
                break
        else:
            return cmd
        if not np.isfinite(cmd).all():
            self._hand_over("command_nonfinite", "command_nonfinite", latch=True)
            return self._fly_fallback(obs)
        self.events["command_clamped"] += 1
        return np.clip(cmd, 0.0, 1.0)
