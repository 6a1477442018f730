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
tables survives a regeneration. By default both go beside the first sweep (comparison.md and
comparison/ in its parent directory), never into the repository's docs: the page in the repository
is rewritten only when named, `--doc docs/comparison.md --figures docs/comparison`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime, timezone
from pathlib import Path

from quadpilot.console import BadFile, Parser, UsageError, quick, run_command

from .compare_report import ALGOS, SWEEP, cmd_report

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
            if args.timing is not None:
                argv += ["--timing", args.timing]
            for item in args.reward or ():
                argv += ["--reward", item]
            specs.append(RunSpec(algo, seed, str(d), str(out / f"{algo}-seed{seed}.log"), tuple(argv), args.threads))
    return specs


def planned_config(run_argv: list[str]) -> dict:
    """The PPOConfig (as config.json holds it) of the first run `quad-compare run RUN_ARGV` trains: its
    quad-train command line read as quad-train reads it, so the matched-settings table of a sweep can
    be printed before the sweep is run (the table lists configuration, not measurements)."""
    from quadpilot.train.cli import build_parser as train_parser
    from quadpilot.train.ppo import PPO
    from quadpilot.train.runs import options

    args = build_parser().parse_args(["run", *run_argv])
    train_args = train_parser().parse_args(list(plan(args)[0].argv))
    return options.make_config(PPO, options.explicit_options(train_args, PPO), train_args.preset).to_json()


def cmd_run(args, argv: list[str]) -> int:
    from quadpilot.train.runs.loop import cpu_model
    from quadpilot.train.runs.runlog import write_json

    ray = _import_ray() if args.engine == "ray" else None  # before anything is written
    args.seeds = args.seeds[: quick(len(args.seeds), 1)]  # QUADPILOT_DOCS_QUICK: one seed (quad-train shortens itself)
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
        "machine": {"cpu": cpu_model(), "cores": os.cpu_count(), "python": platform.python_version()},
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


# --- command line ---------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    from quadpilot.train.envs import TASKS
    from quadpilot.train.ppo import PRESETS

    p = Parser(
        prog="quad-compare",
        description=__doc__.split("\n\n")[0],
        epilog="\n\n".join(__doc__.split("\n\n")[1:]),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        allow_abbrev=False,
    )
    sub = p.add_subparsers(dest="command", required=True, parser_class=Parser)
    r = sub.add_parser("run", help="train every (algorithm, seed) pair of one preset", allow_abbrev=False)
    r.add_argument("--task", choices=[t for t in TASKS if t != "waypoint"], default="hover", help="Default: hover.")
    r.add_argument("--preset", choices=sorted(PRESETS), default="fast", help="PPO preset both match. Default: fast.")
    r.add_argument("--seeds", type=_parse_list(int), default=[0, 1, 2], metavar="S,S,…", help="Default: 0,1,2.")
    r.add_argument(
        "--algos", type=_parse_list(str, ALGOS), default=list(ALGOS), metavar="A,…", help="Default: ppo,sb3."
    )
    r.add_argument("--total-steps", type=int, metavar="N", help="Step budget of every run. Default: the preset's.")
    r.add_argument(
        "--timing",
        choices=("link", "none"),  # core.timing.PRESETS (not imported: --help stays light)
        help="quad-train's --timing for every run (the same for both algorithms). Default: quad-train's (link).",
    )
    r.add_argument(
        "--reward",
        action="append",
        metavar="NAME=VALUE",
        help="quad-train's --reward for every run; repeatable. Default: the task's reward.",
    )
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
    rep = sub.add_parser("report", help="plots and the comparison page from finished sweeps", allow_abbrev=False)
    rep.add_argument("sweeps", nargs="+", metavar="DIR", help="Sweep directories written by quad-compare run.")
    rep.add_argument(
        "--doc",
        metavar="FILE",
        help="Markdown file whose section between the markers is rewritten (created if missing). Default: "
        "comparison.md beside the first sweep (in its parent directory); the repository's page is "
        "docs/comparison.md, rewritten only when named here.",
    )
    rep.add_argument(
        "--figures", metavar="DIR", help="Directory of the PNGs. Default: comparison/ beside the first sweep."
    )
    return p


def _check_args(args) -> None:
    """Every flag value, before anything is trained or written (one line, exit 2)."""
    from quadpilot.train.runs.checks import MAX_THREADS
    from quadpilot.train.runs.loop import check_out_dir

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
        from quadpilot.console import input_path_problem

        for d in args.sweeps:
            why = input_path_problem(d, "a sweep directory written by quad-compare run", directory=True)
            if why is not None:
                raise UsageError(why)
        beside = Path(os.path.abspath(args.sweeps[0])).parent  # the sweeps are kept out of the repository
        args.doc = args.doc or str(beside / "comparison.md")
        args.figures = args.figures or str(beside / "comparison")
        check_out_dir(Path(args.figures), "--figures")
        from quadpilot.console import check_output_path

        try:
            check_output_path(Path(args.doc), "--doc")
        except ValueError as e:
            raise UsageError(str(e)) from None


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_command("quad-compare", lambda: _compare(build_parser().parse_args(argv), argv))


def _compare(args, argv: list[str]) -> int:
    _check_args(args)
    return cmd_run(args, argv) if args.command == "run" else _report(args, argv)


def _report(args, argv: list[str]) -> int:
    try:
        return cmd_report(args, argv)
    except (OSError, ValueError, KeyError, TypeError, IndexError) as e:  # JSON/CSV that is not a sweep's
        what = " ".join(str(e).split())[:200]
        raise BadFile(f"{', '.join(args.sweeps)}: a sweep file cannot be read ({type(e).__name__}: {what})") from None


if __name__ == "__main__":
    sys.exit(main())
