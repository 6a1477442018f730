"""What an episode asks of the vehicle, and when it succeeded: one definition for the training
environments' evaluation and for SITL, so that "success" means the same everywhere.

Tasks (the course brief and the ENPM 667 project; the training environments' defaults, `train.envs.make_config`):
- hover: start within `HOVER_START_RADIUS` of home (0, 0, 2) m, hold home.
- waypoint: start at home (0, 0, 3) m, reach a target uniform in a ball of `WAYPOINT_RADIUS`
  (the last curriculum stage, the course brief's 0.5 → 1 → 2 m) around it, and hold it.
- circle: follow a point moving counter-clockwise round a circle of `CIRCLE_RADIUS` at
  `CIRCLE_SPEED` about home (0, 0, 2) m, starting within `CIRCLE_START_RADIUS` of its start point.

Success: hover and waypoint, the episode does not crash and the mean distance to the target over
its last `SUCCESS_WINDOW_S` is at most `SUCCESS_TOLERANCE_M`. Circle: no crash, and over the
second half of a two-lap flight (the first lap is the approach) the RMS radial error is at most
`CIRCLE_RADIAL_TOLERANCE_M` and the mean absolute tangential-speed error at most
`CIRCLE_SPEED_TOLERANCE_MPS` (the ENPM 667 project's two circle errors, `core.reward.circle_errors`).

Every task also holds its heading (`holds_heading`, the yaw rule): over the same last
`SUCCESS_WINDOW_S`, the mean |yaw rate| is at most `YAW_RATE_TOLERANCE_RAD_S` and the mean heading
error at most `HEADING_TOLERANCE_DEG`. The yaw rate is the body rate r (about body z, what the gyro
reads and PX4's rate controller holds; in a hover it is the heading's rate ψ̇ to within the cosine of
the tilt). The heading error is the yaw angle minus the commanded heading, wrapped to [−180°, 180°);
the commanded heading is the heading at the start of the episode unless a caller gives one. A
vehicle that holds its position while spinning, or that settles facing elsewhere, has not held
still. `window_success` is the one rule: `judge` (SITL, the node, quad-sitl) and the training
environments' `QuadBatch.success` and `train.envs.evaluate` (eval.json) all call it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .reward import RewardConfig, circle_errors, crashed
from .start import sample_ball, sample_start_states
from .state import POS, YAW, R

TASKS = ("hover", "waypoint", "circle")
SUCCESS_TOLERANCE_M = 0.05
SUCCESS_WINDOW_S = 2.0
# The yaw rule (module docstring). 0.2 rad/s is 11.5°/s, a turn in half a minute: slower than any
# deliberate yaw, faster than the drift a gyro bias leaves. 10° is what a camera or a sensor pointed
# by the vehicle tolerates, and far above a held heading's error (a fraction of a degree).
YAW_RATE_TOLERANCE_RAD_S = 0.2
HEADING_TOLERANCE_DEG = 10.0
CIRCLE_RADIAL_TOLERANCE_M = 0.05
CIRCLE_SPEED_TOLERANCE_MPS = 0.1
HOME = {"hover": (0.0, 0.0, 2.0), "waypoint": (0.0, 0.0, 3.0), "circle": (0.0, 0.0, 2.0)}
HOVER_START_RADIUS = 1.0
WAYPOINT_RADIUS = 2.0
CIRCLE_RADIUS = 1.0
CIRCLE_SPEED = 1.0
CIRCLE_START_RADIUS = 0.5
START_RADIUS = {"hover": HOVER_START_RADIUS, "waypoint": 0.0, "circle": CIRCLE_START_RADIUS}


def circle_lap_s(radius: float = CIRCLE_RADIUS, speed: float = CIRCLE_SPEED) -> float:
    return 2.0 * math.pi * radius / speed


def circle_summary(episodes: list[dict]) -> dict:
    """The second lap's figures (`judge`'s) averaged over the episodes that flew it: a shorter
    --duration or a crash leaves a second half that is part of the first lap, or of no lap."""
    laps = [e for e in episodes if e["two_laps_flown"]]
    out = {"circle_lap_s": circle_lap_s(), "circle_second_laps_not_flown": len(episodes) - len(laps)}
    if laps:
        out["radial_rms_m"] = float(np.mean([e["radial_rms_m"] for e in laps]))
        out["speed_error_mps"] = float(np.mean([e["speed_error_mps"] for e in laps]))
    return out


def circle_line(s: dict) -> str:
    """quad-sitl's line of a `circle_summary`: the figures, or that no second lap was flown."""
    short = s["circle_second_laps_not_flown"]
    if "radial_rms_m" not in s:
        two = 2 * s["circle_lap_s"]
        return f"  circle (second lap)     not flown: the episodes ended before two laps ({two:.1f} s)"
    return (
        f"  circle (second lap)     radial RMS {s['radial_rms_m'] * 100:.2f} cm, "
        f"speed error {s['speed_error_mps'] * 100:.2f} cm/s"
        + (f" ({short} other episodes ended before their second lap)" if short else "")
    )


