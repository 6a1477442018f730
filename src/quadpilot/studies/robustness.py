"""Robustness of hover controllers to the plant (domain randomisation).

Three measurements, each the same for learned policies and for the runtime's classical fallback
controller (`runtime.fallback.FallbackController`, which acts on the same observation):

- the grid: perturbed plants (mass, thrust constant k_f, wind; `core.randomization`), 100 hover
  episodes per cell from the hover bar's starts, judged by `core.mission`'s success definition;
  policies through `train.envs.evaluate.evaluate`, the fallback through `fly` (checked equal to
  `evaluate` for a policy by a test);
- the same grid through `quad-sitl` (`--mass-scale`, `--motor-scale`, `--wind`), for ONNX files;
- disturbance scenarios on the nominal plant, starting at rest on the target: a 1 N push for
  0.2 s, a step in wind 0 → 2 m/s, a 1 m offset; settling time (to within 5 cm, staying),
  overshoot, peak and steady position error.

Regenerate the tables of docs/robustness.md:

    python -m quadpilot.studies.robustness --policy nominal=models/hover/policy.pt \\
        --policy randomised=models/hover_dr/policy.pt --fallback --sitl --out docs/bench/robustness

Wind acts as in the SITL simulator: through linear drag, F = drag·(wind − v), with quad-sitl's
default drag coefficient when there is wind (`simulator.DEFAULT_WIND_DRAG`, 0.2 N·s/m).
"""

from __future__ import annotations

import dataclasses
import json
import math
import shlex
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from quadpilot.atomic_files import atomic_write
from quadpilot.console import BadFile, Parser, UsageError, docs_quick, quick, run_command
from quadpilot.core import dynamics
from quadpilot.core.mission import window_success, wrap_angle, yaw_errors
from quadpilot.core.observation import build_observation
from quadpilot.core.params import VehicleParams
from quadpilot.core.randomization import RandomizationConfig
from quadpilot.core.state import POS, YAW
from quadpilot.simulator import DEFAULT_WIND_DRAG
from quadpilot.train.envs import EnvConfig, QuadBatch

GRID_MASS = (0.85, 1.0, 1.15)
GRID_K_F = (0.92, 1.0, 1.08)
GRID_WIND = (0.0, 1.0)
QUICK_EPISODES = 4
"""In-process episodes per cell (and on the nominal plant) under QUADPILOT_DOCS_QUICK."""
QUICK_CELLS = ((1.0, 1.0, 0.0), (1.15, 1.0, 0.0), (1.15, 0.92, 0.0), (1.15, 0.92, 1.0))
"""The (mass, k_f, wind) cells QUADPILOT_DOCS_QUICK flies: those docs/robustness.md's text quotes."""
SETTLE_TOL_M = 0.05  # m, "settled": within 5 cm of the target and staying (the hover bar's tolerance)
SETTLE_FINAL_TOL_M = 0.01  # m, the classical settling time: within 1 cm of the final position


# --- controllers -----------------------------------------------------------------------------


class PolicyController:
    """A learned policy: raw observations (N, obs_dim) → actions in [−1, 1], mapped to rotor
    commands by the environment's map at the *nominal* hover command (what the policy believes)."""

    output = "action"

    def __init__(self, policy: Callable[[np.ndarray], np.ndarray], name: str = "policy") -> None:
        self.policy, self.name = policy, name

    def reset(self, n: int) -> None:
        pass

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.asarray(self.policy(obs), np.float32)


class FallbackBank:
    """One `runtime.fallback.FallbackController` per drone (each has an integrator and a held
    heading), tuned for the nominal vehicle; returns rotor commands in [0, 1]."""

    output = "command"

    def __init__(
        self, vehicle: VehicleParams, dt: float = dynamics.DT, name: str = "fallback", heading_frame: bool = False
    ) -> None:
        from quadpilot.runtime.fallback import FallbackController

        # heading_frame: fed version-2 observations (attitude relative to the commanded heading)
        self._make = lambda: FallbackController(vehicle, dt, heading_frame=heading_frame)
        self.name = name
        self.ctrls: list = []

    def reset(self, n: int) -> None:
        self.ctrls = [self._make() for _ in range(n)]

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.stack([c.act(o) for c, o in zip(self.ctrls, obs, strict=True)])


