"""quad-compare's report: the sweeps `quad-compare run` wrote, read back (`load_sweep`), drawn
(`plot_sweep`: evaluation success and training return of both algorithms against environment steps
and against training wall-clock, the mean over seeds with the min–max band) and written into the
document between its markers (`cmd_report`): the commands, the results, and the matched-settings
table (`matched_settings`). Text outside the markers is kept, so the analysis written around the
tables survives a regeneration.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os
import platform
import shlex
from pathlib import Path

import numpy as np

from quadpilot.console import UsageError

ALGOS = ("ppo", "sb3")
LABELS = {"ppo": "ours (PPO from scratch)", "sb3": "Stable-Baselines3 PPO"}
COLORS = {"ppo": "C0", "sb3": "C3"}
BEGIN = "<!-- BEGIN quad-compare report: generated, edits here are overwritten -->"
END = "<!-- END quad-compare report -->"
SWEEP = "sweep.json"


# --- reading runs ---------------------------------------------------------------------------


@dataclasses.dataclass
class Run:
    algo: str
    seed: int
    dir: Path
    config: dict
    metrics: dict[str, np.ndarray]
    eval: dict


def load_sweep(directory: Path) -> tuple[dict, list[Run]]:
    from quadpilot.train.runs.runlog import read_metrics

    sweep_path = directory / SWEEP
    if not sweep_path.exists():
        raise UsageError(f"{directory} holds no {SWEEP}; make it with quad-compare run --out {directory}")
    sweep = json.loads(sweep_path.read_text())
    runs = []
    for d in sorted(p for p in directory.iterdir() if p.is_dir()):
        if not (d / "eval.json").exists():
            continue
        config = json.loads((d / "config.json").read_text())
        runs.append(
            Run(
                config.get("algo", "ppo"),
                int(config["ppo"]["seed"]),
                d,
                config,
                read_metrics(d / "metrics.csv"),
                json.loads((d / "eval.json").read_text()),
            )
        )
    if not runs:
        raise UsageError(f"{directory} holds no finished run (no */eval.json)")
    return sweep, runs


def _ffill(x: np.ndarray) -> np.ndarray:
    """Carry the last finite value forward (an update in which no episode ended logs NaN)."""
    idx = np.where(np.isfinite(x), np.arange(x.size), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, x[np.maximum(idx, 0)], np.nan)


def _band(series: list[tuple[np.ndarray, np.ndarray]], grid: np.ndarray) -> tuple[np.ndarray, ...]:
    """Mean, min and max across runs of (x, y) series, each interpolated onto `grid` (only where
    every run has data)."""
    ys = []
    for x, y in series:
        ok = np.isfinite(y)
        yi = np.interp(grid, x[ok], y[ok], left=np.nan, right=np.nan) if ok.any() else np.full(grid.shape, np.nan)
        ys.append(yi)
    a = np.array(ys)
    return a.mean(0), a.min(0), a.max(0)


def plot_sweep(runs: list[Run], title: str, out_path: Path) -> Path:
    """2 × 2 panels: evaluation success and training episode return, against environment steps
    and against training wall-clock; each algorithm's mean over seeds with its min–max band."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from quadpilot.atomic_files import atomic_write
    from quadpilot.train.runs.loop import SUCCESS_BAR

    fig = Figure(figsize=(9, 6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 2, sharey="row")
    for algo in ALGOS:
        group = [r for r in runs if r.algo == algo]
        if not group:
            continue
        label = f"{LABELS[algo]} ({len(group)} seed{'s' if len(group) > 1 else ''})"
        for col, xkey in enumerate(("global_step", "time_s")):
            end = min(float(np.nanmax(r.metrics[xkey])) for r in group)
            grid = np.linspace(0.0, end, 300)
            for row, (ykey, fill) in enumerate((("eval_success_rate", False), ("ep_return", True))):
                series = []
                for r in group:
                    y = r.metrics[ykey]
                    series.append((r.metrics[xkey], _ffill(y) if fill else y))
                mean, lo, hi = _band(series, grid)
                ax = axes[row, col]
                ax.plot(grid, mean, color=COLORS[algo], lw=1.5, label=label)
                if len(group) > 1:
                    ax.fill_between(grid, lo, hi, color=COLORS[algo], alpha=0.2, lw=0)
                for r in group:  # where each seed first reached the bar
                    first = r.eval.get("first_success")
                    if row == 0 and first:
                        x = first["global_step"] if xkey == "global_step" else first["train_time_s"]
                        ax.plot([x], [first["success_rate"]], "v", color=COLORS[algo], ms=5)
    for col, xlabel in enumerate(("environment steps", "training wall-clock (s), evaluations excluded")):
        axes[1, col].set_xlabel(xlabel)
        axes[0, col].axhline(SUCCESS_BAR, color="0.4", lw=0.8, ls="--")
    axes[0, 0].set_ylabel("evaluation success\n(100 deterministic episodes)")
    axes[1, 0].set_ylabel("training episode return")
    axes[0, 0].set_ylim(-0.02, 1.06)
    for ax in axes.flat:
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="lower right", fontsize=8)
    fig.suptitle(f"{title}: mean over seeds, band = min–max, ▼ = first evaluation ≥ 95 %", fontsize=10)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write(out_path, lambda f: f.write(buf.getvalue()))