def default_duration_s(task: str) -> float:
    """s of flight an episode of `task` is judged on: 5 s (training's episode), two laps for circle."""
    return 2.0 * circle_lap_s() if task == "circle" else 5.0


@dataclass(frozen=True)
class Mission:
    """One episode's task: where it starts and where the target is at control step k."""

    task: str
    home: tuple[float, float, float]
    start_centre: tuple[float, float, float]
    start_radius: float
    target: tuple[float, float, float]
    """hover: home; waypoint: the drawn target; circle: the target point at k = 0."""
    phase: float = 0.0
    """circle: angle of the target point at k = 0, rad."""
    radius: float = CIRCLE_RADIUS
    speed: float = CIRCLE_SPEED
    dt: float = 0.01

    def target_at(self, k: int) -> tuple[np.ndarray, np.ndarray | None]:
        """(position (3,), velocity (3,) or None) of the target after k control steps, world ENU.
        Circle: the angle advances by speed/radius·dt per step, as in the training environment."""
        if self.task != "circle":
            return np.asarray(self.target, np.float64), None
        ang = self.phase + self.speed / self.radius * self.dt * k
        c, s = math.cos(ang), math.sin(ang)
        h = self.home
        pos = np.array([h[0] + self.radius * c, h[1] + self.radius * s, h[2]])
        return pos, np.array([-self.speed * s, self.speed * c, 0.0])

    def start_state(self, rng: np.random.Generator, vel: float, tilt_deg: float, rate: float = 0.0) -> np.ndarray:
        """(12,) start state drawn around `start_centre` (core.start)."""
        centre = np.asarray(self.start_centre, np.float64)[None]
        return sample_start_states(rng, centre, self.start_radius, vel, tilt_deg, rate)[0]