# --- the runner --------------------------------------------------------------------------------

Disturbance = Callable[[int], tuple[np.ndarray | None, np.ndarray | None]]
"""Step index k → (extra force (N, 3) N world, extra torque (N, 3) N·m body), either None."""


@dataclass
class Flight:
    """N drones flown side by side. states (T+1, N, 12) float64, the start first; crash_step (N,)
    the step at which each crashed (−1: never); mean_err (N,) mean position error over the
    success window (the env's float32 sums, as `evaluate` computes them); final_err (N,)."""

    states: np.ndarray
    target: np.ndarray
    crash_step: np.ndarray
    mean_err: np.ndarray
    final_err: np.ndarray
    ep_return: np.ndarray
    dt: float
    heading: np.ndarray | None = None
    """(N,) rad, each drone's commanded heading (None: its start yaw)."""

    @property
    def alive(self) -> np.ndarray:
        return self.crash_step < 0


def fly(
    controller,
    cfg: EnvConfig,
    n: int,
    seed: int = 12345,
    starts: np.ndarray | None = None,
    steps: int | None = None,
    disturbance: Disturbance | None = None,
) -> Flight:
    """Fly `controller` on `cfg`'s hover task for `steps` (default: the episode) with N drones.

    Start states and plants are drawn exactly as `evaluate(policy, cfg, n, seed)` draws them (one
    `QuadBatch.reset` with `default_rng(seed)`); `starts` (N, 12) replaces the start states.
    Each step: the controller sees the observation and `QuadBatch.step` advances the batch (the
    training environment's step, its observation, reward and crash rule) with the controller's
    output (actions through the nominal-hover map, or commands as they are) and `disturbance(k)`
    on top of the randomisation's external force. Crashed drones keep being stepped but count as
    crashed."""
    batch = QuadBatch(cfg, n)
    batch.reset(np.ones(n, bool), np.random.default_rng(seed))
    if starts is not None:
        batch.state[:] = np.asarray(starts, batch.dtype).reshape(n, dynamics.STATE_DIM)
        batch.heading[:] = wrap_angle(batch.state[:, YAW])  # the given starts hold their own heading
        build_observation(batch.state, batch.target, None, out=batch.obs, heading=batch.obs_heading)
    controller.reset(n)
    T = cfg.episode_steps if steps is None else steps
    window = min(T, cfg.success_steps)
    states = np.empty((T + 1, n, dynamics.STATE_DIM))
    states[0] = batch.state
    alive = np.ones(n, bool)
    crash_step = np.full(n, -1)
    err_sum = np.zeros(n)
    final_err = np.zeros(n)
    ep_return = np.zeros(n)
    commands = controller.output != "action"
    for k in range(T):
        out = np.asarray(controller(batch.obs.copy()), batch.dtype)
        force = torque = None
        if disturbance is not None:
            f2, t2 = disturbance(k)
            force = None if f2 is None else np.asarray(f2, batch.dtype)
            torque = None if t2 is None else np.asarray(t2, batch.dtype)
        _, reward, crash, _, err = batch.step(out, commands, force, torque)
        ep_return += np.where(alive, reward, 0.0)
        final_err = np.where(alive, err, final_err)
        newly = alive & crash
        crash_step[newly] = k + 1
        alive &= ~crash
        if k >= T - window:
            err_sum += err
        states[k + 1] = batch.state
    return Flight(
        states,
        batch.target.astype(np.float64),
        crash_step,
        err_sum / window,
        final_err,
        ep_return,
        cfg.dt,
        batch.heading.astype(np.float64),
    )


