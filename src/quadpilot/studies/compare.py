"""quad-compare: our PPO against Stable-Baselines3 PPO with matched settings, across seeds.

    quad-compare run --preset fast --seeds 0,1,2 --out runs/compare/hover-fast
    quad-compare report runs/compare/hover-fast runs/compare/hover-seed001

`run` trains every (algorithm, seed) pair as its own `quad-train --algo ALGO` process, at most
--workers at a time (default 2, the cores of the build machine), each with --threads torch threads
(default 1) so the wall-clock of both algorithms is measured under the same load; with
--engine ray the same processes are Ray tasks of --threads CPUs each, on a local or existing Ray
cluster (`pip install "quadpilot[cluster]"`; the --out directory must then be on storage every node
sees). A finished run (its eval.json exists) is kept and not trained again. `sweep.json` in --out
records the request, the machine and each run's exit code and wall-clock.

`report` reads sweeps and writes, into --figures, one PNG per sweep (evaluation success and training
return of both algorithms against environment steps and against training wall-clock, the mean over
seeds with the min–max band), and into --doc the matched-settings table, the results and the commands,
between the markers below; text outside the markers is kept, so the analysis written around the
tables survives a regeneration.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import math
import os
import platform
import shlex
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from quadpilot.train.cli import UsageError, _Parser

ALGOS = ("ppo", "sb3")
LABELS = {"ppo": "ours (PPO from scratch)", "sb3": "Stable-Baselines3 PPO"}
COLORS = {"ppo": "C0", "sb3": "C3"}
BEGIN = "<!-- BEGIN quad-compare report: generated, edits here are overwritten -->"
END = "<!-- END quad-compare report -->"
SWEEP = "sweep.json"


# --- running --------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One training process: `quad-train` with `argv`, writing into `out`, its output into `log`."""

    algo: str
    seed: int
    out: str
    log: str
    argv: tuple[str, ...]
    threads: int


def run_one(spec: RunSpec) -> dict:
    """Train one run in a child process; returns its exit code and wall-clock seconds. Torch and the
    BLAS libraries get `spec.threads` threads, the same for every algorithm."""
    env = dict(os.environ)
    for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        env[k] = str(spec.threads)
    t = time.perf_counter()
    with open(spec.log, "w", encoding="utf-8") as log:
        code = subprocess.run(
            [sys.executable, "-m", "quadpilot.train.cli", *spec.argv],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
            check=False,
        ).returncode
    return {
        "algo": spec.algo,
        "seed": spec.seed,
        "dir": spec.out,
        "returncode": code,
        "wall_s": time.perf_counter() - t,
    }


def _run_local(specs: list[RunSpec], workers: int) -> list[dict]:
    # threads only wait on the child processes; the processes do the work, `workers` at a time
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(run_one, specs))


def _import_ray():
    try:
        import ray
    except ImportError:
        raise UsageError(
            "--engine ray needs Ray, which is not installed in this environment; install it with "
            "pip install 'quadpilot[cluster]' (or pip install 'ray[default]'), or use the default --engine process"
        ) from None
    return ray


def _run_ray(ray, specs: list[RunSpec], threads: int, address: str | None) -> list[dict]:
    ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
    task = ray.remote(num_cpus=threads)(run_one)
    return ray.get([task.remote(s) for s in specs])


def _parse_list(kind, choices=None):
    def parse(s: str) -> list:
        try:
            items = [kind(x) for x in s.replace(" ", "").split(",") if x]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {s!r}") from None
        if not items:
            raise argparse.ArgumentTypeError("expected at least one item")
        if choices is not None and (bad := [x for x in items if x not in choices]):
            raise argparse.ArgumentTypeError(f"unknown {bad}; expected some of {list(choices)}")
        if len(set(items)) != len(items):
            raise argparse.ArgumentTypeError(f"repeated items in {s!r}")
        return items

    parse.__name__ = "list"
    return parse


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def plan(args) -> list[RunSpec]:
    out = Path(args.out)
    specs = []
    for seed in args.seeds:
        for algo in args.algos:  # interleaved, so the two algorithms share the machine alike
            d = out / f"{algo}-seed{seed}"
            argv = ["--algo", algo, "--task", args.task, "--preset", args.preset, "--seed", str(seed)]
            argv += ["--threads", str(args.threads), "--eval-every", str(args.eval_every), "--out", str(d)]
            if args.total_steps is not None:
                argv += ["--total-steps", str(args.total_steps)]
            specs.append(RunSpec(algo, seed, str(d), str(out / f"{algo}-seed{seed}.log"), tuple(argv), args.threads))
    return specs


