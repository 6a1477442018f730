"""What one flight of the node recorded (`EpisodeLog`), and its judgement (`episode_summary`):
the record `autopilot.node.Node.fly` fills step by step, and the one success rule applied to it."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from quadpilot.core.mission import judge
from quadpilot.link import wire


@dataclass
class EpisodeLog:
    """What one flight recorded: ground truth per step and what the node did."""

    t: list = field(default_factory=list)
    states: list = field(default_factory=list)
    """Ground truth per simulator step (12-state ENU/FLU); a step whose state was dropped repeats the
    last valid one."""
    targets: list = field(default_factory=list)
    commands: list = field(default_factory=list)
    sources: list = field(default_factory=list)
    ticks: list = field(default_factory=list)
    """Per step: True where the policy (or the monitor's fallback) ran, False where the command was held."""
    latency_s: list = field(default_factory=list)
    """s from a step's HIL_SENSOR to its command handed to the socket (the send itself left out: `on_sensor`)."""
    wall: list = field(default_factory=list)
    """perf_counter() at each step's HIL_SENSOR: the loop's period and jitter."""
    replies: int = 0
    """HIL_ACTUATOR_CONTROLS sent in answer to a step, including blind ones before any valid state
    (not logged: nothing to log them against)."""
    estimates: list = field(default_factory=list)
    """(simulated time s, the node's estimated 12-state) of every step flown without its state."""
    state_lost_steps: int = 0
    """Steps answered without their state (HIL_SENSOR alone), on the estimate of `autopilot.state_loss`."""
    blind_replies: int = 0
    """Of `replies`, those flown blind (their step's state dropped), logged or not."""
    home: wire.Home | None = None
    """The geodetic origin flown with (`NodeConfig.home`, or the first valid position)."""
    mavlink_version: int = 2
    """The MAVLink version the node spoke to the simulator at the end of the flight."""
    dropped: Counter = field(default_factory=Counter)
    """Messages and states refused, by reason (see the module docstring)."""
    failsafe: str | None = None
    failsafe_latency_s: float | None = None
    wall_s: float = 0.0
    telemetry_sent: int = 0
    handovers: list = field(default_factory=list)
    """(simulated time s, "hand-over" | "hand-back" | "latched", why) of every change of who flies
    (`SafetyMonitor.transitions`), in order."""
    events: list = field(default_factory=list)
    """Commanded flights: (simulated time s, text) of every STATUSTEXT the commander sent."""
    commander: dict | None = None
    """Commanded flights: the commander's state at the end (armed, flown, landed state, mode, what
    the ground station sent and what of it was dropped)."""

    @property
    def steps(self) -> int:
        return len(self.commands)

    @property
    def step_s(self) -> float:
        """s, the simulator's step: the median interval between logged steps (NaN below two)."""
        return float(np.median(np.diff(self.t))) if len(self.t) > 1 else math.nan

    def ended_early(self, duration_s: float) -> str:
        """The one line of a flight that ended before `duration_s` on a failsafe. A simulator that
        closed the link stopped stepping first (a script's loop of fewer steps than the duration
        ends so): the line says how much of the duration it flew, and what to change."""
        line = f"the flight ended early after {self.replies:,} steps: failsafe: {self.failsafe}"
        if self.failsafe != "simulator closed the link" or not math.isfinite(self.step_s):
            return line
        flown = self.steps * self.step_s
        return (
            f"{line} after {flown:.2f} s of sim time, before --duration {duration_s:g} s: the simulator "
            f"stopped stepping first; run it for at least --duration, or give --duration {flown:.2f}"
        )


def episode_summary(log: EpisodeLog, control_period_s: float, task: str = "hover") -> dict:
    """Success and errors of one flight with the project's one definition (`core.mission.judge`,
    the same as the training evaluation's); a failsafe is never a success. The log holds one entry
    per simulator step: it is judged at the simulator's step as measured (`EpisodeLog.step_s`),
    `control_period_s` when fewer than two steps were flown. `dropped`: what the node refused, by
    reason (EpisodeLog.dropped)."""
    dt = log.step_s if math.isfinite(log.step_s) else control_period_s
    out = judge(task, np.asarray(log.states), np.asarray(log.targets), dt)
    out["success"] = bool(out["success"] and log.failsafe is None)
    out["dropped"] = dict(log.dropped)  # packets and states refused, by reason
    return out
