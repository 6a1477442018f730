"""Waypoint curriculum (the course brief): targets start close to home and move out as the policy masters
each distance, 0.5 → 1.0 → 2.0 m.

Pure logic, no training in here: after each PPO update the trainer hands `observe` the success
flags of the episodes that ended during that update, and calls `env.set_target_radius(radius)`
when `observe` says the stage advanced. A stage is passed when, over at least `min_episodes`
episodes ended in it, the success rate over the last `window` of them reaches `threshold`.

Episodes that end just after an advance began at the previous, easier radius (targets are drawn
at reset). They are not counted: for the first `settle_steps` environment steps of a stage (one
episode length by default) ended episodes are ignored, so every counted episode was flown at the
stage's own radius.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass


@dataclass(frozen=True)
class CurriculumConfig:
    """When the waypoint target radius grows. Derived values are properties of WaypointCurriculum."""

    radii: tuple[float, ...] = (0.5, 1.0, 2.0)
    """m, target radius of each stage, in order (the course brief: 0.5, 1.0, 2.0)."""
    threshold: float = 0.9
    """Success rate over the sliding window that passes a stage."""
    min_episodes: int | None = None
    """Episodes that must end in a stage before it can be passed; None: 2 × num_envs, at least 50."""
    window: int | None = None
    """Sliding window, in episodes, over which the success rate is measured; None: min_episodes."""
    settle_steps: int | None = None
    """Environment steps per drone after an advance during which ended episodes are not counted
    (they began at the previous radius); None: one episode length."""

    def __post_init__(self) -> None:
        r = self.radii
        if not r or any(not x > 0 for x in r) or any(b <= a for a, b in itertools.pairwise(r)):
            raise ValueError(f"radii must be positive and strictly increasing, got {r!r}")
        if not 0.0 < self.threshold <= 1.0:
            raise ValueError(f"threshold must be in (0, 1], got {self.threshold}")
        for name in ("min_episodes", "window"):
            v = getattr(self, name)
            if v is not None and v < 1:
                raise ValueError(f"{name} must be ≥ 1 or None, got {v}")
        if self.settle_steps is not None and self.settle_steps < 0:
            raise ValueError(f"settle_steps must be ≥ 0 or None, got {self.settle_steps}")

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> CurriculumConfig:
        return cls(**{**d, "radii": tuple(d["radii"])})


class WaypointCurriculum:
    """The stage machine. `observe(successes)` once per update; True means "advanced, apply the
    new `radius`". State round-trips through `state_dict()` (JSON-able) for checkpoints."""

    def __init__(self, cfg: CurriculumConfig, num_envs: int, rollout_steps: int, episode_steps: int) -> None:
        self.cfg = cfg
        self.min_episodes = cfg.min_episodes if cfg.min_episodes is not None else max(2 * num_envs, 50)
        self.window = cfg.window if cfg.window is not None else self.min_episodes
        settle = cfg.settle_steps if cfg.settle_steps is not None else episode_steps
        # an episode ending in update u ≥ ceil(settle/T) + 1 of a stage started ≥ settle steps into it
        self.settle_updates = math.ceil(settle / rollout_steps)
        self.stage = 0
        self.updates_in_stage = 0
        self.counted = 0
        self.recent: deque[bool] = deque(maxlen=self.window)

    @property
    def radius(self) -> float:
        return float(self.cfg.radii[self.stage])

    @property
    def final(self) -> bool:
        return self.stage == len(self.cfg.radii) - 1

    @property
    def success_rate(self) -> float:
        """Success rate over the window of counted episodes (NaN before any)."""
        return sum(self.recent) / len(self.recent) if self.recent else float("nan")

    def observe(self, successes: Iterable[bool]) -> bool:
        """Record the episodes that ended in one update; returns True if the stage advanced."""
        self.updates_in_stage += 1
        if self.stage > 0 and self.updates_in_stage <= self.settle_updates:
            return False
        for s in successes:
            self.recent.append(bool(s))
            self.counted += 1
        if self.final or self.counted < self.min_episodes or self.success_rate < self.cfg.threshold:
            return False
        self.stage += 1
        self.updates_in_stage = 0
        self.counted = 0
        self.recent.clear()
        return True

    def state_dict(self) -> dict:
        return {
            "config": self.cfg.to_json(),
            "stage": self.stage,
            "updates_in_stage": self.updates_in_stage,
            "counted": self.counted,
            "recent": list(self.recent),
        }

    def load_state_dict(self, d: dict) -> None:
        if not 0 <= int(d["stage"]) < len(self.cfg.radii):
            raise ValueError(f"curriculum stage {d['stage']} outside 0..{len(self.cfg.radii) - 1}")
        self.stage = int(d["stage"])
        self.updates_in_stage = int(d["updates_in_stage"])
        self.counted = int(d["counted"])
        self.recent = deque((bool(x) for x in d["recent"]), maxlen=self.window)