# --- the report -----------------------------------------------------------------------------


def _stat(values: list[float | None], fmt: str, missing: str = "–") -> str:
    """'mean (min–max)' of the finite values; `missing` if none; a count when some are missing."""
    vals = [v for v in values if v is not None and math.isfinite(v)]
    if not vals:
        return missing
    s = fmt.format(np.mean(vals))
    if len(vals) > 1 and min(vals) != max(vals):
        s += f" ({fmt.format(min(vals))}–{fmt.format(max(vals))})"
    if len(vals) < len(values):
        s += f", {len(vals)} of {len(values)} seeds"
    return s


def gradient_steps_per_update(algo: str, ppo: dict) -> int:
    """Minibatch gradient steps in one update: ours drops the remainder of the rollout, SB3 makes
    a last, shorter minibatch of it."""
    batch, mb = ppo["num_envs"] * ppo["rollout_steps"], ppo["minibatch_size"]
    per_epoch = math.ceil(batch / mb) if algo == "sb3" else max(1, batch // mb)
    return per_epoch * ppo["epochs"]


def summarize(run: Run) -> dict:
    """The per-run figures of the results table."""
    m, ev = run.metrics, run.eval
    ppo = run.config["ppo"]
    updates = int(np.isfinite(m["update_s"]).sum())
    first = ev.get("first_success") or {}
    ret = m["ep_return"][np.isfinite(m["ep_return"])]
    return {
        "steps_to_bar": first.get("global_step"),
        "time_to_bar": first.get("train_time_s"),
        "final_success": ev["success_rate"],
        "final_error_cm": None if ev.get("mean_error_last_window_m") is None else 100 * ev["mean_error_last_window_m"],
        "eval_return": ev["mean_return"],
        "train_return": float(ret[-10:].mean()) if ret.size else None,
        "steps": ev["global_step"],
        "train_s": ev["train_time_s"],
        "steps_per_s": ev["global_step"] / ev["train_time_s"],
        "fractions": (ev.get("time_breakdown_s") or {}).get("fractions", {}),
        "grad_steps": gradient_steps_per_update(run.algo, ppo),
        "ms_per_grad_step": 1e3 * float(np.nansum(m["update_s"])) / (updates * gradient_steps_per_update(run.algo, ppo))
        if updates
        else None,
        "ms_per_env_step": 1e3 * float(np.nansum(m["rollout_s"])) / (updates * ppo["rollout_steps"])
        if updates
        else None,
    }


def _table(header: list[str], rows: list[list[str]], align: str | None = None) -> list[str]:
    align = align or "l" + "r" * (len(header) - 1)
    sep = ["---:" if a == "r" else "---" for a in align]
    return [
        "| " + " | ".join(header) + " |",
        "| " + " | ".join(sep) + " |",
        *("| " + " | ".join(r) + " |" for r in rows),
    ]


def _ratio(a: list, b: list) -> str:
    """Ratio of means; '–' unless every seed of both reached the figure."""
    if not a or not b or any(x is None for x in (*a, *b)):
        return "–"
    return f"{np.mean(a) / np.mean(b):.2f}×"


def sweep_section(directory: Path, sweep: dict, runs: list[Run], figure: Path, doc_dir: Path) -> list[str]:
    lines = [f"### {sweep['task']}, preset `{sweep['preset']}`", ""]
    budget = runs[0].config["ppo"]["total_steps"]
    lines += [
        f"{'Seeds' if len(sweep['seeds']) > 1 else 'Seed'} {', '.join(map(str, sweep['seeds']))}; {budget:,} "
        "environment steps per run; deterministic "
        f"evaluation (100 episodes) every {sweep['eval_every']} updates; {sweep['threads']} torch thread(s) per "
        f"process, {sweep['workers'] or 'Ray-scheduled'} processes at a time (engine {sweep['engine']}), nice "
        f"{sweep['nice']}, on {sweep['machine']['cores']} cores of an {sweep['machine']['cpu']}. Run "
        f"{sweep['started'][:10]}.",
        "",
        f"![{sweep['task']} {sweep['preset']}]({os.path.relpath(figure, doc_dir)})",
        "",
    ]
    by = {a: [summarize(r) for r in sorted(runs, key=lambda r: r.seed) if r.algo == a] for a in ALGOS}
    not_reached = f"not reached within {budget / 1e6:g} M steps"
    rows = []
    for a in ALGOS:
        s = by[a]
        if not s:
            continue
        rows.append(
            [
                LABELS[a],
                str(len(s)),
                _stat([x["eval_return"] for x in s], "{:.1f}"),
                _stat([x["train_return"] for x in s], "{:.1f}"),
                _stat([100 * x["final_success"] for x in s], "{:.0f} %"),
                _stat([x["final_error_cm"] for x in s], "{:.1f}"),
                _stat([x["steps_to_bar"] for x in s], "{:,.0f}", not_reached),
                _stat([x["time_to_bar"] for x in s], "{:.1f}", "–"),
                _stat([x["steps_per_s"] for x in s], "{:,.0f}"),
            ]
        )
    lines += _table(
        [
            "algorithm",
            "seeds",
            "final eval return",
            "final training return",
            "final eval success",
            "final eval error (cm)",
            "steps to 95 %",
            "training s to 95 %",
            "steps/s",
        ],
        rows,
    )
    if by["ppo"] and by["sb3"]:
        p, s = by["ppo"], by["sb3"]
        lines += [
            "",
            "SB3 ÷ ours (means over seeds): wall-clock to the bar "
            f"{_ratio([x['time_to_bar'] for x in s], [x['time_to_bar'] for x in p])}, steps to the bar "
            f"{_ratio([x['steps_to_bar'] for x in s], [x['steps_to_bar'] for x in p])}, whole-run steps/s "
            f"{_ratio([x['steps_per_s'] for x in s], [x['steps_per_s'] for x in p])}.",
        ]
    lines += [
        "",
        "Per run. Time split: environment / policy inference and rollout bookkeeping (GAE included) / update. "
        "ms per gradient step: the update time over the minibatch steps it made (forward, backward, clip, Adam "
        "and the loop around them); rollout ms per vector step: one step of all drones with inference.",
        "",
    ]
    rows = []
    for r in sorted(runs, key=lambda r: (ALGOS.index(r.algo), r.seed)):
        x = summarize(r)
        f = x["fractions"]
        split = " / ".join(f"{100 * f[k]:.0f} %" for k in ("env_s", "inference_s", "update_s")) if f else "–"
        rows.append(
            [
                r.algo,
                str(r.seed),
                "–" if x["steps_to_bar"] is None else f"{x['steps_to_bar']:,}",
                "–" if x["time_to_bar"] is None else f"{x['time_to_bar']:.1f}",
                f"{100 * x['final_success']:.0f} %",
                f"{x['steps']:,}",
                f"{x['train_s']:.1f}",
                f"{x['steps_per_s']:,.0f}",
                split,
                f"{x['grad_steps']}",
                "–" if x["ms_per_grad_step"] is None else f"{x['ms_per_grad_step']:.2f}",
                "–" if x["ms_per_env_step"] is None else f"{x['ms_per_env_step']:.2f}",
            ]
        )
    lines += _table(
        [
            "algo",
            "seed",
            "steps to 95 %",
            "s to 95 %",
            "final success",
            "steps",
            "training s",
            "steps/s",
            "time split",
            "gradient steps per update",
            "ms per gradient step",
            "rollout ms per vector step",
        ],
        rows,
        "llrrrrrrrrrr",
    )
    return [*lines, ""]


def settings_section(cfg_json: dict, preset: str) -> list[str]:
    from quadpilot.train.ppo import PPOConfig

    from .matched_settings import IMPLICIT_ROWS, settings_rows

    cfg = PPOConfig.from_json(cfg_json)
    lines = [f"### Matched settings, preset `{preset}`", ""]
    rows = [[f"`{a}`", f"`{b}`" if b != "—" else b, c] for a, b, c in settings_rows(cfg)]
    lines += _table(["ours (PPOConfig)", "SB3 (PPO / policy / env)", "how they match, or how they differ"], rows, "lll")
    lines += ["", "Not configuration fields, but they decide what is computed:", ""]
    lines += _table(["", "ours", "SB3"], [list(r) for r in IMPLICIT_ROWS], "lll")
    return [*lines, ""]


def render(directories: list[Path], figures: Path, doc: Path, argv: list[str]) -> str:
    import stable_baselines3
    import torch

    lines = [
        BEGIN,
        "",
        f"Generated by `{shlex.join(['quad-compare', *argv])}` from the runs of these sweeps "
        f"(stable-baselines3 {stable_baselines3.__version__}, torch {torch.__version__}, Python "
        f"{platform.python_version()}).",
        "",
    ]
    loaded = []
    for d in directories:
        sweep, runs = load_sweep(d)
        loaded.append((d, sweep, runs))
    lines += ["### Commands", "", "```bash"]
    for _, sweep, _ in loaded:
        lines.append(f"nice -n {sweep['nice']} .venv/bin/{sweep['command']}")
    lines += [f".venv/bin/{shlex.join(['quad-compare', *argv])}", "```", ""]
    for d, sweep, runs in loaded:
        figure = figures / f"{sweep['task']}-{sweep['preset']}.png"
        plot_sweep(runs, f"{sweep['task']}, preset {sweep['preset']}", figure)
        lines += sweep_section(d, sweep, runs, figure, doc.parent)
    seen = set()
    for _, sweep, runs in loaded:
        if sweep["preset"] in seen:
            continue
        seen.add(sweep["preset"])
        lines += settings_section(runs[0].config["ppo"], sweep["preset"])
    lines.append(END)
    return "\n".join(lines) + "\n"


def cmd_report(args, argv: list[str]) -> int:
    from quadpilot.atomic_files import atomic_write

    doc, figures = Path(args.doc), Path(args.figures)
    section = render([Path(d) for d in args.sweeps], figures, doc, argv)
    old = doc.read_text(encoding="utf-8") if doc.exists() else ""
    if BEGIN in old and END in old:
        head, rest = old.split(BEGIN, 1)
        new = head + section.rstrip("\n") + rest.split(END, 1)[1]
    else:
        new = (old.rstrip("\n") + "\n\n" if old else "") + section
    doc.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(doc, lambda f: f.write(new.encode("utf-8")))
    print(f"quad-compare: wrote {doc} and the figures in {figures}", flush=True)
    return 0
