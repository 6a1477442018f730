"""One recorded flight, as the plots and the video read it: `FlightTrace`.

NumPy only. A trace comes from quad-sitl's `EpisodeLog` (`FlightTrace.from_episode_log`), from an
in-process evaluation (`FlightTrace.from_arrays`) or from a file written by `to_npz`.

Frames and units are the project's (docs/architecture.md): world ENU (z up), body FLU, ZYX Euler angles in
rad, SI units; the state columns are `core.dynamics.STATE_NAMES`. Motor commands are ω/ω_max in
[0, 1] in PX4's quad-X order (`core.dynamics.MOTOR_NAMES`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from quadpilot.atomic_files import atomic_output
from quadpilot.core.dynamics import NUM_MOTORS, POS, STATE_DIM

NPZ_FORMAT = 1
"""Version of the `to_npz` layout; `from_npz` refuses other versions by name."""
POLICY = "policy"
"""The source of a step the policy commanded; every other source is shaded in the plots."""


@dataclass(eq=False)
class FlightTrace:
    """One flight, N control steps. Validated and copied to float64 on construction."""

    t: np.ndarray
    """(N,) s, simulation time of each step, non-decreasing. Plots show time since t[0]."""
    states: np.ndarray
    """(N, 12) core state: x, y, z (m, world ENU, z up), vx, vy, vz (m/s), roll, pitch, yaw (rad,
    ZYX Euler, body FLU), p, q, r (rad/s). Non-finite rows are allowed (they leave gaps); a trace
    without a single finite position is refused."""
    commands: np.ndarray
    """(N, 4) motor commands ω/ω_max in [0, 1], PX4 quad-X order: 0 front-right, 1 rear-left,
    2 front-left, 3 rear-right."""
    target: np.ndarray
    """(3,) a fixed target, or (N, 3) a moving one (circle, waypoints), m, world ENU."""
    sources: list[str] | None = None
    """Per step, who commanded: "policy", "fallback", "blind", ... None: the policy throughout."""
    label: str = ""
    """Legend text; empty: "episode k"."""
    failsafe_t: float | None = None
    """s, on the clock of `t`: when the failsafe latched, if it did."""

    def __post_init__(self) -> None:
        self.t = _as_float(self.t, "t")
        n = self.t.shape[0] if self.t.ndim == 1 else -1
        if self.t.ndim != 1 or n < 1:
            raise ValueError(f"FlightTrace: t must have shape (N,) with N ≥ 1, got {self.t.shape}")
        if not np.isfinite(self.t).all():
            raise ValueError("FlightTrace: t must be finite everywhere")
        if n > 1 and np.any(np.diff(self.t) < 0):
            k = int(np.argmax(np.diff(self.t) < 0))
            raise ValueError(
                f"FlightTrace: t must be non-decreasing; t[{k + 1}] = {self.t[k + 1]} < t[{k}] = {self.t[k]}"
            )

        self.states = _as_float(self.states, "states")
        if self.states.shape != (n, STATE_DIM):
            raise ValueError(
                f"FlightTrace: states must have shape ({n}, {STATE_DIM}) to match t, got {self.states.shape}"
            )
        if not np.isfinite(self.states[:, POS]).all(axis=1).any():
            raise ValueError("FlightTrace: states has no step with a finite position (all NaN/Inf); nothing to draw")

        self.commands = _as_float(self.commands, "commands")
        if self.commands.shape != (n, NUM_MOTORS):
            raise ValueError(
                f"FlightTrace: commands must have shape ({n}, {NUM_MOTORS}) to match t, got {self.commands.shape}"
            )
        if not np.isfinite(self.commands).any():
            raise ValueError("FlightTrace: commands has no finite value (all NaN/Inf)")

        self.target = _as_float(self.target, "target")
        if self.target.shape not in ((3,), (n, 3)):
            raise ValueError(f"FlightTrace: target must have shape (3,) or ({n}, 3), got {self.target.shape}")
        if not np.isfinite(self.target).all():
            raise ValueError("FlightTrace: target must be finite everywhere")

        if self.sources is not None:
            if isinstance(self.sources, str) or not isinstance(self.sources, Sequence | np.ndarray):
                raise ValueError(f"FlightTrace: sources must be a list of N = {n} strings or None")
            sources = [str(s) for s in self.sources]
            if len(sources) != n:
                raise ValueError(f"FlightTrace: sources has {len(sources)} entries, t has {n}")
            self.sources = sources

        if not isinstance(self.label, str):
            raise ValueError(f"FlightTrace: label must be a str, got {type(self.label).__name__}")
        if self.failsafe_t is not None:
            try:
                self.failsafe_t = float(self.failsafe_t)
            except (TypeError, ValueError):
                raise ValueError(f"FlightTrace: failsafe_t must be a number or None, got {self.failsafe_t!r}") from None
            if not math.isfinite(self.failsafe_t):
                raise ValueError(f"FlightTrace: failsafe_t must be finite or None, got {self.failsafe_t}")

    # -- construction -------------------------------------------------------------------------

    @classmethod
    def from_arrays(
        cls,
        t,
        states,
        commands,
        target,
        sources: Sequence[str] | None = None,
        label: str = "",
        failsafe_t: float | None = None,
    ) -> FlightTrace:
        """The same as the constructor; takes anything `np.asarray` takes (lists of rows too)."""
        return cls(t, states, commands, target, sources, label, failsafe_t)

    @classmethod
    def from_episode_log(cls, log, target, label: str = "") -> FlightTrace:
        """From the runtime node's `EpisodeLog` (duck-typed: `t`, `states`, `commands`, `sources`,
        `failsafe`; nothing of `quadpilot.runtime` is imported). The node latches a failsafe and
        ends the episode, so a failsafe is placed at the last recorded step."""
        if not len(log.t):
            raise ValueError("FlightTrace: the episode log recorded no steps; nothing to draw")
        failsafe_t = float(log.t[-1]) if getattr(log, "failsafe", None) else None
        sources = list(log.sources) if getattr(log, "sources", None) else None
        return cls(
            np.asarray(log.t), np.asarray(log.states), np.asarray(log.commands), target, sources, label, failsafe_t
        )

    # -- derived values -----------------------------------------------------------------------

    @property
    def n(self) -> int:
        """Number of steps."""
        return self.t.shape[0]

    @property
    def time(self) -> np.ndarray:
        """(N,) s since the first step: what the plots put on their time axes."""
        return self.t - self.t[0]

    @property
    def duration(self) -> float:
        """s from the first step to the last."""
        return float(self.t[-1] - self.t[0])

    @property
    def moving_target(self) -> bool:
        """True when the target is given per step."""
        return self.target.ndim == 2

    @property
    def target_path(self) -> np.ndarray:
        """(N, 3) the target at every step (a fixed target repeated)."""
        return self.target if self.moving_target else np.broadcast_to(self.target, (self.n, 3))

    @property
    def position(self) -> np.ndarray:
        """(N, 3) m, world ENU."""
        return self.states[:, POS]

    @property
    def error(self) -> np.ndarray:
        """(N,) m, ‖p − target‖ per step (NaN where the state is not finite)."""
        return np.linalg.norm(self.position - self.target_path, axis=1)

    @property
    def source_list(self) -> list[str]:
        """Per-step sources with None expanded to "policy"."""
        return list(self.sources) if self.sources is not None else [POLICY] * self.n

    def non_policy_spans(self) -> list[tuple[float, float, str]]:
        """Contiguous runs where the source is not "policy": (start, end, source), time since t[0].
        A run ends where the next step starts (or at the last step plus one step length), so a
        single-step run still has a width."""
        if self.sources is None:
            return []
        time = self.time
        step = float(np.median(np.diff(time))) if self.n > 1 else 0.01
        spans: list[tuple[float, float, str]] = []
        k = 0
        while k < self.n:
            src = self.sources[k]
            j = k
            while j + 1 < self.n and self.sources[j + 1] == src:
                j += 1
            if src != POLICY:
                end = time[j + 1] if j + 1 < self.n else time[j] + step
                spans.append((float(time[k]), float(end), src))
            k = j + 1
        return spans

    @property
    def failsafe_time(self) -> float | None:
        """s since t[0] of the failsafe, or None."""
        return None if self.failsafe_t is None else self.failsafe_t - float(self.t[0])

    # -- files --------------------------------------------------------------------------------

    def to_npz(self, path: str | os.PathLike) -> Path:
        """Write the trace to `path` exactly (no ".npz" appended), atomically, as plain arrays
        (readable with `np.load(..., allow_pickle=False)`). Returns the path."""
        path = Path(path)
        arrays = {
            "format": np.asarray(NPZ_FORMAT),
            "t": self.t,
            "states": self.states,
            "commands": self.commands,
            "target": self.target,
            "has_sources": np.asarray(self.sources is not None),
            "sources": np.asarray(self.sources if self.sources is not None else [], dtype=np.str_),
            "label": np.asarray(self.label, dtype=np.str_),
            "failsafe_t": np.asarray(np.nan if self.failsafe_t is None else self.failsafe_t),
        }
        with atomic_output(path) as tmp, open(tmp, "xb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        return path

    @classmethod
    def from_npz(cls, path: str | os.PathLike) -> FlightTrace:
        """Read a file written by `to_npz`; ValueError naming what is missing or wrong."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except (OSError, ValueError) as e:
            raise ValueError(f"{path}: not a readable FlightTrace .npz file ({e})") from e
        need = {"format", "t", "states", "commands", "target", "has_sources", "sources", "label", "failsafe_t"}
        missing = sorted(need - set(data))
        if missing:
            raise ValueError(f"{path}: not a FlightTrace file, missing arrays {missing}")
        if int(data["format"]) != NPZ_FORMAT:
            raise ValueError(f"{path}: FlightTrace format {int(data['format'])}, this version reads {NPZ_FORMAT}")
        failsafe_t = float(data["failsafe_t"])
        try:
            return cls(
                data["t"],
                data["states"],
                data["commands"],
                data["target"],
                [str(s) for s in data["sources"]] if bool(data["has_sources"]) else None,
                str(data["label"]),
                None if math.isnan(failsafe_t) else failsafe_t,
            )
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from e


def _as_float(a, name: str) -> np.ndarray:
    try:
        return np.array(a, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as e:
        raise ValueError(f"FlightTrace: {name} must be numeric, got {type(a).__name__} ({e})") from None
