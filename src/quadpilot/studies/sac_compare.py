"""SAC against our PPO on one task: the table and the learning-curve figure of
docs/comparison.md's section "SAC", from finished quad-train run directories.

    python -m quadpilot.studies.sac_compare --ppo runs/sac-vs-ppo/ppo-seed{0,1,2} \\
        --sac runs/sac-vs-ppo/sac-seed{0,1,2} --png docs/comparison/sac-vs-ppo-hover.png

Each run is read from its own files: eval.json (final evaluation and the first periodic evaluation
at ≥ 95 %, `first_success`) and metrics.csv (the periodic evaluations, `eval_success_rate` and
`eval_error_m`, against environment steps and training seconds; evaluation time is not training
time in either trainer). Prints a markdown table.
"""

from __future__ import annotations

import io
import json
import math
import sys
from pathlib import Path

import numpy as np

from quadpilot.console import BadFile, Parser, UsageError, run_command


def _read(run: Path) -> dict:
    ev = json.loads((run / "eval.json").read_text())
    cfg = json.loads((run / "config.json").read_text())
    algo = cfg.get("algo", "ppo")
    from quadpilot.train.algorithms import ALGORITHMS
    from quadpilot.train.runs.runlog import read_metrics

    m = read_metrics(run / "metrics.csv", ALGORITHMS[algo].columns)
    first = ev.get("first_success") or {}
    seed = (cfg.get("sac") or cfg.get("ppo") or {}).get("seed")
    return {
        "run": run,
        "algo": algo,
        "seed": seed,
        "metrics": m,
        "steps": ev["global_step"],
        "train_s": ev["train_time_s"],
        "steps_to_bar": first.get("global_step"),
        "s_to_bar": first.get("train_time_s"),
        "success": ev["success_rate"],
        "error_cm": 100 * ev["mean_error_last_window_m"] if ev.get("mean_error_last_window_m") is not None else None,
        "grad_steps": ev.get("grad_steps") or (_ppo_grad_steps(cfg, ev) if algo == "ppo" else None),
        "split": (ev.get("time_breakdown_s") or {}).get("fractions") or {},
    }


def _ppo_grad_steps(cfg: dict, ev: dict) -> int | None:
    p = cfg.get("ppo") or {}
    try:
        per_update = p["epochs"] * max(1, p["num_envs"] * p["rollout_steps"] // p["minibatch_size"])
        return int(per_update * ev["updates"])
    except (KeyError, TypeError):
        return None


def _fmt(v, spec: str = ",.0f", none: str = "–") -> str:
    return none if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)


def _summary(vals: list, spec: str) -> str:
    got = [v for v in vals if v is not None]
    if not got:
        return "not reached"
    s = format(float(np.mean(got)), spec)
    if len(got) > 1 and format(min(got), spec) != format(max(got), spec):
        s += f" ({format(min(got), spec)}–{format(max(got), spec)})"
    if len(got) < len(vals):
        s += f", {len(got)} of {len(vals)} seeds"
    return s


