"""The commanded flight of docs/ground_station.md as an animation, drawn from its measured data:

    .venv/bin/python benchmarks/commanded_flight.py run docs/bench/commanded_flight.json   # flies it, ~40 s
    .venv/bin/python docs/ground_station_gif.py                                            # draws it, ~10 s

Reads docs/bench/commanded_flight.json (the goals, `goals_enu_m`) and the trace the benchmark wrote
beside it (commanded_flight_trace.csv: time, position ENU, phase, at 10 Hz of simulated time) and
writes docs/media/commanded_flight.gif: the top view (east, north) and the side view (east, up) with
the path flown so far coloured by phase, the goals marked (the current one in red), and a line with
the simulated time (the simulator's clock, as the JSON's event times) and the phase. `SPEED`
simulated seconds per second of GIF at `FPS` frames per second: one frame per `SPEED / FPS` s of
flight, the trace's last row at or before it. The same data give the same file, byte for byte (Agg
drawing, one shared palette; nothing from the clock or the machine goes in).
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np

from quadpilot.console import EXIT_BAD_FILE, EXIT_BAD_FLAG, Parser, UsageError, check_output_path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_JSON = ROOT / "docs" / "bench" / "commanded_flight.json"
DEFAULT_OUT = ROOT / "docs" / "media" / "commanded_flight.gif"
FPS = 10
SPEED = 3.0
"""Simulated seconds per GIF second: the ~37 s flight in ~12 s."""
SIZE_PX = (720, 340)
DPI = 100
NEED = ("t_s", "east_m", "north_m", "up_m", "phase")
PHASE_COLOURS = {
    "take-off": "tab:green",
    "hold": "tab:gray",
    "goto": "tab:orange",
    "mission": "tab:blue",
    "land": "tab:purple",
    "return": "tab:brown",
}
"""Colour of the path flown in each phase ("mission" covers every mission item); others: light grey."""
IDLE_COLOUR = "0.75"


def trace_csv(json_path: Path) -> Path:
    """Where benchmarks/commanded_flight.py writes the trace of `json_path` (the same rule)."""
    return json_path.with_name(f"{json_path.stem}_trace.csv")


def read_flight(json_path: Path, csv_path: Path) -> tuple[np.ndarray, np.ndarray, list[str], dict]:
    """(t (N,) s, positions (N, 3) ENU m, phases (N,), goals {name: (3,) or (K, 3)}). ValueError
    naming the file and what is wrong."""
    try:
        goals = json.loads(json_path.read_text(encoding="utf-8"))["goals_enu_m"]
        goals = {"takeoff": np.array(goals["takeoff"], float), "goto": np.array(goals["goto"], float)} | {
            "mission": np.array(goals["mission"], float).reshape(-1, 3)
        }
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{json_path}: cannot read it ({e})") from None
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{json_path}: expected goals_enu_m with takeoff, goto and mission in metres ({e})") from None
    try:
        with open(csv_path, newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise ValueError(f"{csv_path}: cannot read it ({e})") from None
    if not rows or any(c not in rows[0] for c in NEED):
        raise ValueError(f"{csv_path}: expected a CSV with columns {', '.join(NEED)} and at least one row")
    try:
        t = np.array([float(r["t_s"]) for r in rows])
        pos = np.array([[float(r["east_m"]), float(r["north_m"]), float(r["up_m"])] for r in rows])
    except (TypeError, ValueError) as e:
        raise ValueError(f"{csv_path}: t_s, east_m, north_m and up_m must be numbers ({e})") from None
    if not (np.isfinite(t).all() and np.isfinite(pos).all() and (np.diff(t) >= 0).all()):
        raise ValueError(f"{csv_path}: expected finite positions and non-decreasing t_s")
    return t, pos, [r["phase"] for r in rows], goals


def phase_colour(phase: str) -> str:
    return PHASE_COLOURS.get(phase.split(" ")[0], IDLE_COLOUR)


def current_goal(phase: str, goals: dict) -> np.ndarray | None:
    """The goal the phase flies to, or None (on the ground, holding, landing)."""
    if phase == "take-off":
        return goals["takeoff"]
    if phase == "goto":
        return goals["goto"]
    if phase.startswith("mission item "):
        k = int(phase.rsplit(" ", 1)[1]) - 1
        return goals["mission"][k] if 0 <= k < len(goals["mission"]) else None
    return None


def frame_rows(t: np.ndarray, fps: int = FPS, speed: float = SPEED) -> np.ndarray:
    """Row of the trace each frame shows: frame k is simulated time t[0] + k·speed/fps, the last row
    at or before it (quadpilot.viz.video's rule); floor((t[-1] − t[0])·fps/speed) + 1 frames."""
    from quadpilot.viz.video import frame_times

    tau = frame_times(float(t[-1] - t[0]), fps, speed)
    return np.clip(np.searchsorted(t - t[0], tau + 1e-9, side="right") - 1, 0, len(t) - 1)


def draw(t, pos, phases, goals, out: Path) -> int:
    """Write the GIF; returns its number of frames."""
    from matplotlib.collections import LineCollection

    from quadpilot.atomic_files import atomic_output
    from quadpilot.viz._mpl import new_figure
    from quadpilot.viz.video import gif_writer_class  # the project's shared-palette PillowWriter

    fig = new_figure(SIZE_PX[0] / DPI, SIZE_PX[1] / DPI, DPI)
    top = fig.add_axes((0.07, 0.12, 0.38, 0.66))
    side = fig.add_axes((0.56, 0.12, 0.41, 0.66))
    named = [("T", goals["takeoff"]), ("G", goals["goto"])]
    named += [(str(k + 1), g) for k, g in enumerate(goals["mission"])]
    every = np.concatenate([pos, [g for _, g in named], [[0.0, 0.0, 0.0]]])
    colours = [phase_colour(p) for p in phases]
    paths, dots, targets = [], [], []
    for ax, (i, j), (xl, yl) in ((top, (0, 1), ("east [m]", "north [m]")), (side, (0, 2), ("east [m]", "up [m]"))):
        lo, hi = every[:, [i, j]].min(axis=0) - 0.5, every[:, [i, j]].max(axis=0) + 0.5
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(min(lo[1], -0.2) if j == 2 else lo[1], hi[1])
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel(xl, fontsize=8, labelpad=1)
        ax.set_ylabel(yl, fontsize=8, labelpad=1)
        ax.tick_params(labelsize=7, length=2, pad=1)
        ax.grid(True, lw=0.3, alpha=0.5)
        if j == 2:
            ax.axhline(0.0, color="0.35", lw=1.0)  # the ground
        ax.plot(0.0, 0.0, marker="s", color="0.35", ms=5, ls="none")  # home
        at: dict[tuple[float, float], list[str]] = {}  # goals that fall on one point in this view share a label
        for name, g in named:
            at.setdefault((round(float(g[i]), 2), round(float(g[j]), 2)), []).append(name)
        for (x, y), names in at.items():
            ax.plot(x, y, marker="x", color="k", ms=6, mew=1.2, ls="none")
            ax.annotate(",".join(names), (x, y), xytext=(4, 3), textcoords="offset points", fontsize=7)
        path = LineCollection([], linewidths=1.6)
        ax.add_collection(path)
        paths.append(path)
        dots.append(ax.plot([], [], "o", color="k", ms=5)[0])
        targets.append(ax.plot([], [], marker="x", color="tab:red", ms=9, mew=2.2, ls="none")[0])
    top.set_title("top view", fontsize=8, pad=2)
    side.set_title("side view (from the south)", fontsize=8, pad=2)
    fig.text(0.07, 0.955, "quad-sitl, the shipped hover policy, commanded by MAVSDK", fontsize=8, color="0.3")
    fig.text(0.97, 0.955, f"×{SPEED:g} speed, ✕ goals, ■ home", fontsize=8, color="0.3", ha="right")
    line = fig.text(0.07, 0.875, "", fontsize=11, weight="bold", family="monospace")
    flown = [name for name in PHASE_COLOURS if any(phase_colour(p) == PHASE_COLOURS[name] for p in phases)]
    for k, name in enumerate(flown):  # a legend of the phases this flight has
        fig.text(0.56 + 0.08 * k, 0.875, name, fontsize=8, color=PHASE_COLOURS[name], weight="bold")

    rows = frame_rows(t)
    writer = gif_writer_class()(fps=FPS)
    with atomic_output(out) as tmp, writer.saving(fig, str(tmp), DPI):
        for k in rows:
            k = int(k)
            for path, dot, target, (i, j) in zip(paths, dots, targets, ((0, 1), (0, 2)), strict=True):
                xy = pos[: k + 1][:, [i, j]]
                path.set_segments(list(np.stack([xy[:-1], xy[1:]], axis=1)))
                path.set_color(colours[1 : k + 1])
                dot.set_data([pos[k, i]], [pos[k, j]])
                goal = current_goal(phases[k], goals)
                target.set_data([], []) if goal is None else target.set_data([goal[i]], [goal[j]])
            line.set_text(f"t {t[k]:5.1f} s   {phases[k]}")
            line.set_color(phase_colour(phases[k]) if phase_colour(phases[k]) != IDLE_COLOUR else "0.3")
            writer.grab_frame()
    return len(rows)


def main(argv: list[str] | None = None) -> int:
    p = Parser(description=__doc__.splitlines()[0])
    p.add_argument("--json", type=Path, default=DEFAULT_JSON, help="the benchmark's JSON (goals_enu_m)")
    p.add_argument("--csv", type=Path, default=None, help="its trace (default: JSON_STEM_trace.csv beside it)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="the GIF to write")
    try:
        a = p.parse_args(argv)
        if a.out.suffix.lower() != ".gif":
            raise UsageError(f"--out {a.out}: expected a .gif file")
        a.out.parent.mkdir(parents=True, exist_ok=True)
        check_output_path(a.out, "--out")
    except (UsageError, ValueError, OSError) as e:
        print(f"ground_station_gif: error: {e}", file=sys.stderr)
        return EXIT_BAD_FLAG
    csv_path = a.csv if a.csv is not None else trace_csv(a.json)
    try:
        t, pos, phases, goals = read_flight(a.json, csv_path)
    except ValueError as e:
        print(f"ground_station_gif: error: {e}", file=sys.stderr)
        return EXIT_BAD_FILE
    n = draw(t, pos, phases, goals, a.out)
    shown = a.out.resolve().relative_to(ROOT) if a.out.resolve().is_relative_to(ROOT) else a.out
    print(f"wrote {shown} ({n} frames at {FPS} fps, {a.out.stat().st_size:,} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
