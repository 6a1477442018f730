"""Flights that measure how a controller moves, beside the hover rule: a step and a figure-eight.

Both start at rest at home (hover's (0, 0, 2) m, level, rotors at hover speed) and hand the
controller a target that moves: `target_at(k)` gives the position and velocity of the target after k
control steps, world ENU, the same interface as `core.mission.Mission`. A policy that observes the
target's velocity gets it, and RAPTOR's observation takes it as PX4 mc_raptor's does (velocity
minus setpoint velocity). A hover-layout policy, trained on a target at rest, is flown in the moving
target's frame (`autopilot.node`): it observes v − v_target where it observed v, which is exact for
a target at constant velocity (the dynamics do not change with a constant-velocity frame, drag
aside) and leaves the target's acceleration as the error that remains. Without it a hover policy
trails the figure-eight by tens of centimetres.

- `Step`: the target jumps `distance` metres east at k = 0 and stays there. Measured: the overshoot
  (how far past the target the vehicle went along the step, metres), the rise time (10 % to 90 % of
  the step) and the settling time (from the step until the distance to the target stays within
  `SETTLE_BAND_M` for good; 5 cm, the hover rule's tolerance, 5 % of the 1 m step).
- `FigureEight`: PX4 mc_raptor's own figure-eight, the Lissajous curve of
  mc_raptor/trajectories/lissajous.hpp (x = A sin θ, y = B sin 2θ about home, the speed ramped up
  linearly over `ramp_s`; mc_raptor holds yaw 0, here the heading the flight starts with), with
  A = 2 m and B = 1 m (mc_raptor's defaults are 1 m and 0.5 m; twice the size keeps the
  accelerations of the 4 m/s flight within the thrust of the set's heaviest airframe: 8 m/s² across,
  4 m/s² along). `speed` is the target's peak speed (at the centre crossing). Measured over one lap
  after the ramp: the RMS and the largest distance to the target.

NumPy only: the simulator's node and the benchmarks call it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .mission import HOME
from .state import POS

SETTLE_BAND_M = 0.05
"""m: the step has settled when the distance to the target stays within this (the hover rule's 5 cm)."""
STEP_DISTANCE_M = 1.0
STEP_DURATION_S = 5.0
EIGHT_A_M = 2.0
EIGHT_B_M = 1.0
MAX_STEP_M = 100.0
SPEEDS_MPS = (0.1, 20.0)
"""The figure-eight's peak speeds flown (mc_raptor's documentation shows 12 m/s on real vehicles); at
0.1 m/s one lap takes three minutes."""
EIGHT_RAMP_S = 3.0
"""s over which the figure-eight's speed ramps up from rest (mc_raptor lissajous.hpp's ramp_duration)."""


@dataclass(frozen=True)
class Step:
    """A target `distance` metres east of home from the first step on."""

    distance: float = STEP_DISTANCE_M
    dt: float = 0.01
    home: tuple[float, float, float] = HOME["hover"]

    name = "step"

    @property
    def duration_s(self) -> float:
        return STEP_DURATION_S

    def target_at(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        h = self.home
        return np.array([h[0] + self.distance, h[1], h[2]]), np.zeros(3)

    def measure(self, states: np.ndarray, dt: float) -> dict:
        """Overshoot (m and % of the step), rise time and settling time (s; NaN when never) of one
        flight: states (N, 12), state k at k·dt, state 0 the start (at rest at home)."""
        p = np.asarray(states, np.float64)[:, POS]
        if p.shape[0] == 0:
            return {"overshoot_m": math.nan, "overshoot_pct": math.nan, "rise_s": math.nan, "settling_s": math.nan}
        start, goal = p[0], np.array(self.target_at(0)[0])
        axis = (goal - start) / np.linalg.norm(goal - start)
        along = (p - start) @ axis  # progress along the step, m
        span = float((goal - start) @ axis)
        over = max(0.0, float(along.max()) - span)
        dist = np.linalg.norm(p - goal, axis=1)
        outside = np.flatnonzero(dist > SETTLE_BAND_M)
        if outside.size == 0:
            settling = 0.0
        elif outside[-1] == len(dist) - 1:
            settling = math.nan  # still outside the band when the flight ended
        else:
            settling = float(outside[-1] + 1) * dt
        lo, hi = np.flatnonzero(along >= 0.1 * span), np.flatnonzero(along >= 0.9 * span)
        rise = float(hi[0] - lo[0]) * dt if lo.size and hi.size else math.nan
        return {"overshoot_m": over, "overshoot_pct": 100.0 * over / span, "rise_s": rise, "settling_s": settling}


@dataclass(frozen=True)
class FigureEight:
    """mc_raptor's figure-eight about home at peak speed `speed` m/s (module docstring)."""

    speed: float
    dt: float = 0.01
    home: tuple[float, float, float] = HOME["hover"]
    a: float = EIGHT_A_M
    b: float = EIGHT_B_M
    ramp_s: float = EIGHT_RAMP_S

    name = "figure8"

    def __post_init__(self) -> None:
        if not (SPEEDS_MPS[0] <= self.speed <= SPEEDS_MPS[1]):  # (NaN fails both)
            raise ValueError(f"figure-eight speed {self.speed!r}: expected {SPEEDS_MPS[0]:g} to {SPEEDS_MPS[1]:g} m/s")

    @property
    def rate(self) -> float:
        """rad/s of the curve's parameter θ after the ramp: the peak speed is rate·√(A² + 4B²), at θ = 0."""
        return self.speed / math.hypot(self.a, 2.0 * self.b)

    @property
    def lap_s(self) -> float:
        return 2.0 * math.pi / self.rate

    @property
    def duration_s(self) -> float:
        """The ramp, then one lap: the lap is what is measured."""
        return self.ramp_s + self.lap_s

    def theta(self, t: float) -> tuple[float, float]:
        """(θ, dθ/dt) at time t: the rate ramps linearly from 0 over ramp_s, then stays."""
        w, r = self.rate, self.ramp_s
        if t < r:
            return 0.5 * w * t * t / r, w * t / r
        return w * (0.5 * r + t - r), w

    def target_at(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        th, dth = self.theta(k * self.dt)
        h = self.home
        pos = np.array([h[0] + self.a * math.sin(th), h[1] + self.b * math.sin(2.0 * th), h[2]])
        vel = np.array([self.a * math.cos(th) * dth, 2.0 * self.b * math.cos(2.0 * th) * dth, 0.0])
        return pos, vel

    def lap_flown(self, steps: int, dt: float) -> bool:
        """Whether a flight of `steps` steps of `dt` s lasted the ramp and the whole lap after it
        (one step short allowed, as `core.mission.judge` allows the circle's two laps)."""
        return steps * dt >= self.duration_s - dt

    def measure(self, states: np.ndarray, targets: np.ndarray, dt: float) -> dict:
        """RMS and largest distance to the target over the lap after the ramp (m): states (N, 12) and
        the targets (N, 3) given at each step."""
        p = np.asarray(states, np.float64)[:, POS]
        k0 = round(self.ramp_s / dt)
        if p.shape[0] <= k0:
            return {"tracking_rms_m": math.nan, "tracking_max_m": math.nan}
        d = np.linalg.norm(p[k0:] - np.asarray(targets, np.float64)[k0:], axis=1)
        return {"tracking_rms_m": float(np.sqrt(np.mean(d**2))), "tracking_max_m": float(d.max())}


def parse_maneuver(text: str, dt: float = 0.01) -> Step | FigureEight:
    """`step`, `step:D` (metres) or `figure8:V` (peak m/s), as quad-sitl's --maneuver takes it."""
    name, _, arg = text.partition(":")
    try:
        if name == "step":
            d = float(arg) if arg else STEP_DISTANCE_M
            if not (0.0 < d <= MAX_STEP_M):
                raise ValueError
            return Step(d, dt)
        if name == "figure8" and arg:
            return FigureEight(float(arg), dt)
    except ValueError:
        pass
    raise ValueError(
        f"maneuver {text!r}: expected step, step:METRES (up to {MAX_STEP_M:g}) or figure8:M/S "
        f"({SPEEDS_MPS[0]:g} to {SPEEDS_MPS[1]:g}, e.g. figure8:2)"
    )


def summarise(maneuver: Step | FigureEight, flights: list[tuple[np.ndarray, np.ndarray, float]]) -> dict:
    """What `maneuver` measures of each flight (states (N, 12), the targets given (N, 3), the step
    in s), and the means over the flights that measured it: a step that never settled has no
    settling time and is counted in `not_settled`."""
    if isinstance(maneuver, Step):
        per = [maneuver.measure(states, dt) for states, _, dt in flights]
        measured = per
    else:  # the lap's figures only of the flights that flew it: part of a lap is not "the lap"
        per = [
            {
                **maneuver.measure(states, targets, dt),
                "flown_s": len(states) * dt,
                "lap_flown": maneuver.lap_flown(len(states), dt),
            }
            for states, targets, dt in flights
        ]
        measured = [e for e in per if e["lap_flown"]]
    out: dict = {"maneuver": {"name": maneuver.name, **dataclasses.asdict(maneuver)}, "maneuver_per_episode": per}
    keys = (
        ("overshoot_m", "overshoot_pct", "rise_s", "settling_s")
        if isinstance(maneuver, Step)
        else ("tracking_rms_m", "tracking_max_m")
    )
    for key in keys:  # NaN where nothing was flown (interrupted in the first flight)
        finite = [e[key] for e in measured if math.isfinite(e[key])]
        out[key] = float(np.mean(finite)) if finite else math.nan
    if isinstance(maneuver, Step):
        out["not_settled"] = sum(1 for e in per if not math.isfinite(e["settling_s"]))
    else:
        out["laps_not_flown"] = len(per) - len(measured)
    return out


def summary_line(s: dict) -> str:
    """One line of a `summarise` result, as quad-sitl prints it."""
    if s["maneuver"]["name"] == "step":
        settle = f"{s['settling_s']:.2f} s" if math.isfinite(s["settling_s"]) else "never"
        return (
            f"  step {s['maneuver']['distance']:g} m          overshoot {s['overshoot_m'] * 100:.1f} cm "
            f"({s['overshoot_pct']:.1f} %), rise {s['rise_s']:.2f} s, settling {settle}"
            + (f" ({s['not_settled']} never settled)" if s["not_settled"] else "")
        )
    head = f"  figure-eight {s['maneuver']['speed']:g} m/s  "
    short = s.get("laps_not_flown", 0)
    if short and short == len(s["maneuver_per_episode"]):
        m = s["maneuver"]
        ramp, lap = m["ramp_s"], 2.0 * math.pi * math.hypot(m["a"], 2.0 * m["b"]) / m["speed"]
        flown = max(e["flown_s"] for e in s["maneuver_per_episode"])
        return (
            head + f"lap not flown: {flown:.1f} s flown, the ramp and the lap take {ramp + lap:.1f} s "
            f"({ramp:g} s + {lap:.1f} s; --duration)"
        )
    return (
        head + f"tracking RMS {s['tracking_rms_m'] * 100:.1f} cm, "
        f"largest {s['tracking_max_m'] * 100:.1f} cm (the lap after the ramp)"
        + (f"; {short} of {len(s['maneuver_per_episode'])} flights ended before their lap did" if short else "")
    )