def table(runs: list[dict]) -> str:
    lines = [
        "| algorithm | seeds | steps to 95 % | training s to 95 % | final success | final error (cm) | "
        "steps | training s | steps/s | gradient steps |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for algo, label in (("ppo", "our PPO (`fast`)"), ("sac", "our SAC")):
        rs = [r for r in runs if r["algo"] == algo]
        if not rs:
            continue
        lines.append(
            f"| {label} | {len(rs)} | {_summary([r['steps_to_bar'] for r in rs], ',.0f')} | "
            f"{_summary([r['s_to_bar'] for r in rs], '.1f')} | "
            f"{_summary([100 * r['success'] for r in rs], '.0f')} % | "
            f"{_summary([r['error_cm'] for r in rs], '.1f')} | {_summary([r['steps'] for r in rs], ',.0f')} | "
            f"{_summary([r['train_s'] for r in rs], '.1f')} | "
            f"{_summary([r['steps'] / r['train_s'] for r in rs], ',.0f')} | "
            f"{_summary([r['grad_steps'] for r in rs], ',.0f')} |"
        )
    lines += [
        "",
        "| run | steps to 95 % | s to 95 % | final success | final error (cm) | time split env / inference / update |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in runs:
        sp = r["split"]
        split = " / ".join(
            _fmt(100 * sp[k], ".0f") + " %" if sp.get(k) is not None else "–"
            for k in ("env_s", "inference_s", "update_s")
        )
        lines.append(
            f"| {r['algo']} seed {r['seed']} | {_fmt(r['steps_to_bar'])} | {_fmt(r['s_to_bar'], '.1f')} | "
            f"{100 * r['success']:.0f} % | {_fmt(r['error_cm'], '.1f')} | {split} |"
        )
    return "\n".join(lines)


def _has_positive(points: list[tuple[np.ndarray, np.ndarray]], coord: int) -> bool:
    """Whether one of the (x, y) points drawn on a panel (both finite) is > 0 on `coord` (0: x, 1: y)."""
    return any(np.any(xy[coord][np.isfinite(xy[0]) & np.isfinite(xy[1])] > 0) for xy in points)


def plot(runs: list[dict], png: Path, title: str) -> Path:
    """Periodic evaluation success and error against environment steps and training seconds."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from quadpilot.atomic_files import atomic_write

    fig = Figure(figsize=(10, 6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 2, sharey="row")
    colours = {"ppo": "C0", "sac": "C3"}
    labels = {"ppo": "PPO", "sac": "SAC"}
    seen = set()
    drawn = {(i, j): [] for i in range(2) for j in range(2)}  # each panel's (x, y) data, for its log axes
    for r in runs:
        m = r["metrics"]
        ev = np.isfinite(m["eval_success_rate"])
        x_steps, x_s = m["global_step"][ev], m["time_s"][ev]
        succ, err = 100 * m["eval_success_rate"][ev], 100 * m["eval_error_m"][ev]
        kw = {"color": colours[r["algo"]], "lw": 1.1, "alpha": 0.85, "marker": "o", "ms": 2}
        label = labels[r["algo"]] if r["algo"] not in seen else None
        seen.add(r["algo"])
        for (i, j), xy in {
            (0, 0): (x_steps, succ),
            (0, 1): (x_s, succ),
            (1, 0): (x_steps, err),
            (1, 1): (x_s, err),
        }.items():
            axes[i, j].plot(*xy, label=label if (i, j) == (0, 0) else None, **kw)
            drawn[i, j].append(xy)
    for ax in axes[0]:
        ax.axhline(95, color="0.4", lw=0.8, ls="--")
        ax.set_ylim(-2, 102)
    axes[0, 0].set_ylabel("evaluation success (%)")
    axes[1, 0].set_ylabel("evaluation error, last 2 s (cm)")
    # a log axis only where that panel has a point with a positive value on it: every evaluation of a
    # short run may have crashed (error None), and a run too short may clock no positive time
    for j, ax in enumerate(axes[1]):
        if _has_positive(drawn[1, j], 1):
            ax.set_yscale("log")
        ax.axhline(5, color="0.4", lw=0.8, ls="--")
    axes[1, 0].set_xlabel("environment steps")
    timed = [axes[i, 1] for i in range(2) if _has_positive(drawn[i, 1], 0)]
    axes[1, 1].set_xlabel("training seconds (evaluation excluded" + ("; log scale)" if axes[1, 1] in timed else ")"))
    for ax in timed:
        ax.set_xscale("log")
    for ax in axes.flat:
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="lower right")
    fig.suptitle(title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    return atomic_write(png, lambda f: f.write(buf.getvalue()))


def main(argv: list[str] | None = None) -> int:
    p = Parser(prog="python -m quadpilot.studies.sac_compare", description=__doc__.split("\n\n")[0])
    p.add_argument("--ppo", nargs="*", type=Path, default=[], help="run directories of quad-train (PPO)")
    p.add_argument("--sac", nargs="*", type=Path, default=[], help="run directories of quad-train --algo sac")
    p.add_argument("--png", type=Path, help="write the learning-curve figure here")
    p.add_argument("--title", default="hover: periodic deterministic evaluation (100 episodes), one line per seed")
    return run_command("python -m quadpilot.studies.sac_compare", lambda: _compare(p.parse_args(argv)))


def _compare(args) -> int:
    if not (args.ppo or args.sac):
        raise UsageError("give --ppo and/or --sac run directories")
    runs = []
    for run in [*args.ppo, *args.sac]:
        try:
            runs.append(_read(run))
        except (OSError, ValueError, KeyError, TypeError) as e:  # not a finished quad-train run directory
            why = e.strerror if isinstance(e, OSError) and e.strerror else f"{type(e).__name__}: {e}"
            raise BadFile(f"{run}: {why}; expected a finished quad-train run directory") from None
    print(table(runs))
    if args.png:
        out = plot(runs, args.png, args.title)
        print(f"\n![SAC and PPO on hover]({out}) ({out.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
