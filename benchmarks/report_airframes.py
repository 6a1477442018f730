"""The tables and the plot of docs/raptor.md from benchmarks/airframes.py's JSON:

    python benchmarks/report_airframes.py docs/bench/airframes.json                       # the tables
    python benchmarks/report_airframes.py docs/bench/airframes.json --plot docs/img/airframes.png

Tables: `holding` (our simulator: hover, wind, the impulse and the wrong-file flights: success of
the episodes and the mean error over the last 2 s), `moving` (our simulator: the 1 m step's
overshoot and settling time, the figure-eight's tracking error), `rotorpy` (RotorPy's PX4 simulator,
one flight each, from its ground truth), `rotorpy-holding` (RotorPy: the hover, the wind, the impulse and the
wrong-file flights), `training` (ours and tuned: the wall time from the vehicle file to a checked policy.onnx;
the generalist: the export for the file, and its one training run). Controllers: raptor, ours and,
where flown, tuned (the generalist trained on with the file) and the generalist. A cell that
quad-sitl refused, or that RotorPy's harness could not finish, says so."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

TUNED_FROM = "tuned_from_generalist_training"
"""The JSON's record of the generalist `tuned` was trained on from, while `generalist_training` is
another one (a generalist made again after `tuned` was; airframes.py's `_keep_tuneds_generalist`)."""
HOLDING = ("hover", "wind", "impulse", "mass+30%", "mass-30%", "thrust+20%", "thrust-20%")
EIGHTS = ("figure8 1 m/s", "figure8 2 m/s", "figure8 4 m/s")
CONTROLLERS = ("raptor", "ours", "tuned", "generalist")


def _cm(v) -> str:
    return "–" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{100 * v:.1f} cm"


def cell(r: dict) -> str:
    if "refused" in r:
        return "refused"
    crash = f", {r['crashes']} crashed" if r.get("crashes") else ""
    return f"{100 * r['success_rate']:.0f} % · {_cm(r.get('mean_error_last_2s_m'))}{crash}"


def step_cell(r: dict, episodes: int | None = None) -> str:
    if "refused" in r or "failed" in r:
        return "refused" if "refused" in r else "not flown"
    settle = r.get("settling_s")
    s = "never" if settle is None or not math.isfinite(settle) else f"{settle:.2f} s"
    never = r.get("not_settled")
    tail = (
        f" ({never} of {episodes} never)" if never and episodes and settle is not None and math.isfinite(settle) else ""
    )
    return f"{r['overshoot_pct']:.1f} % · {s}{tail}"


def eight_cell(r: dict) -> str:
    if "refused" in r or "failed" in r:
        return "refused" if "refused" in r else "not flown"
    crash = f", {r['crashes']} crashed" if r.get("crashes") else ""
    return f"{_cm(r.get('tracking_rms_m'))}{crash}"


def _rows(data: dict):
    for name, rows in data["airframes"].items():
        for controller in CONTROLLERS:
            if controller in rows:
                yield name, controller, rows


def holding(data: dict) -> str:
    flights = [f for f in HOLDING if f in data["flights"]]
    lines = ["| airframe | controller | " + " | ".join(flights) + " |", "|---|---|" + "---|" * len(flights)]
    for name, c, rows in _rows(data):
        cells = [cell(rows[c][f]) if f in rows[c] else "–" for f in flights]
        lines.append(f"| {name} | {c} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def moving(data: dict) -> str:
    eights = [f for f in EIGHTS if f in data["flights"]]
    head = "| airframe | controller | step: overshoot · settling | " + " | ".join(eights) + " |"
    lines = [head, "|---|---|---|" + "---:|" * len(eights)]
    for name, c, rows in _rows(data):
        r = rows[c]
        cells = [step_cell(r["step"], data["episodes"]) if "step" in r else "–"]
        cells += [eight_cell(r[f]) if f in r else "–" for f in eights]
        lines.append(f"| {name} | {c} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def rotorpy(data: dict) -> str:
    lines = [
        "| airframe | controller | hover to 0.95 m | step: overshoot · settling | "
        + " | ".join(EIGHTS)
        + " | missed steps |",
        "|---|---|---:|---|" + "---:|" * len(EIGHTS) + "---:|",
    ]
    for name, rows in data["airframes"].items():
        side = rows.get("rotorpy")
        for c in [c for c in CONTROLLERS if c in side] if side else ():
            r = side[c]
            hover = r.get("hover", {})
            h = "not flown" if "failed" in hover else _cm(hover.get("mean_error_last_2s_m"))
            missed = sum(f.get("missed_steps", 0) for f in r.values())
            cells = [
                h,
                step_cell(r["step"]) if "step" in r else "–",
                *(eight_cell(r[f]) if f in r else "–" for f in EIGHTS),
            ]
            lines.append(f"| {name} | {c} | " + " | ".join(cells) + f" | {missed} |")
    return "\n".join(lines)


BEFORE_LAG_FIX = "airframes_before_lag_fix.json"
"""Beside the JSON: the RotorPy flights (and the hover in our simulator) before the motor lag's
thrust became the step's mean of k_f·ω² (see docs/raptor.md)."""


LAG_FIX_SHOWN = ("ours",)
"""The lag-fix table's controllers: the per-airframe policies, trained again from their files after the
correction. The generalist that flew before and after it has since been replaced by one trained from
scratch on the corrected model, so its rows now would compare two policies, not two models."""


def lag_fix(data: dict, before: dict) -> str:
    """RotorPy, our per-airframe policies (`LAG_FIX_SHOWN`) on each vehicle file: before the correction
    → after it."""
    lines = [
        "| airframe | controller | hover to 0.95 m | step overshoot | figure8 1 m/s | figure8 2 m/s |",
        "|---|---|---:|---:|---:|---:|",
    ]

    def pair(f, r0, r1, key, fmt):
        values = []
        for r in (r0, r1):
            v = (r or {}).get(f, {}).get(key)
            values.append("–" if v is None else fmt(v))
        return " → ".join(values)

    for name, rows in data["airframes"].items():
        side = rows.get("rotorpy") or {}
        old = before["airframes"].get(name, {}).get("rotorpy") or {}
        for c in LAG_FIX_SHOWN:
            if c not in side:
                continue
            r0, r1 = old.get(c), side[c]
            cells = [
                pair("hover", r0, r1, "mean_error_last_2s_m", _cm),
                pair("step", r0, r1, "overshoot_pct", lambda v: f"{v:.0f} %"),
                *(pair(f, r0, r1, "tracking_rms_m", _cm) for f in EIGHTS[:2]),
            ]
            lines.append(f"| {name} | {c} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


WRONG_FILE = ("mass+30%", "mass-30%", "thrust+20%", "thrust-20%")


DISTURBED = ("wind", "impulse")
ROTORPY_HOLDING = ("hover", *DISTURBED, *WRONG_FILE)
"""The rotorpy-holding table's flights: each to the same point, with a disturbance or a wrong file."""


def rotorpy_holding(data: dict) -> str:
    """RotorPy: the hover, the disturbances and the wrong-file flights (the plant scaled, the file as
    it is), one each."""
    lines = [
        "| airframe | controller | hover to 0.95 m | " + " | ".join(ROTORPY_HOLDING[1:]) + " |",
        "|---|---|" + "---:|" * len(ROTORPY_HOLDING),
    ]
    for name, rows in data["airframes"].items():
        side = rows.get("rotorpy") or {}
        for c in [c for c in CONTROLLERS if c in side]:
            if not any(f in side[c] for f in ROTORPY_HOLDING[1:]):
                continue
            cells = []
            for f in ROTORPY_HOLDING:
                r = side[c].get(f)
                if r is None or "failed" in r:
                    cells.append("–" if r is None else "not flown")
                else:
                    cells.append(f"{'✓' if r['success'] else '✗'} {_cm(r['mean_error_last_2s_m'])}")
            lines.append(f"| {name} | {c} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def training(data: dict) -> str:
    lines = [
        "| airframe | controller | file → checked policy.onnx | training | export and parity | its evaluation "
        "| load at start |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for name, rows in data["airframes"].items():
        for c, t in (("ours", rows.get("ours_training")), ("tuned", rows.get("tuned_training"))):
            if t:
                lines.append(
                    f"| {name} | {c} | {t['file_to_policy_s']:.0f} s | {t['train_s']:.0f} s | {t['export_s']:.0f} s | "
                    f"{100 * t['eval_success_rate']:.0f} % · {_cm(t['eval_mean_final_distance_m'])} | "
                    f"{t['load_1min_before']:.1f} |"
                )
        g = rows.get("generalist_export")
        if g:
            lines.append(f"| {name} | generalist | {g['file_to_policy_s']:.0f} s (the export) | – | – | – | – |")
    earlier = "`tuned` was trained on from an earlier generalist, trained once"
    for key, who in (("generalist_training", "The generalist, trained once"), (TUNED_FROM, earlier)):
        g = data.get(key)
        if not g:
            continue
        first = g.get("init_from")
        trained = f"\n{who}: {_run_text(g)}"
        if first and "command" in first:  # trained, then trained on from that policy
            trained = f"\n{who}: {_run_text(first)}, then on from that policy: {_run_text(g)}"
        lines.append(
            f"{trained}; its evaluation over drawn airframes: {100 * g['eval_success_rate']:.0f} % · "
            f"{_cm(g['eval_mean_final_distance_m'])}."
        )
    return "\n".join(lines)


def _run_text(r: dict) -> str:
    """A training run's record (`airframes.training_record`) as the training table's note says it."""
    return f"`{_command(r['command'])}`, {r['steps']:,} steps in {r['train_s']:.0f} s"


def _command(command: str) -> str:
    """A recorded quad-train command without the machine's own paths: --out and the file named by
    --init-from shown by their last folder."""
    words = command.split()
    for i, w in enumerate(words[:-1]):
        if w in ("--out", "--init-from"):
            path = Path(words[i + 1])
            words[i + 1] = f"runs/{path.name}" if w == "--out" else f"runs/{path.parent.name}/{path.name}"
    return " ".join(words)


def plot(data: dict, path: Path) -> None:
    """Hover error and figure-eight tracking error per airframe, RAPTOR beside ours, in both simulators."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = list(data["airframes"])
    panels = [
        (
            "our simulator: hover, error over the last 2 s",
            lambda rows, c: rows[c].get("hover", {}).get("mean_error_last_2s_m"),
        ),
        (
            "our simulator: figure-eight 2 m/s, tracking RMS",
            lambda rows, c: rows[c].get("figure8 2 m/s", {}).get("tracking_rms_m"),
        ),
        (
            "RotorPy: hover to 0.95 m, error over the last 2 s",
            lambda rows, c: rows.get("rotorpy", {}).get(c, {}).get("hover", {}).get("mean_error_last_2s_m"),
        ),
        (
            "RotorPy: figure-eight 2 m/s, tracking RMS",
            lambda rows, c: rows.get("rotorpy", {}).get(c, {}).get("figure8 2 m/s", {}).get("tracking_rms_m"),
        ),
    ]
    fig, axes = plt.subplots(len(panels), 1, figsize=(10, 3.0 * len(panels)), sharex=True)
    x = np.arange(len(names))
    for ax, (title, get) in zip(axes, panels, strict=True):
        colors = {"raptor": "tab:red", "ours": "tab:blue", "tuned": "tab:purple", "generalist": "tab:green"}
        for j, (c, color) in enumerate(colors.items()):
            vals = [_get(get, data["airframes"][n], c) for n in names]
            cm = [100 * v if v is not None and math.isfinite(v) else np.nan for v in vals]
            ax.bar(x + (j - 1.5) * 0.21, cm, 0.21, label=c, color=color)
        ax.axhline(5.0, color="k", lw=0.8, ls="--")  # the hover rule's 5 cm
        ax.set_yscale("log")
        ax.set_ylabel("cm")
        ax.set_title(title, fontsize=10)
        ax.legend(loc="upper left", fontsize=8)
    axes[-1].set_xticks(x, names, rotation=30, ha="right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _get(get, rows: dict, c: str):
    """A figure of controller `c` (None where it was not flown)."""
    try:
        return get(rows, c)
    except KeyError:
        return None


def _runs(rows: dict, data: dict) -> list[dict]:
    """When an airframe's cells in our simulator were flown: its run (or the file's), the flights
    added later, the generalist's export, tuned's training and the flights of both added later."""
    runs = [rows.get("run", data), *rows.get("flights_run", {}).values()]
    runs += [rows[k]["run"] for k in ("generalist_export", "tuned_training") if k in rows]
    return [*runs, *rows.get("generalist_flights_run", {}).values(), *rows.get("tuned_flights_run", {}).values()]


def _flew(key: str, controllers: tuple, flights: tuple) -> bool:
    """Whether a RotorPy run (its key: "run", a whole run of the default flights, which hold the hover
    and the maneuvers, or "run CONTROLLER: FLIGHT, FLIGHT" or "run CONTROLLER: the flights with missed
    steps, again") flew cells of these controllers and flights."""
    if key == "run":
        return True
    controller, _, what = key.removeprefix("run ").partition(": ")
    return controller in controllers and (what.startswith("the flights") or bool(set(what.split(", ")) & set(flights)))


def _before_commit(path: Path) -> str:
    return json.loads(path.read_text()).get("commit_of_the_table", "?") if path.is_file() else "?"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("json", type=Path)
    tables = {
        "holding": holding,
        "moving": moving,
        "rotorpy": rotorpy,
        "rotorpy-holding": rotorpy_holding,
        "training": training,
        "lag-fix": None,  # with the flights before the correction, beside the JSON
    }
    p.add_argument("--table", choices=sorted(tables), default="holding")
    p.add_argument("--plot", type=Path, help="Draw the plot there instead of printing a table.")
    args = p.parse_args(argv)
    data = json.loads(args.json.read_text())
    before = args.json.with_name(BEFORE_LAG_FIX)
    tables["lag-fix"] = lambda d: lag_fix(d, json.loads(before.read_text()))
    if args.plot is not None:
        plot(data, args.plot)
        return 0
    print(tables[args.table](data))
    runs = [run for rows in data["airframes"].values() for run in _runs(rows, data)]
    if args.table.startswith("rotorpy") or args.table == "lag-fix":
        sides = [rows.get("rotorpy", {}) for rows in data["airframes"].values()]
        shown = LAG_FIX_SHOWN if args.table == "lag-fix" else CONTROLLERS
        flights = ROTORPY_HOLDING if args.table == "rotorpy-holding" else ("hover", "step", *EIGHTS)
        runs = [r for side in sides for k, r in side.items() if _flew(k, shown, flights)]
    commits = ", ".join(sorted({r["commit"][:10] for r in runs}))
    loads = [r["load_1min_before"] for r in runs]
    per = {
        "rotorpy": "one flight per cell",
        "lag-fix": f"one flight per cell, before → after (before: commit {_before_commit(before)})",
        "rotorpy-holding": "one flight per cell (✓: the hover rule's 5 cm over the last 2 s)",
        "holding": f"{data['episodes']} episodes per cell (success · mean error over the last 2 s)",
    }.get(args.table, f"{data['episodes']} episodes per cell")
    print(
        f"\n{per}; {data['machine']['cpus']} CPUs, load {min(loads):.1f} to {max(loads):.1f} at the starts; "
        f"commit {commits}."
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