def summarise(flight: Flight, cfg: EnvConfig) -> dict:
    """The hover keys of `evaluate`'s result for a flight."""
    alive = flight.alive
    window = flight.states[-min(len(flight.states) - 1, cfg.success_steps) :]
    heading = flight.states[0, :, YAW] if flight.heading is None else flight.heading
    rate, head = yaw_errors(window, heading)
    success = window_success(alive, flight.mean_err, rate.mean(axis=0), head.mean(axis=0), cfg.success_tolerance)
    nan = float("nan")
    return {
        "episodes": int(alive.size),
        "success_rate": float(success.mean()),
        "crash_rate": float((~alive).mean()),
        "mean_error_last_window_m": float(flight.mean_err[alive].mean()) if alive.any() else nan,
        "max_error_last_window_m": float(flight.mean_err[alive].max()) if alive.any() else nan,
        "mean_final_distance_m": float(flight.final_err[alive].mean()) if alive.any() else nan,
    }


# --- the grid ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Cell:
    """One perturbed plant: mass and k_f scales, wind speed (m/s, towards +x/east, as
    `quad-sitl --wind W,0,0`)."""

    mass: float = 1.0
    k_f: float = 1.0
    wind: float = 0.0

    @property
    def label(self) -> str:
        return f"mass ×{self.mass:g}, k_f ×{self.k_f:g}, wind {self.wind:g} m/s"

    @property
    def plant(self) -> RandomizationConfig:
        drag = DEFAULT_WIND_DRAG if self.wind else None  # quad-sitl: drag only when there is wind
        return RandomizationConfig.fixed(
            mass=self.mass, k_f=self.k_f, wind=self.wind, wind_direction_deg=0.0, drag=drag, name=self.label
        )

    def sitl_flags(self) -> list[str]:
        flags = ["--mass-scale", f"{self.mass:g}", "--motor-scale", f"{self.k_f:g}"]
        return [*flags, "--wind", f"{self.wind:g},0,0"] if self.wind else flags


def grid(masses=GRID_MASS, k_fs=GRID_K_F, winds=GRID_WIND) -> list[Cell]:
    return [Cell(m, k, w) for w in winds for m in masses for k in k_fs]


def hover_config(vehicle: str | VehicleParams = "seed", dtype: str = "float32") -> EnvConfig:
    """The hover evaluation environment (the training defaults), without randomisation."""
    from quadpilot.train.envs import make_config

    return make_config("hover", vehicle=vehicle, dtype=dtype)


def evaluate_grid(controller, cfg: EnvConfig, cells: list[Cell], episodes: int = 100, seed: int = 12345) -> list[dict]:
    """Success and position error of `controller` on each cell, `episodes` episodes each, the
    same starts in every cell. Policies go through `train.envs.evaluate.evaluate`, the rest through
    `fly`."""
    from quadpilot.train.envs.evaluate import evaluate

    out = []
    for cell in cells:
        c = dataclasses.replace(cfg, randomization=cell.plant)
        if isinstance(controller, PolicyController):
            r = evaluate(controller.policy, c, episodes=episodes, seed=seed)
        else:
            r = summarise(fly(controller, c, episodes, seed), c)
        out.append({"mass": cell.mass, "k_f": cell.k_f, "wind": cell.wind, **_grid_keys(r)})
    return out


def _grid_keys(r: dict) -> dict:
    keys = ("episodes", "success_rate", "crash_rate", "mean_error_last_window_m", "max_error_last_window_m")
    return {k: r[k] for k in keys}


# --- quad-sitl ---------------------------------------------------------------------------------


