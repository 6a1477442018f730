"""The one run loop of quad-train, for every algorithm (a `trainer.Trainer`: PPO, recurrent PPO, SAC).
It knows none of them by name: `train` is handed the registry (`train.algorithms.ALGORITHMS`) and
asks the chosen Trainer class what differs (its configuration, preset, --init-from, checkpoint).

A run checks and locks its directory (fresh: new or empty; --resume: the newest readable
checkpoint, whose configuration it keeps but for --total-steps and --threads), then iterates. Per
iteration: one metrics.csv row, written before the checkpoint (a kill between the two leaves a row
the resume drops); every --eval-every iterations a deterministic evaluation, its time not counted as
training time, and `first_success` the first time it passes SUCCESS_BAR at the final curriculum
stage; the waypoint curriculum's advance; a snapshot every --snapshot-every; a checkpoint every
--checkpoint-every. The first SIGINT or SIGTERM ends the iteration, saves and exits 130 (resumable);
a second aborts at once, the last checkpoint intact. At the end: policy.pt, curves.png, eval.json.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import shlex
import signal
import sys
import threading
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch

from quadpilot.console import UsageError
from quadpilot.core.timing import TimingConfig

from . import options
from .checkpoint import POLICY, has_checkpoint, load_for_resume, save_checkpoint, save_snapshot
from .checkpoint_read import algorithm_of
from .runlog import (
    MetricsLog,
    check_run_dir_free,
    holds_run_files,
    lock_run_dir,
    read_metrics,
    truncate_metrics,
    write_json,
)
from .trainer import LATEST

SUCCESS_BAR = 0.95  # success rate over 100 deterministic episodes: the bar "solved" means here
SUCCESS_KEY = {"circle": "circle_success_rate"}  # hover and waypoint use evaluate()'s success_rate
RUN_SCHEMA = "quadpilot.run/1"
RUN_FILES = (
    *("config.json", "metrics.csv", "checkpoint.pt", "checkpoint.prev.pt", "policy.pt", "eval.json", "curves.png"),
)
SIGNALS = ("SIGINT", "SIGTERM")


def cpu_model() -> str:
    """The CPU's model name (Linux's /proc/cpuinfo), else what `platform` knows: what every result
    file records as its machine."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            name = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), None)
    except OSError:
        name = None
    return name or platform.processor() or platform.machine() or "unknown"


def machine() -> dict:
    """What bit-identical retraining depends on besides the code and the command: the CPU (torch's
    BLAS and vectorised kernels pick their instructions from it), the thread count is in the
    command, and the numerical libraries' versions."""
    return {"cpu": cpu_model(), "torch": torch.__version__, "numpy": np.__version__}


def command(argv: list[str]) -> str:
    return shlex.join(["quad-train", *argv])


def resume_argv(argv: list[str]) -> list[str]:
    """The command that resumes this run: with --resume, without --init-from (a resumed run
    continues from its checkpoint, and quad-train refuses the two together)."""
    kept, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a == "--init-from":
            skip = True
        elif not a.startswith("--init-from="):
            kept.append(a)
    return kept if "--resume" in kept else [*kept, "--resume"]


def now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


# --- progress and signals --------------------------------------------------------------------


def _info(m: dict) -> str:
    ret, succ = m["ep_return"], m["success_rate"]
    ret_s = f"{ret:.1f}" if math.isfinite(ret) else "–"  # no episode ended in this iteration
    succ_s = f"{succ:.0%}" if math.isfinite(succ) else "–"
    s = f"{m['steps_per_s']:,.0f} steps/s · return {ret_s} · success {succ_s}"
    if m.get("curriculum_stage") is not None:
        s += f" · stage {m['curriculum_stage']} ({m['target_radius']:g} m)"
    return s