def cmd_run(args, argv: list[str]) -> int:
    from quadpilot.train.runlog import write_json

    ray = _import_ray() if args.engine == "ray" else None  # before anything is written
    out = Path(args.out)
    specs = plan(args)
    todo, done = [], []
    for s in specs:
        d = Path(s.out)
        if (d / "eval.json").exists():
            done.append(s)
        elif d.exists() and any(d.iterdir()):
            raise UsageError(f"{d} holds an unfinished run; delete it (or the whole --out) and run again")
        else:
            todo.append(s)
    out.mkdir(parents=True, exist_ok=True)
    previous = json.loads((out / SWEEP).read_text()) if (out / SWEEP).exists() else {}
    sweep = {
        "schema": "quadpilot.compare/1",
        "task": args.task,
        "preset": args.preset,
        "seeds": args.seeds,
        "algos": args.algos,
        "total_steps": args.total_steps,
        "eval_every": args.eval_every,
        "threads": args.threads,
        "workers": args.workers if args.engine == "process" else None,
        "engine": args.engine,
        "nice": os.nice(0),
        "command": shlex.join(["quad-compare", *argv]),
        "machine": {"cpu": _cpu_model(), "cores": os.cpu_count(), "python": platform.python_version()},
        "started": _now(),
        "runs": [r for r in previous.get("runs", []) if any(r["dir"] == s.out for s in done)],
    }
    write_json(out / SWEEP, sweep)
    print(
        f"quad-compare: {len(todo)} run(s) to train ({len(done)} already finished), "
        f"{args.workers if ray is None else 'Ray'} at a time, {args.threads} torch thread(s) each; logs in {out}",
        flush=True,
    )
    results = _run_local(todo, args.workers) if ray is None else _run_ray(ray, todo, args.threads, args.ray_address)
    for r in results:
        print(f"  {r['algo']} seed {r['seed']}: exit {r['returncode']}, {r['wall_s']:.0f} s", flush=True)
    sweep["runs"] += results
    sweep["finished"] = _now()
    write_json(out / SWEEP, sweep)
    failed = [r for r in results if r["returncode"] != 0]
    if failed:
        logs = ", ".join(str(Path(r["dir"]).with_suffix(".log")) for r in failed)
        print(f"quad-compare: {len(failed)} run(s) failed; see {logs}", file=sys.stderr)
        return 1
    return 0


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
    from quadpilot.train.runlog import read_metrics

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

    from quadpilot.train.checkpoint import atomic_write
    from quadpilot.train.cli import SUCCESS_BAR

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
    from quadpilot.train.sb3_baseline import IMPLICIT_ROWS, settings_rows

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
    from quadpilot.train.checkpoint import atomic_write

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