def sitl_grid(onnx: Path, cells: list[Cell], episodes: int = 10, seed: int = 0) -> list[dict]:
    """Fly `onnx` with quad-sitl (lockstep, numpy backend) on each cell; its summary per cell."""
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, cell in enumerate(cells):
            path = Path(tmp) / f"cell{i}.json"
            cmd = [sys.executable, "-m", "quadpilot.sitl", str(onnx), "--episodes", str(episodes), "--seed", str(seed)]
            cmd += ["--gcs", "none", "--json", str(path), *cell.sitl_flags()]
            done = subprocess.run(cmd, capture_output=True, text=True)
            if done.returncode != 0 or not path.exists():
                raise RuntimeError(f"quad-sitl failed on {cell.label} (exit {done.returncode}): {done.stderr[-2000:]}")
            s = json.loads(path.read_text())
            eps = s["per_episode"]
            alive = [e for e in eps if not e["crashed"]]
            out.append(
                {
                    "mass": cell.mass,
                    "k_f": cell.k_f,
                    "wind": cell.wind,
                    "episodes": s["episodes"],
                    "success_rate": s["success_rate"],
                    "crash_rate": s["crashes"] / max(s["episodes"], 1),
                    "mean_error_last_window_m": float(np.mean([e["mean_error_last_window_m"] for e in alive]))
                    if alive
                    else float("nan"),
                    "max_error_last_window_m": float(np.max([e["mean_error_last_window_m"] for e in alive]))
                    if alive
                    else float("nan"),
                    "steps_per_s": s["steps_per_s"],
                    "fallback_steps": s["fallback_steps"],
                    "command": shlex.join(
                        ["quad-sitl", *cmd[3 : -len(cell.sitl_flags()) - 1], "OUT.json", *cell.sitl_flags()]
                    ),
                }
            )
    return out


# --- disturbance scenarios -----------------------------------------------------------------------


@dataclass(frozen=True)
class Scenario:
    """A disturbance flown from rest on the target (or from an offset), nominal plant."""

    name: str
    description: str
    kind: str
    """push (a force for `duration_s`), wind (a step in wind speed, through `drag`), offset (a start
    `magnitude` m away)."""
    magnitude: float
    """N (push), m/s (wind) or m (offset)."""
    seconds: float = 6.0
    onset_s: float = 1.0
    duration_s: float = 0.2
    drag: float | None = None
    """N·s/m, the plant's drag coefficient (wind needs one; None: the preset's)."""

    @property
    def direction(self) -> np.ndarray:
        return np.array([1.0, 0.0, 0.0])  # world +x; the drones' headings are random


SCENARIOS = (
    Scenario("push", "1 N along +x for 0.2 s at t = 1 s (0.30 m/s imparted)", "push", 1.0),
    Scenario(
        "wind step",
        f"wind 0 → 2 m/s along +x at t = 1 s ({DEFAULT_WIND_DRAG:g} N·s/m drag: {2 * DEFAULT_WIND_DRAG:g} N)",
        "wind",
        2.0,
        seconds=8.0,
        drag=DEFAULT_WIND_DRAG,
    ),
    Scenario("1 m offset", "start at rest 1 m from the target along x", "offset", 1.0, onset_s=0.0),
)


def run_scenario(controller, sc: Scenario, cfg: EnvConfig, n: int = 20, seed: int = 0) -> dict:
    """Fly `sc` with N drones, each with its own heading (uniform, the same for every controller
    with the same seed). Returns per-drone and summary metrics (see `scenario_metrics`)."""
    rng = np.random.default_rng(seed)
    starts = np.zeros((n, dynamics.STATE_DIM))
    starts[:, POS] = cfg.home
    starts[:, YAW] = rng.uniform(-np.pi, np.pi, n)
    d = sc.direction
    if sc.kind == "offset":
        starts[:, POS] += sc.magnitude * d
    plant = RandomizationConfig.fixed(drag=sc.drag, name="nominal" if sc.drag is None else "nominal with drag")
    c = dataclasses.replace(cfg, randomization=plant, episode_steps=round(sc.seconds / cfg.dt))
    k0 = round(sc.onset_s / cfg.dt)
    k1 = k0 + max(1, round(sc.duration_s / cfg.dt))
    if sc.kind == "push":
        force = np.tile(sc.magnitude * d, (n, 1))
        disturbance = lambda k: (force, None) if k0 <= k < k1 else (None, None)  # noqa: E731
    elif sc.kind == "wind":
        force = np.tile(sc.drag * sc.magnitude * d, (n, 1))  # drag·wind; −drag·v is in the plant
        disturbance = lambda k: (force, None) if k >= k0 else (None, None)  # noqa: E731
    else:
        disturbance = None
    flight = fly(controller, c, n, seed=seed, starts=starts, disturbance=disturbance)
    out = scenario_metrics(flight, np.asarray(cfg.home, float), d, k0)
    out.update(scenario=sc.name, description=sc.description, controller=controller.name, drones=n)
    return out


