"""Timing of a real vehicle's loop in training: an action delay, an observation delay and jitter,
drawn per drone and per episode and applied at the control rate.

A deployed policy does not see the state of now, and its command does not reach the rotors now: a
radio or serial link, the state estimator and the ESC each add milliseconds. Sim-to-real work on
quadrotors trains through such latency (Molchanov et al. 2019, "Sim-to-(multi)-real"; Eschmann et
al. 2024, "Learning to fly in seconds", which randomised the delay of the actions it trained on);
`quad-sitl --link-impair delay=T` adds T to each direction of the node's link, so a delay of T
there is T on the observation and T on the command.

`TimingConfig` holds the ranges, in milliseconds: at every reset each drone draws an action delay,
an observation delay and a jitter amplitude uniformly from them. At every step each delay is the
episode's delay plus a draw uniform in ±jitter (never below 0), as `link.impair` delays each frame:

- **Action delay** d = k·dt + r (0 ≤ r < dt): over the step the rotors are driven by the command
  sent k + 1 steps ago for the first r seconds and by the one sent k steps ago for the rest, whose
  zero-order-hold average is what `DelayLine.command` hands the plant:
  (r/dt)·u[t−k−1] + (1 − r/dt)·u[t−k].
- **Observation delay**: the policy sees the state of k = round(d/dt) steps ago, the rounding drawn
  (up with probability frac(d/dt)), so that on average the state is d old; a state is never older
  than the one seen the step before (frames keep their order, as on a serial line).

Before an episode's first step the history is the start: the commands are the start rotor speeds'
and the states the start state. NumPy only; randomness comes from a generator the batch reseeds at
every reset, so a batch without timing draws exactly what it drew before.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

Range = tuple[float, float]

MAX_DELAY_MS = 500.0
"""ms, the largest delay plus jitter a TimingConfig accepts."""


@dataclass(frozen=True)
class TimingConfig:
    """Ranges, in milliseconds, of the per-episode timing: each drawn uniformly per drone at every
    reset. (a, a) fixes a value."""

    name: str = "custom"
    """The preset this came from (`PRESETS`), or custom."""
    action_delay_ms: Range = (0.0, 0.0)
    """ms, from the policy's output to the rotors' command."""
    obs_delay_ms: Range = (0.0, 0.0)
    """ms, age of the state the policy is given."""
    jitter_ms: Range = (0.0, 0.0)
    """ms, per-step spread of both delays: each step adds a draw uniform in ±jitter."""

    def __post_init__(self) -> None:
        for key in ("action_delay_ms", "obs_delay_ms", "jitter_ms"):
            v = getattr(self, key)
            if not (isinstance(v, (tuple, list)) and len(v) == 2):
                raise ValueError(f"timing {key} must be a (low, high) pair of milliseconds, got {v!r}")
            try:
                lo, hi = float(v[0]), float(v[1])
            except (TypeError, ValueError):
                raise ValueError(f"timing {key} must be a (low, high) pair of milliseconds, got {v!r}") from None
            if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo <= hi):
                raise ValueError(f"timing {key} must be finite with 0 ≤ low ≤ high, got {v!r}")
            object.__setattr__(self, key, (lo, hi))
        worst = max(self.action_delay_ms[1], self.obs_delay_ms[1]) + self.jitter_ms[1]
        if worst > MAX_DELAY_MS:
            raise ValueError(f"timing: a delay plus its jitter may reach {worst:g} ms; at most {MAX_DELAY_MS:g} ms")

    @classmethod
    def fixed(cls, delay_ms: float, jitter_ms: float = 0.0) -> TimingConfig:
        """The same delay on the action and the observation, and ±jitter per step, in every episode:
        what `quad-sitl --link-impair delay=T,jitter=J` does to each direction of the node's link."""
        d, j = (float(delay_ms), float(delay_ms)), (float(jitter_ms), float(jitter_ms))
        return cls(name=f"{delay_ms:g}ms±{jitter_ms:g}", action_delay_ms=d, obs_delay_ms=d, jitter_ms=j)

    @property
    def active(self) -> bool:
        """Any delay or jitter at all."""
        return max(self.action_delay_ms[1], self.obs_delay_ms[1], self.jitter_ms[1]) > 0.0

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> TimingConfig:
        if not isinstance(d, dict):
            raise ValueError(f"timing must be a table of action_delay_ms, obs_delay_ms, jitter_ms; got {d!r}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown timing field(s) {sorted(unknown)}; known: {sorted(known)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


PRESETS: dict[str, TimingConfig] = {
    # up to 50 ms each way and ±10 ms per step: room round quad-sitl --link-impair delay=20ms,jitter=10ms
    # (20 ms each way) and up to delay=40ms. Trained on the seed vehicle, 0-40 ms left 12 to 44 % of
    # the episodes at a fixed 40 ms each way crashing and 0-60 ms cost 1 to 2 cm of hover error with
    # none; 0-50 ms over 3 M steps held both (docs/robustness.md, "Trained through delay")
    "link": TimingConfig(name="link", action_delay_ms=(0.0, 50.0), obs_delay_ms=(0.0, 50.0), jitter_ms=(0.0, 10.0)),
    "none": TimingConfig(name="none"),
}
"""Named timings (quad-train --timing NAME)."""


def get_timing(name: str) -> TimingConfig:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown timing preset {name!r}; known: {', '.join(PRESETS)}") from None


class DelayLine:
    """The delays of n drones: ring buffers of the last commands (M, n) and states (12, n), a slot a
    step, with each drone's drawn delays (`TimingConfig`, module docstring for the rules)."""

    def __init__(self, cfg: TimingConfig, n: int, n_rotors: int, state_dim: int, dt: float, dtype) -> None:
        self.cfg, self.n, self.dt = cfg, n, float(dt)
        worst = max(cfg.action_delay_ms[1], cfg.obs_delay_ms[1]) + cfg.jitter_ms[1]
        self.length = math.ceil(worst * 1e-3 / self.dt) + 2  # slots: the oldest a step can reach, + 1
        self.commands = np.zeros((self.length, n_rotors, n), dtype)
        self.states = np.zeros((self.length, state_dim, n), dtype)
        self.slot = 0  # where the newest command and state were written
        self.action_steps = np.zeros(n)  # each drone's episode delays, in steps
        self.obs_steps = np.zeros(n)
        self.jitter_steps = np.zeros(n)
        self.seen = np.zeros(n, np.int64)  # age-ordering: the step count of the state last seen
        self.count = np.zeros(n, np.int64)  # steps since the drone's episode began
        self.rng = np.random.default_rng(0)
        self._cols = np.arange(n)

    def reset(self, idx: np.ndarray, rng: np.random.Generator, commands: np.ndarray, states: np.ndarray) -> None:
        """Drones `idx` start an episode: delays drawn from `rng`, the histories filled with their
        start commands (M, k) and states (12, k); the per-step draws continue from a seed drawn here."""
        k, c, ms = idx.size, self.cfg, 1e-3 / self.dt
        self.action_steps[idx] = rng.uniform(*c.action_delay_ms, k) * ms
        self.obs_steps[idx] = rng.uniform(*c.obs_delay_ms, k) * ms
        self.jitter_steps[idx] = rng.uniform(*c.jitter_ms, k) * ms
        self.rng = np.random.default_rng(int(rng.integers(2**63)))
        self.commands[:, :, idx] = commands[None]
        self.states[:, :, idx] = states[None]
        self.seen[idx] = 0
        self.count[idx] = 0

    def _delays(self, base: np.ndarray) -> np.ndarray:
        """This step's delay of every drone, in steps: base ± jitter, at least 0, at most the ring's reach."""
        d = base + self.jitter_steps * self.rng.uniform(-1.0, 1.0, self.n)
        # rounded to 1e-9 of a step, so that a delay of whole steps (30 ms at 100 Hz: 2.9999999999999996
        # steps in floating point) is whole
        return np.clip(np.round(d, 9), 0.0, self.length - 2)

    def command(self, u: np.ndarray) -> np.ndarray:
        """The command the rotors get this step (M, n), with `u` (M, n) the one sent now."""
        self.slot = (self.slot + 1) % self.length
        self.count += 1
        self.commands[self.slot] = u
        d = self._delays(self.action_steps)
        k = np.floor(d).astype(np.int64)
        r = (d - k).astype(u.dtype)
        newer = self.commands[(self.slot - k) % self.length, :, self._cols].T  # (M, n)
        older = self.commands[(self.slot - k - 1) % self.length, :, self._cols].T
        return newer + r * (older - newer)

    def observed(self, s: np.ndarray) -> np.ndarray:
        """The state rows the policy sees this step (12, n), with `s` (12, n) the state now (after the
        step whose command `command` gave)."""
        self.states[self.slot] = s
        d = self._delays(self.obs_steps)
        k = np.floor(d).astype(np.int64)
        k += self.rng.random(self.n) < (d - k)
        k = np.minimum(k, self.count - self.seen)  # never older than the state seen last
        k = np.minimum(k, self.length - 1)
        self.seen = self.count - k
        return np.ascontiguousarray(self.states[(self.slot - k) % self.length, :, self._cols].T)

    ARRAYS = ("commands", "states", "action_steps", "obs_steps", "jitter_steps", "seen", "count")

    def state_dict(self) -> dict:
        """What is in flight (copies) and the generator state: arrays and JSON-able data only, so that a
        resumed training run goes on with the same commands and states on their way."""
        return {
            **{k: getattr(self, k).copy() for k in self.ARRAYS},
            "slot": self.slot,
            "rng": self.rng.bit_generator.state,
        }

    def load_state_dict(self, d: dict) -> None:
        """Put back `state_dict`'s data; ValueError, saying what does not fit, for data of another line."""
        arrays = {}
        for k in self.ARRAYS:
            mine = getattr(self, k)
            v = np.asarray(d[k]).astype(mine.dtype)
            if v.shape != mine.shape:
                raise ValueError(f"timing {k}: shape {v.shape}, this delay line's is {mine.shape}")
            arrays[k] = v.copy()
        slot = int(d["slot"])
        if not 0 <= slot < self.length:
            raise ValueError(f"timing slot {slot}: expected 0 to {self.length - 1}")
        state = d["rng"]
        if not isinstance(state, dict) or state.get("bit_generator") != "PCG64":
            raise ValueError("timing rng: expected a PCG64 generator state")
        bitgen = np.random.PCG64()
        bitgen.state = state
        for k, v in arrays.items():
            setattr(self, k, v)
        self.slot, self.rng = slot, np.random.Generator(bitgen)