class Progress:
    """A rich progress bar on a terminal; a plain line every ~10 % otherwise (CI logs)."""

    def __init__(self, label: str, start: int, total: int) -> None:
        from rich.console import Console

        self.label, self.total = label, total
        console = Console()
        self.fancy = console.is_terminal
        self.next_mark = math.floor(10 * start / total + 1e-9) / 10 + 0.1 if total else 1.0
        if self.fancy:
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
            from rich.progress import Progress as Bar
            from rich.table import Column

            self.bar = Bar(
                TextColumn("[bold]{task.description}"),
                BarColumn(bar_width=24),
                # on a narrow terminal the counters keep their width and the metrics get cut
                MofNCompleteColumn(table_column=Column(min_width=2 * len(f"{total}") + 1)),
                TimeRemainingColumn(table_column=Column(min_width=7)),
                TextColumn("{task.fields[info]}", table_column=Column(no_wrap=True, overflow="ellipsis")),
                console=console,
            )
            self.task = self.bar.add_task(label.removeprefix("quad-train "), total=total, completed=start, info="")
            self.bar.start()
        else:
            print(f"{label}: {start:,}/{total:,} steps", flush=True)

    def update(self, m: dict) -> None:
        step = int(m["global_step"])
        if self.fancy:
            self.bar.update(self.task, completed=step, info=_info(m))
            return
        frac = step / self.total if self.total else 1.0
        if frac + 1e-9 >= self.next_mark or step >= self.total:
            print(
                f"{self.label}: {step:,}/{self.total:,} steps ({frac:.0%}), update {m['update']} · {_info(m)}",
                flush=True,
            )
            self.next_mark = math.floor(10 * frac + 1e-9) / 10 + 0.1

    def close(self) -> None:
        if self.fancy:
            self.bar.stop()
            self.fancy = False


class Stop:
    """First SIGINT/SIGTERM: finish the iteration, save, exit. Second: abort at once."""

    def __init__(self) -> None:
        self.signal: str | None = None
        self._old: dict = {}

    def __call__(self, signum, frame) -> None:
        if self.signal is not None:
            raise KeyboardInterrupt
        self.signal = signal.Signals(signum).name

    def __enter__(self) -> Stop:
        if threading.current_thread() is threading.main_thread():
            for name in SIGNALS:
                sig = getattr(signal, name, None)
                if sig is not None:
                    self._old[sig] = signal.signal(sig, self)
        return self

    def __exit__(self, *exc) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


# --- the run directory -----------------------------------------------------------------------


def _check_name(out: Path, flag: str = "--out") -> None:
    """UsageError if the OS refuses the name itself (too long, through a file, a loop of links)."""
    from quadpilot.console import os_reason

    try:
        os.stat(out)
    except FileNotFoundError:
        pass
    except OSError as e:
        raise UsageError(f"{flag} {out}: {os_reason(e)}") from None


def check_out_dir(out: Path, flag: str = "--out") -> None:
    """UsageError unless `out` is a directory this process could create or write in (checked before
    any work: a path through a file, under /proc, or in a read-only place is refused up front)."""
    from quadpilot.console import check_output_path  # the one place outputs are probed

    if not str(out):
        raise UsageError(f"{flag}: empty path")
    _check_name(out, flag)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{flag} {out}: exists and is not a directory")
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    try:
        check_output_path(existing, flag, directory=True)
    except ValueError as e:
        raise UsageError(f"{flag} {out}: cannot be created: {str(e).removeprefix(f'{flag} ')}") from None


def _check_fresh_dir(out: Path) -> None:
    """A fresh run needs --out to be new or empty, and not in use by another run."""
    _check_name(out)
    if out.is_dir():
        check_run_dir_free(out)  # RunDirBusy: exit 1, before anything else is looked at
        if holds_run_files(out):
            raise UsageError(
                f"{out} exists and is not empty; add --resume to continue that run or choose another --out"
            )
    elif out.exists() or out.is_symlink():
        raise UsageError(f"{out} exists and is not a directory; choose another --out")
    check_out_dir(out)


def _claim(out: Path) -> None:
    """Take the run directory's lock for the rest of this process (runlog.lock_run_dir)."""
    try:
        lock_run_dir(out)
    except PermissionError as e:
        raise UsageError(f"--out {out}: cannot write there ({e.strerror or e})") from None