def _settling(err: np.ndarray, tol: float, dt: float) -> np.ndarray:
    """(N,) s after which err (T', N) stays within tol: 0 if it never leaves, NaN if it ends out."""
    out = np.full(err.shape[1], np.nan)
    for i in range(err.shape[1]):
        outside = np.flatnonzero(err[:, i] > tol)
        if outside.size == 0:
            out[i] = 0.0
        elif outside[-1] < err.shape[0] - 1:
            out[i] = (outside[-1] + 1) * dt
    return out


def scenario_metrics(flight: Flight, target: np.ndarray, direction: np.ndarray, k0: int) -> dict:
    """From the onset step k0 on, per drone: peak error; settling time, the time after onset
    after which the error stays within 5 cm of the target (0 if it never leaves; NaN if it ends
    outside), and the classical one, within 1 cm of the final position (the mean over the last
    second); overshoot, how far past the target the vehicle goes along `direction` after its peak
    excursion; steady error, the mean error over the last 2 s. Means over the drones (settling:
    mean over those that settled, and the worst), crashes counted."""
    p = flight.states[k0:, :, POS] - target  # (T', N, 3)
    err = np.linalg.norm(p, axis=2)
    along = p @ direction
    n = err.shape[1]
    settle = _settling(err, SETTLE_TOL_M, flight.dt)
    final = p[-max(1, round(1.0 / flight.dt)) :].mean(axis=0)
    settle_final = _settling(np.linalg.norm(p - final, axis=2), SETTLE_FINAL_TOL_M, flight.dt)
    overshoot = np.zeros(n)
    for i in range(n):
        peak_k = int(np.argmax(along[:, i]))
        overshoot[i] = max(0.0, -float(along[peak_k:, i].min()))
    window = max(1, round(2.0 / flight.dt))
    steady = err[-window:].mean(axis=0)
    settled = np.isfinite(settle)
    nan = float("nan")
    return {
        "peak_error_m": float(err.max(axis=0).mean()),
        "settling_time_s": float(settle[settled].mean()) if settled.any() else nan,
        "settling_time_max_s": float(settle[settled].max()) if settled.any() else nan,
        "settled": int(settled.sum()),
        "settling_final_1cm_s": float(np.nanmean(settle_final)) if np.isfinite(settle_final).any() else nan,
        "settling_final_1cm_max_s": float(np.nanmax(settle_final)) if np.isfinite(settle_final).any() else nan,
        "overshoot_m": float(overshoot.mean()),
        "overshoot_max_m": float(overshoot.max()),
        "steady_error_m": float(steady.mean()),
        "crashes": int((~flight.alive).sum()),
    }


# --- report ------------------------------------------------------------------------------------


def _pct(x: float | None) -> str:  # None: no episode to take it over (`evaluate`, every one crashed)
    return "–" if x is None or not math.isfinite(x) else f"{100 * x:.0f} %"


def _cm(x: float | None) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{100 * x:.1f}"