def plan_episode(
    task: str,
    seed: int,
    episode: int,
    dt: float = 0.01,
    start_radius: float | None = None,
    waypoint_radius: float = WAYPOINT_RADIUS,
) -> Mission:
    """Episode `episode` of a run seeded `seed`: the same draw on every side that calls it (the
    simulator for the start, the autopilot for the target), from np.random.default_rng([seed,
    episode, 1]), a stream apart from the start state's own."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; expected one of {TASKS}")
    rng = np.random.default_rng([seed, episode, 1])
    home = HOME[task]
    radius = START_RADIUS[task] if start_radius is None else start_radius
    if task == "waypoint":
        target = tuple(float(v) for v in np.asarray(home) + sample_ball(rng, 1, waypoint_radius)[0])
        return Mission(task, home, home, radius, target, dt=dt)
    if task == "circle":
        phase = float(rng.uniform(-math.pi, math.pi))
        m = Mission(task, home, home, radius, home, phase=phase, dt=dt)
        start = tuple(float(v) for v in m.target_at(0)[0])
        return Mission(task, home, start, radius, start, phase=phase, dt=dt)
    return Mission(task, home, home, radius, home, dt=dt)


def wrap_angle(a):
    """Angle(s) in rad wrapped to [−π, π)."""
    return np.remainder(np.asarray(a, np.float64) + math.pi, 2.0 * math.pi) - math.pi


def yaw_errors(states: np.ndarray, heading) -> tuple[np.ndarray, np.ndarray]:
    """(|yaw rate| rad/s, |heading error| rad) per state: states (..., 12) with yaw in [−π, π] (as
    `core.dynamics` keeps it), heading the commanded heading in [−π, π] (`wrap_angle` it first; a
    scalar or an array broadcasting against states[..., 8]). See the module docstring.

    With both angles in [−π, π], d = |ψ − ψ_cmd| ≤ 2π and the wrapped error is min(d, 2π − d): the
    training environments compute this every step, so it avoids a modulo."""
    states = np.asarray(states)
    d = np.abs(states[..., YAW] - heading)
    return np.abs(states[..., R]), np.minimum(d, 2.0 * math.pi - d)


def holds_heading(mean_abs_yaw_rate, mean_abs_heading_error):
    """The yaw rule on window means (rad/s, rad): bool, or a bool array for arrays."""
    return (np.asarray(mean_abs_yaw_rate) <= YAW_RATE_TOLERANCE_RAD_S) & (
        np.asarray(mean_abs_heading_error) <= math.radians(HEADING_TOLERANCE_DEG)
    )


def window_success(
    ended_well, mean_error_m, mean_abs_yaw_rate, mean_abs_heading_error, tolerance_m: float = SUCCESS_TOLERANCE_M
):
    """The one success rule of hover and waypoint (and of circle's held heading): the episode ended
    well (no crash, long enough), the mean position error over the window is within `tolerance_m`
    and the vehicle held its heading (`holds_heading`). Scalars or (N,) arrays of window means."""
    return (
        np.asarray(ended_well, bool)
        & (np.asarray(mean_error_m) <= tolerance_m)
        & holds_heading(mean_abs_yaw_rate, mean_abs_heading_error)
    )


def judge(
    task: str,
    states: np.ndarray,
    targets: np.ndarray,
    dt: float,
    home=None,
    reward: RewardConfig | None = None,
    window_s: float = SUCCESS_WINDOW_S,
    tolerance_m: float = SUCCESS_TOLERANCE_M,
    heading: float | None = None,
) -> dict:
    """Success and errors of one flown episode: states (N, 12) and the targets (N, 3) the policy
    was given at each step. The flight must have lasted at least the judged window. `heading`: the
    commanded heading in rad (ENU yaw, 0 = east); None: the first state's yaw."""
    states = np.asarray(states, np.float64)
    if states.ndim != 2 or states.shape[0] == 0:
        return {"steps": 0, "success": False, "crashed": False, "rms_error_m": math.nan, "final_distance_m": math.nan}
    heading = float(wrap_angle(states[0, YAW] if heading is None else heading))
    err = states[:, POS] - np.broadcast_to(np.asarray(targets, np.float64), states[:, POS].shape)
    dist = np.linalg.norm(err, axis=1)
    crash = bool(crashed(states, err, reward or RewardConfig()).any())
    k = max(1, round(window_s / dt))
    window = float(dist[-k:].mean())
    rate, head = yaw_errors(states[-k:], heading)
    rate, head = float(rate.mean()), float(head.mean())
    held = bool(holds_heading(rate, head))
    out = {
        "steps": len(states),
        "crashed": crash,
        "rms_error_m": float(np.sqrt(np.mean(dist**2))),
        "mean_error_last_window_m": window,
        "final_distance_m": float(dist[-1]),
        "mean_abs_yaw_rate_last_window_rad_s": rate,
        "mean_heading_error_last_window_deg": math.degrees(head),
        "heading_deg": math.degrees(heading),
    }
    if task == "circle":
        half = states[len(states) // 2 :]
        e_r, e_v = circle_errors(
            half, np.asarray(HOME["circle"] if home is None else home), CIRCLE_RADIUS, CIRCLE_SPEED
        )
        rms, spd = float(np.sqrt(np.mean(e_r**2))), float(np.mean(np.abs(e_v)))
        long_enough = len(states) * dt >= 2.0 * circle_lap_s() - dt
        out.update(radial_rms_m=rms, speed_error_mps=spd, two_laps_flown=long_enough)
        out["success"] = bool(
            not crash
            and long_enough
            and rms <= CIRCLE_RADIAL_TOLERANCE_M
            and spd <= CIRCLE_SPEED_TOLERANCE_MPS
            and held
        )
    else:
        out["success"] = bool(window_success(not crash and len(states) >= k, window, rate, head, tolerance_m))
    return out