# --- command line ---------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    from quadpilot.train.envs import TASKS
    from quadpilot.train.ppo import PRESETS

    p = _Parser(
        prog="quad-compare",
        description=__doc__.split("\n\n")[0],
        epilog="\n\n".join(__doc__.split("\n\n")[1:]),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        allow_abbrev=False,
    )
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    r = sub.add_parser("run", help="train every (algorithm, seed) pair of one preset", allow_abbrev=False)
    r.add_argument("--task", choices=[t for t in TASKS if t != "waypoint"], default="hover", help="Default: hover.")
    r.add_argument("--preset", choices=sorted(PRESETS), default="fast", help="PPO preset both match. Default: fast.")
    r.add_argument("--seeds", type=_parse_list(int), default=[0, 1, 2], metavar="S,S,…", help="Default: 0,1,2.")
    r.add_argument(
        "--algos", type=_parse_list(str, ALGOS), default=list(ALGOS), metavar="A,…", help="Default: ppo,sb3."
    )
    r.add_argument("--total-steps", type=int, metavar="N", help="Step budget of every run. Default: the preset's.")
    r.add_argument(
        "--eval-every",
        type=int,
        default=10,
        metavar="N",
        help="Deterministic evaluation (100 episodes) every N updates; the step grid of the bar. Default: 10.",
    )
    r.add_argument("--threads", type=int, default=1, metavar="N", help="Torch threads per run. Default: 1.")
    r.add_argument("--workers", type=int, default=2, metavar="N", help="Runs at a time (engine process). Default: 2.")
    r.add_argument(
        "--engine",
        choices=("process", "ray"),
        default="process",
        help="process: a local pool of --workers processes; ray: Ray tasks of --threads CPUs (needs "
        "quadpilot[cluster]). Default: process.",
    )
    r.add_argument("--ray-address", metavar="ADDR", help="An existing Ray cluster (engine ray). Default: a local one.")
    r.add_argument("--out", required=True, metavar="DIR", help="Sweep directory (keep it out of the repository).")
    rep = sub.add_parser("report", help="plots and docs/comparison.md from finished sweeps", allow_abbrev=False)
    rep.add_argument("sweeps", nargs="+", metavar="DIR", help="Sweep directories written by quad-compare run.")
    rep.add_argument("--doc", default="docs/comparison.md", metavar="FILE", help="Default: docs/comparison.md.")
    rep.add_argument("--figures", default="docs/comparison", metavar="DIR", help="Default: docs/comparison.")
    return p


def _check_args(args) -> None:
    """Every flag value, before anything is trained or written (one line, exit 2)."""
    from quadpilot.train.checkpoint import MAX_THREADS
    from quadpilot.train.cli import check_out_dir

    limits = {"threads": MAX_THREADS, "workers": 256, "eval_every": 2**62, "total_steps": 2**62}  # quad-train's
    for name, hi in limits.items():
        v = getattr(args, name, None)
        if v is not None and v < 1:
            raise UsageError(f"--{name.replace('_', '-')} must be ≥ 1, got {v}")
        if v is not None and v > hi:
            raise UsageError(f"--{name.replace('_', '-')} must be ≤ {hi:,}, got {v:,}")
    if args.command == "run":
        if bad := [s for s in args.seeds if not 0 <= s < 2**63]:
            raise UsageError(f"--seeds: {bad} are not seeds; expected integers ≥ 0")
        check_out_dir(Path(args.out))
    else:
        for d in args.sweeps:
            if not Path(d).is_dir():
                raise UsageError(f"{d}: not a directory; expected a sweep directory written by quad-compare run")
        check_out_dir(Path(args.figures), "--figures")
        from quadpilot.console import check_output_path

        try:
            check_output_path(Path(args.doc), "--doc")
        except ValueError as e:
            raise UsageError(str(e)) from None


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(argv)
        _check_args(args)
        return cmd_run(args, argv) if args.command == "run" else _report(args, argv)
    except SystemExit as e:  # --help
        return e.code if isinstance(e.code, int) else 0
    except UsageError as e:
        print(f"quad-compare: error: {e}", file=sys.stderr)
        return 2
    except _BadSweep as e:
        print(f"quad-compare: error: {e}", file=sys.stderr)
        return 1


class _BadSweep(Exception):
    """A sweep directory whose files cannot be read: exit code 1, one line."""


def _report(args, argv: list[str]) -> int:
    try:
        return cmd_report(args, argv)
    except (OSError, ValueError, KeyError, TypeError, IndexError) as e:  # JSON/CSV that is not a sweep's
        what = " ".join(str(e).split())[:200]
        raise _BadSweep(f"{', '.join(args.sweeps)}: a sweep file cannot be read ({type(e).__name__}: {what})") from None


if __name__ == "__main__":
    sys.exit(main())