def grid_table(results: dict[str, list[dict]]) -> str:
    """Markdown: one row per cell, success and mean error over the last 2 s per controller."""
    names = list(results)
    head = "| mass | k_f | wind (m/s) | " + " | ".join(f"{n}: success, error (cm)" for n in names) + " |"
    lines = [head, "|---:|---:|---:|" + "---:|" * len(names)]
    for i, row in enumerate(results[names[0]]):
        cells = []
        for n in names:
            r = results[n][i]
            cells.append(f"{_pct(r['success_rate'])}, {_cm(r['mean_error_last_window_m'])}")
        lines.append(f"| ×{row['mass']:g} | ×{row['k_f']:g} | {row['wind']:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def scenario_table(rows: list[dict]) -> str:
    lines = [
        "| scenario | controller | peak error (cm) | settling to 5 cm of target, mean / worst (s) "
        "| settling to 1 cm of final position, mean / worst (s) | overshoot, mean / worst (cm) "
        "| steady error (cm) | crashes |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if r["settled"] == r["drones"]:
            settle = f"{r['settling_time_s']:.2f} / {r['settling_time_max_s']:.2f}"
        else:
            settle = f"{r['drones'] - r['settled']} of {r['drones']} never"
            if r["settled"]:
                settle += f" (others {r['settling_time_s']:.2f} / {r['settling_time_max_s']:.2f})"
        lines.append(
            f"| {r['scenario']} | {r['controller']} | {_cm(r['peak_error_m'])} | {settle} | "
            f"{r['settling_final_1cm_s']:.2f} / {r['settling_final_1cm_max_s']:.2f} | "
            f"{_cm(r['overshoot_m'])} / {_cm(r['overshoot_max_m'])} | {_cm(r['steady_error_m'])} | {r['crashes']} |"
        )
    return "\n".join(lines)


def write_model_eval(eval_path: Path, name: str, report: dict, policy) -> dict:
    """Add this harness's results for policy `name` to a shipped model's eval.json (models/README):
    `nominal` (100 episodes on the nominal plant, `evaluate`), `grid_in_process` and `sitl`."""
    from quadpilot.train.envs.evaluate import evaluate

    data = json.loads(Path(eval_path).read_text())
    nominal = dataclasses.replace(policy.env_config, randomization=None)
    data["nominal"] = evaluate(policy, nominal, episodes=quick(100, QUICK_EPISODES))
    data["grid_in_process"] = report["grid"][name]
    if name in report.get("sitl", {}):
        data["sitl"] = {"backend": "numpy", "lockstep": True, "grid": report["sitl"][name]}
    data["robustness_command"] = report["command"]
    atomic_write(eval_path, lambda f: f.write((json.dumps(data, indent=2, default=float) + "\n").encode()))
    return data


def _machine() -> dict:
    import os
    import platform

    from quadpilot.train.runs.loop import cpu_model

    return {"cpu": cpu_model(), "cores": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__}


def main(argv: list[str] | None = None) -> int:
    p = Parser(prog="python -m quadpilot.studies.robustness", description=__doc__.split("\n\n")[0], allow_abbrev=False)
    p.add_argument(
        "--policy",
        action="append",
        default=[],
        metavar="NAME=PATH",
        help="A hover policy.pt (the .onnx beside it, if any, flies in quad-sitl); repeat for several.",
    )
    p.add_argument("--fallback", action="store_true", help="Include the runtime's classical fallback controller.")
    p.add_argument("--sitl", action="store_true", help="Fly the grid through quad-sitl too (the policies' ONNX files).")
    p.add_argument("--episodes", type=int, default=100, help="In-process episodes per cell. Default: 100.")
    p.add_argument("--sitl-episodes", type=int, default=10, help="quad-sitl episodes per cell. Default: 10.")
    p.add_argument("--drones", type=int, default=20, help="Headings per disturbance scenario. Default: 20.")
    p.add_argument("--out", type=Path, required=True, help="Directory for robustness.json and robustness.md.")
    p.add_argument(
        "--write-eval",
        action="append",
        default=[],
        metavar="NAME=EVAL_JSON",
        help="Add policy NAME's results to a shipped model's eval.json (keys nominal, grid_in_process, sitl).",
    )
    return run_command("python -m quadpilot.studies.robustness", lambda: _study(p.parse_args(argv)))


def _study(args) -> int:
    from quadpilot.train.algorithms import load_policy
    from quadpilot.train.runs.checkpoint import CheckpointError

    controllers = []
    onnx = {}
    for spec in args.policy:
        name, _, path = spec.partition("=")
        if not path:
            raise UsageError(f"--policy wants NAME=PATH, got {spec!r}")
        try:
            controllers.append(PolicyController(load_policy(path), name))
        except CheckpointError as e:
            raise BadFile(f"--policy {name}: {e}") from None
        onnx[name] = Path(path).with_suffix(".onnx")
    cfg = hover_config()
    if args.fallback:
        controllers.append(FallbackBank(cfg.params, cfg.dt, heading_frame=cfg.layout.heading_frame))
    if not controllers:
        raise UsageError("nothing to measure: give --policy and/or --fallback")
    named = {c.name for c in controllers if isinstance(c, PolicyController)}
    for spec in args.write_eval:  # checked before the work, not after it
        if spec.partition("=")[0] not in named:
            raise UsageError(f"--write-eval {spec!r}: no --policy named {spec.partition('=')[0]!r}")
    args.out.mkdir(parents=True, exist_ok=True)
    cells = grid()
    if docs_quick():  # console.docs_quick: the cells docs/robustness.md quotes, a few episodes and drones
        cells = [c for c in cells if (c.mass, c.k_f, c.wind) in QUICK_CELLS]
    args.drones = quick(args.drones, 2)
    args.episodes, args.sitl_episodes = quick(args.episodes, QUICK_EPISODES), quick(args.sitl_episodes, 1)
    report: dict = {
        "machine": _machine(),
        "command": " ".join(["python -m quadpilot.studies.robustness", *sys.argv[1:]]),
    }
    t0 = time.perf_counter()
    report["grid"] = {c.name: evaluate_grid(c, cfg, cells, args.episodes) for c in controllers}
    report["grid_s"] = time.perf_counter() - t0
    print(f"grid done in {report['grid_s']:.0f} s", file=sys.stderr, flush=True)
    scfg = hover_config(dtype="float64")
    report["scenarios"] = [run_scenario(c, sc, scfg, args.drones) for sc in SCENARIOS for c in controllers]
    if args.sitl:
        t1 = time.perf_counter()
        missing = [f"{n} ({path})" for n, path in onnx.items() if not path.exists()]
        if missing:
            print(f"quad-sitl: no ONNX file for {', '.join(missing)}; skipped (quad-export it)", file=sys.stderr)
        report["sitl"] = {n: sitl_grid(path, cells, args.sitl_episodes) for n, path in onnx.items() if path.exists()}
        report["sitl_s"] = time.perf_counter() - t1
    text = json.dumps(report, indent=1, default=float) + "\n"
    atomic_write(args.out / "robustness.json", lambda f: f.write(text.encode()))
    md = [f"## In-process grid ({args.episodes} episodes per cell)", "", grid_table(report["grid"]), ""]
    md += ["## Disturbance scenarios (nominal plant)", "", scenario_table(report["scenarios"]), ""]
    if args.sitl and report["sitl"]:
        md += [f"## quad-sitl grid ({args.sitl_episodes} episodes per cell)", "", grid_table(report["sitl"]), ""]
    atomic_write(args.out / "robustness.md", lambda f: f.write("\n".join(md).encode()))
    policies = {c.name: c.policy for c in controllers if isinstance(c, PolicyController)}
    for spec in args.write_eval:
        name, _, path = spec.partition("=")
        write_model_eval(Path(path), name, report, policies[name])
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