def _claim_fresh_dir(out: Path) -> None:
    """Create --out and take its lock; then check again that it is empty (another fresh run may
    have started in it between `_check_fresh_dir` and here)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(f"--out {out}: cannot create the run directory ({e.strerror or e})") from None
    _claim(out)
    if holds_run_files(out):
        raise UsageError(f"{out} exists and is not empty; add --resume to continue that run or choose another --out")


def _check_resume_dir(out: Path) -> None:
    """--resume needs a run directory with a checkpoint that no other run holds; takes its lock."""
    _check_name(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--resume: {out} is not a directory; --out names the run directory")
    if not out.is_dir() or not has_checkpoint(out):
        if out.is_dir() and holds_run_files(out):  # e.g. killed before its first iteration ended
            raise UsageError(f"--resume: {out} holds no checkpoint.pt; remove it or pick another --out to start afresh")
        raise UsageError(f"--resume: no checkpoint.pt in {out}; start the run without --resume")
    _claim(out)  # before reading: the checkpoint read is the one this run continues from


def _clean_stale_temps(out: Path) -> None:
    """Temporary files of a write that a kill interrupted (see atomic_files.atomic_output)."""
    for f in out.glob(".*.tmp*"):
        if any(f.name.startswith(f".{name}.") for name in RUN_FILES):
            f.unlink(missing_ok=True)
    for f in (out / "snapshots").glob(".policy-*.tmp*"):
        f.unlink(missing_ok=True)


# --- starting and resuming -------------------------------------------------------------------


@dataclasses.dataclass
class Run:
    """A run in progress: its trainer and what the loop carries beside it."""

    agent: object
    cur: object  # the waypoint curriculum (curriculum.WaypointCurriculum) or None
    preset: str | None
    elapsed_s: float  # training seconds before this process
    first_success: dict | None


def _curriculum(task: str, agent, state: dict | None = None):
    """The waypoint curriculum of a run (None for the other tasks), restored from `state` (a
    checkpoint's) with the agent's environment set to the radius it had reached."""
    from ..envs.curriculum import CurriculumConfig, WaypointCurriculum

    if state is None and task != "waypoint":
        return None
    cfg = CurriculumConfig.from_json(state["config"]) if state is not None else CurriculumConfig()
    c = agent.cfg
    cur = WaypointCurriculum(cfg, c.num_envs, c.rollout_steps, agent.env_cfg.episode_steps)
    if state is not None:
        cur.load_state_dict(state)
        agent.env.set_target_radius(cur.radius)
    return cur


def start_fresh(args, algo, explicit: dict, out: Path, argv: list[str], algorithms: dict) -> Run:
    from ..envs import make_config
    from ..envs.curriculum import CurriculumConfig

    _check_fresh_dir(out)
    preset = (args.preset or algo.default_preset) if algo.default_preset else None
    source = None
    if getattr(args, "init_from", None) is not None:  # a fine-tune: the file's network and weights
        source, explicit = algo.init_from(args.init_from, explicit, algorithms)
    cfg = options.make_config(algo, explicit, preset)
    env_kw = options.env_kwargs(args)
    if args.task == "waypoint":
        env_kw["target_radius"] = CurriculumConfig().radii[0]
    env_cfg = make_config(args.task, **env_kw)
    try:
        agent = algo(cfg, env_cfg)  # before any file is written: a failure here leaves no half-made run
    except ValueError as e:
        raise UsageError(f"{algo.algo.upper()} configuration: {e}") from None
    started_from = agent.start_from(source, args.init_from) if source is not None else None
    _claim_fresh_dir(out)
    cur = _curriculum(args.task, agent)
    values = {
        "schema": RUN_SCHEMA,
        "algo": algo.algo,
        "task": args.task,
        "preset": preset,
        **agent.run_entries(),
        "env": env_cfg.to_json(),
        "curriculum": cur.cfg.to_json() if cur else None,
        "checkpoint_every": args.checkpoint_every,
        "snapshot_every": args.snapshot_every,
        "eval_episodes": args.eval_episodes,
        "eval_every": args.eval_every,
        "command": command(argv),
        "started": now(),
        "resumes": [],
        "versions": {"torch": torch.__version__, "numpy": np.__version__, "python": sys.version.split()[0]},
        "machine": machine(),
    }
    kept = {k: values[k] for k in algo.run_keys}
    write_json(out / "config.json", kept if started_from is None else {**kept, "init_from": started_from})
    MetricsLog(out / "metrics.csv", algo.columns).close()  # the header, so the file exists from the start
    return Run(agent, cur, preset, 0.0, None)


def resume(args, algo, explicit: dict, out: Path, argv: list[str], algorithms: dict) -> Run:
    _check_resume_dir(out)
    ckpt, used, warning = load_for_resume(out, algorithms)  # CheckpointError: a bad file, exit 1 (cli.main)
    stored_algo = algorithm_of(ckpt, algorithms).algo
    if stored_algo != algo.algo:
        raise UsageError(f"{out} holds a {stored_algo} run; resume it with --algo {stored_algo}")
    if warning:
        print(f"quad-train: warning: {warning}", file=sys.stderr)
    task = ckpt["env_config"]["task"]
    if args.task != task:
        raise UsageError(f"{out} holds a {task} run; --task {args.task} does not match it")
    stored = algo.Config.from_json(ckpt[algo.config_key()])
    extra = ckpt["extra"]
    clashes = options.clashes(args, explicit, stored, extra, ckpt["env_config"])
    if clashes:
        raise UsageError(
            f"a resumed run keeps its configuration; only --total-steps and --threads may change: {', '.join(clashes)}"
        )
    cfg = dataclasses.replace(stored, **{k: v for k, v in explicit.items() if k in options.RESUME_MAY_CHANGE})
    schedule = getattr(cfg, "lr_schedule", "constant")
    if schedule != "constant" and cfg.total_steps != stored.total_steps:
        print(
            f"quad-train: note: the {schedule} learning-rate schedule runs over total_steps; from here on it "
            f"follows the new {cfg.total_steps:,} instead of {stored.total_steps:,}",
            file=sys.stderr,
        )
    _clean_stale_temps(out)
    algo.clean_stale_files(out)
    agent = algo.from_checkpoint(ckpt, cfg, source=str(used), directory=out)
    cur = _curriculum(task, agent, extra.get("curriculum"))
    try:  # metrics.csv cut back to the checkpoint's iterations, the resume recorded in config.json
        dropped = truncate_metrics(out / "metrics.csv", agent.updates, algo.columns)
    except ValueError as e:
        raise UsageError(str(e)) from None
    config_path = out / "config.json"
    config = json.loads(config_path.read_text()) if config_path.exists() else {}
    config[algo.algo] = cfg.to_json()
    resumed = {"command": command(argv), "from": used.name, "update": agent.updates, "at": now()}
    config.setdefault("resumes", []).append({**resumed, "metrics_rows_dropped": dropped})
    write_json(config_path, config)
    print(
        f"quad-train: resuming {out} from {used.name} at {algo.unit} {agent.updates} ({agent.global_step:,} steps)",
        flush=True,
    )
    return Run(agent, cur, extra.get("preset"), float(extra.get("elapsed_s", 0.0)), extra.get("first_success"))


# --- the loop --------------------------------------------------------------------------------


def default_out(task: str, algo, seed: int) -> Path:
    """The run directory without --out: runs/<task>-seed<seed> (SAC's runs/<task>-sac-seed<seed>)."""
    return Path(f"runs/{task}-{algo.tag + '-' if algo.tag else ''}seed{seed}")


def train(args, argv: list[str], algorithms: dict) -> int:
    """`quad-train --algo ppo|sac ...` from parsed flags: start or resume, iterate, finish.
    `algorithms` is the registry (name → Trainer class) that --algo and the checkpoints name."""
    algo = algorithms[args.algo]
    explicit = options.explicit_options(args, algo)
    seed = explicit.get("seed", algo.Config.seed)
    out = Path(args.out) if args.out else default_out(args.task, algo, seed)
    run = (resume if args.resume else start_fresh)(args, algo, explicit, out, argv, algorithms)
    agent, cur, cfg = run.agent, run.cur, run.agent.cfg
    t0 = time.perf_counter()
    eval_s = 0.0  # time spent in periodic evaluations: not training time

    def train_time() -> float:
        return run.elapsed_s + time.perf_counter() - t0 - eval_s

    def extra(metrics: dict | None) -> dict:
        return {
            "preset": run.preset,
            "curriculum": cur.state_dict() if cur else None,
            "metrics": metrics or {},
            "elapsed_s": train_time(),
            "first_success": run.first_success,
            "command": command(argv),
        }

    last: dict | None = None
    saved_at = agent.updates if args.resume else -1
    if args.snapshot_every and agent.updates == 0:
        save_snapshot(out, agent, extra(None))  # the untrained policy: where a learning montage starts
    label = f"quad-train {args.task}" + (f" ({algo.tag})" if algo.tag else "")
    progress = Progress(label, agent.global_step, cfg.num_updates * cfg.batch_size)
    try:
        with Stop() as stop, MetricsLog(out / "metrics.csv", algo.columns) as log:
            while agent.updates < cfg.num_updates and stop.signal is None:
                m = agent.iterate()
                m["time_s"] = train_time()
                run.first_success, dt = evaluate_and_advance(agent, args, cur, m, run.first_success)
                eval_s += dt
                log.write(m)  # the row first: a kill before the save leaves a row the resume drops
                last = m
                end = agent.updates == cfg.num_updates
                if args.snapshot_every and (agent.updates % args.snapshot_every == 0 or end):
                    save_snapshot(out, agent, extra(m))  # before the checkpoint: a resume redoes it, never skips it
                if agent.updates % args.checkpoint_every == 0 or end:
                    agent.save_for_resume(out, extra(m))
                    saved_at = agent.updates
                progress.update(m)
            if saved_at != agent.updates:
                agent.save_for_resume(out, extra(last))
    except KeyboardInterrupt:  # a second Ctrl-C: the last saved checkpoint stands
        progress.close()
        print(f"\nquad-train: aborted; the checkpoint of {algo.unit} {saved_at} in {out} is intact.", file=sys.stderr)
        print(f"Resume with: {command(resume_argv(argv))}", file=sys.stderr)
        return 130
    finally:
        progress.close()
    title = f"{args.task}" + (f" ({algo.tag.upper()})" if algo.tag else "") + f", {out.name}"
    agent.plot_curves(out / "metrics.csv", out / "curves.png", title, cur.cfg.radii if cur else ())
    if stop.signal is not None and agent.updates < cfg.num_updates:
        print(
            f"quad-train: stopped by {stop.signal} after {algo.unit} {agent.updates}/{cfg.num_updates}; "
            f"checkpoint saved in {out / LATEST}.\nResume with: {command(resume_argv(argv))}",
            file=sys.stderr,
        )
        return 130
    save_checkpoint(out / POLICY, agent, extra(last))
    print(time_line(time_breakdown(out / "metrics.csv", algo.columns), eval_s), flush=True)
    done = "done" + (f" ({algo.tag})" if algo.tag else "")
    steps = f"{agent.global_step:,} steps in {agent.updates} {algo.unit}s"
    summary = f"quad-train: {done}, {steps}; policy in {out / POLICY}"
    if args.eval_episodes:

        def meta() -> dict:
            values = {
                "algo": algo.algo,
                "policy": POLICY,
                "global_step": agent.global_step,
                "updates": agent.updates,
                "grad_steps": getattr(agent, "grad_steps", None),
                "train_time_s": extra(last)["elapsed_s"],
                "first_success": run.first_success,
                "time_breakdown_s": time_breakdown(out / "metrics.csv", algo.columns),
            }
            return {k: values[k] for k in algo.eval_keys}

        summary += final_evaluation(agent, args, cur, out, meta)
    print(summary, flush=True)
    return 0


def time_line(breakdown: dict, eval_s: float) -> str:
    """Where the training time went, one line: the rollout (environment and policy inference), the
    update, and this session's periodic evaluations (not counted as training time)."""
    names = {"env_s": "environment", "inference_s": "policy inference", "update_s": "update"}
    fractions = breakdown.get("fractions", {})
    parts = []
    for k, v in breakdown.items():
        if k.endswith("_s") and isinstance(v, (int, float)):
            f = fractions.get(k)
            share = f" ({f:.0%})" if isinstance(f, float) else ""
            parts.append(f"{names.get(k, k.removesuffix('_s'))} {v:.1f} s{share}")
    return f"quad-train: time: {', '.join(parts) or 'not recorded'}; periodic evaluation {eval_s:.1f} s"


def evaluate_and_advance(agent, args, cur, m: dict, first_success: dict | None) -> tuple[dict | None, float]:
    """After an iteration of `agent` with metrics row `m`: every --eval-every iterations, the
    deterministic evaluation into m's eval columns and, the first time it passes SUCCESS_BAR at the
    final curriculum stage, `first_success`; then the curriculum's stage into `m` and its advance on
    the iteration's episodes. Returns (first_success, seconds spent evaluating), the latter not
    counted as training time. `agent` is anything with updates, global_step, act_deterministic and
    env_cfg (and, with a curriculum, ep_success and env): a trainer, or the SB3 baseline's view."""
    from ..envs.evaluate import evaluate

    eval_s = 0.0
    if args.eval_every and agent.updates % args.eval_every == 0:
        te = time.perf_counter()
        r = evaluate(agent.act_deterministic, _eval_config(agent, cur), episodes=args.eval_episodes or 100)
        eval_s = time.perf_counter() - te
        m["eval_success_rate"] = r[SUCCESS_KEY.get(args.task, "success_rate")]
        m["eval_error_m"] = r["mean_error_last_window_m"]
        final_stage = cur is None or cur.stage == len(cur.cfg.radii) - 1
        if first_success is None and final_stage and m["eval_success_rate"] >= SUCCESS_BAR:
            first_success = {
                "global_step": agent.global_step,
                "update": agent.updates,
                "train_time_s": m["time_s"],
                "success_rate": m["eval_success_rate"],
                "episodes": r["episodes"],
            }
    if cur is not None:
        m["curriculum_stage"], m["target_radius"] = cur.stage, cur.radius
        n = int(m["episodes"])
        if cur.observe(agent.ep_success[len(agent.ep_success) - n :] if n else []):
            agent.env.set_target_radius(cur.radius)
    return first_success, eval_s


JUDGED_TIMINGS = {"no_delay": None, "delay_20ms_jitter_10ms": TimingConfig.fixed(20.0, 10.0)}
"""Besides the timing it trained with, what a run trained through delay is judged at (eval.json
"timings"): none, and quad-sitl --link-impair delay=20ms,jitter=10ms."""


def final_evaluation(agent, args, cur, out: Path, meta) -> str:
    """The end-of-run evaluation of `agent` over --eval-episodes episodes, written to eval.json after
    `meta()` (called once the evaluation is done) and the curriculum's final stage; returns the
    summary line's evaluation clause."""
    from ..envs.evaluate import evaluate

    cfg = _eval_config(agent, cur)
    result = evaluate(agent.act_deterministic, cfg, episodes=args.eval_episodes)
    line = f"; evaluation: success {result['success_rate']:.0%} over {args.eval_episodes} episodes"
    if cfg.timing is not None and cfg.timing.active:  # trained through delay: judged without it and at a fixed link
        result["timings"] = {
            name: evaluate(
                agent.act_deterministic, dataclasses.replace(cfg, timing=timing), episodes=args.eval_episodes
            )
            for name, timing in JUDGED_TIMINGS.items()
        }
        line += (
            " ("
            + ", ".join(f"{n.replace('_', ' ')} {r['success_rate']:.0%}" for n, r in result["timings"].items())
            + ")"
        )
    info = meta()
    if cur is not None:
        info.update(curriculum_stage=cur.stage, target_radius=cur.radius)
    write_json(out / "eval.json", {**info, **result})
    return line


def _eval_config(agent, cur):
    """The environment a policy is judged on: the training one, at the radius the waypoint
    curriculum has reached."""
    if cur is None:
        return agent.env_cfg
    return dataclasses.replace(agent.env_cfg, target_radius=cur.radius)


def time_breakdown(metrics_path: Path, columns: tuple[str, ...]) -> dict:
    """Where the training time went, summed over every iteration in metrics.csv (header `columns`):
    the environment (dynamics, observations, rewards, resets), policy inference and bookkeeping
    during rollouts, and the update (PPO's GAE is in the rollout figure)."""
    m = read_metrics(metrics_path, columns)
    parts = {k: float(np.nansum(m[k])) for k in ("env_s", "inference_s", "update_s")}
    total = sum(parts.values())
    return {**parts, "fractions": {k: (v / total if total else None) for k, v in parts.items()}}
