"""A learning montage: one start state flown by the early, middle and final policies of a training
run, side by side in one GIF.

    quad-train --task hover --snapshot-every 5 --out runs/hover-montage
    python -m quadpilot.studies.learning_montage runs/hover-montage -o montage.gif

Reads the run's snapshots (`RUN/snapshots/policy-<steps>.pt`, written by quad-train
--snapshot-every), picks --snapshots of them evenly from the first (the untrained policy, 0 steps)
to the last (or, with --steps, the ones nearest the given step counts), and flies each
deterministically (the mean action, as evaluation does) on the training environment's `QuadBatch`
(the `core` dynamics, nominal plant) from the same start state, drawn with --seed from the task's
start distribution. The panels are titled with the snapshot's training steps and its result: the
mean position error over the last `success_window` seconds, or when it crashed. Drawing is
`quadpilot.viz.render_montage`; the video lasts as long as the longest flight.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

from quadpilot.console import BadFile, Parser, UsageError, run_command
from quadpilot.train.cli import int_at_least


def pick_snapshots(snapshots: list[tuple[int, Path]], k: int) -> list[tuple[int, Path]]:
    """k of `snapshots` (sorted by steps), evenly spaced by position, always the first and the
    last (all of them when there are no more than k)."""
    if k < 1:
        raise ValueError(f"need at least one snapshot, asked for {k}")
    if len(snapshots) <= k:
        return list(snapshots)
    if k == 1:
        return [snapshots[-1]]
    idx = np.unique(np.round(np.linspace(0, len(snapshots) - 1, k)).astype(int))
    return [snapshots[i] for i in idx]


def nearest_snapshots(snapshots: list[tuple[int, Path]], steps: list[int]) -> list[tuple[int, Path]]:
    """For each of `steps`, the snapshot with the nearest step count (each snapshot once, in the
    order asked)."""
    chosen: list[tuple[int, Path]] = []
    for want in steps:
        best = min(snapshots, key=lambda s: abs(s[0] - want))
        if best not in chosen:
            chosen.append(best)
    return chosen


def parse_steps(text: str) -> list[int]:
    """ "0,120k,1M" → [0, 120000, 1000000]."""
    scale = {"k": 1_000, "m": 1_000_000}
    out = []
    for item in text.split(","):
        item = item.strip().lower().replace("_", "")
        try:
            value = float(item[:-1]) * scale[item[-1]] if item[-1:] in scale else float(item)
        except (ValueError, IndexError):
            raise argparse.ArgumentTypeError(f"expected step counts like 0,120k,1M, got {text!r}") from None
        if not (math.isfinite(value) and value >= 0):
            raise argparse.ArgumentTypeError(f"step counts must be ≥ 0, got {item!r}")
        out.append(round(value))
    return out


def flight_config(policy, seconds: float | None = None):
    """The environment a snapshot is flown in: its training environment without domain
    randomisation (the nominal plant), the waypoint radius its curriculum had reached, and an
    episode of `seconds` (default: the training episode)."""
    cfg = policy.env_config
    changes = {}
    if getattr(cfg, "randomization", None) is not None:
        changes["randomization"] = None
    cur = (policy.extra or {}).get("curriculum")
    if cur:
        from quadpilot.train.envs.curriculum import CurriculumConfig

        changes["target_radius"] = CurriculumConfig.from_json(cur["config"]).radii[int(cur["stage"])]
    if seconds is not None:
        changes["episode_steps"] = max(1, round(seconds / cfg.dt))
    return dataclasses.replace(cfg, **changes) if changes else cfg


def fly(policy, env_cfg, seed: int = 0, label: str = ""):
    """Fly `policy` (a `TrainedPolicy`, deterministic) for one episode of `env_cfg` from the start
    state `seed` draws. Returns (FlightTrace, result): the trace holds the state before every step,
    the motor command of that step and the target, plus the state after the last step (a crash
    ends the episode there); result = {"crashed_at_s": s or None, "mean_error_m": over the last
    `success_window` seconds, or of the whole flight when it crashed sooner}."""
    from quadpilot.core import dynamics
    from quadpilot.train.envs import QuadBatch
    from quadpilot.viz import FlightTrace

    batch = QuadBatch(env_cfg, 1)
    batch.reset(np.ones(1, bool), np.random.default_rng(seed))
    dt = env_cfg.dt
    hidden = policy.initial_state(1) if policy.recurrent else None
    t, states, commands, targets, errors = [], [], [], [], []
    crashed_at = None
    for k in range(env_cfg.episode_steps):
        obs = batch.obs.copy()
        if hidden is not None:
            action, hidden = policy.step(obs, hidden)
        else:
            action = policy(obs)
        action = np.asarray(action, dtype=batch.dtype)
        t.append(k * dt)
        states.append(batch.state[0].copy())
        commands.append(dynamics.action_to_command(action, batch.u_hover)[0])
        targets.append(batch.target[0].copy())
        _, _, terminated, _, err = batch.step(action)
        errors.append(float(err[0]))
        if terminated[0]:
            crashed_at = (k + 1) * dt
            break
    t.append(len(t) * dt)  # the state the last command led to
    states.append(batch.state[0].copy())
    commands.append(commands[-1])
    targets.append(batch.target[0].copy())
    targets = np.asarray(targets, dtype=np.float64)
    target = targets[0] if np.all(targets == targets[0]) else targets  # a star, or a moving dot
    trace = FlightTrace(np.asarray(t), np.asarray(states), np.asarray(commands), target, label=label)
    window = errors[-env_cfg.success_steps :]
    return trace, {"crashed_at_s": crashed_at, "mean_error_m": float(np.mean(window))}


def steps_text(steps: int) -> str:
    """0 → "0 steps", 40960 → "41k steps", 1007616 → "1.01M steps"."""
    if steps >= 1_000_000:
        return f"{steps / 1e6:.2f}M steps"
    if steps >= 1_000:
        return f"{steps / 1e3:.0f}k steps"
    return f"{steps} steps"


def result_text(result: dict, window_s: float) -> str:
    if result["crashed_at_s"] is not None:
        return f"crashed at {result['crashed_at_s']:.2f} s"
    return f"error {100 * result['mean_error_m']:.1f} cm (last {window_s:g} s)"


def build_parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="python -m quadpilot.studies.learning_montage",
        description=__doc__.split("\n\n")[0],
        epilog="\n\n".join(__doc__.split("\n\n")[1:]),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        allow_abbrev=False,
    )
    p.add_argument("run", type=Path, metavar="RUN_DIR", help="A quad-train run directory with snapshots/.")
    p.add_argument("-o", "--out", type=Path, metavar="OUT.gif", help="Where to write. Default: RUN_DIR/montage.gif.")
    pick = p.add_mutually_exclusive_group()
    pick.add_argument(
        "--snapshots",
        type=int_at_least(1, 64),
        default=3,
        metavar="K",
        help="Snapshots to show, evenly spaced from the first to the last. Default: 3.",
    )
    pick.add_argument(
        "--steps",
        type=parse_steps,
        metavar="LIST",
        help="Show instead the snapshots nearest these training steps, e.g. 0,120k,1M.",
    )
    p.add_argument(
        "--seed",
        type=int_at_least(0, 2**63 - 1),
        default=0,
        help="Seed of the start state every snapshot flies from. Default: 0.",
    )
    p.add_argument("--seconds", type=float, metavar="S", help="Seconds to fly. Default: the training episode (5 s).")
    p.add_argument("--fps", type=int_at_least(1, 120), default=20, help="Frames per second (≤ 120). Default: 20.")
    p.add_argument(
        "--size",
        default="720x320",
        metavar="WxH",
        help="Size in pixels of the whole montage. Default: 720x320.",
    )
    return p


MAX_PIXELS = 4096  # per side of the montage; a frame of 4096² is 50 MB of RGB
MAX_SECONDS = 600.0


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise UsageError(f"--size must be WIDTHxHEIGHT in pixels, e.g. 720x320, got {text!r}") from None
    if not (16 <= w <= MAX_PIXELS and 16 <= h <= MAX_PIXELS):
        raise UsageError(f"--size {text}: each side must be 16 to {MAX_PIXELS} pixels")
    return w, h


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_command("quadpilot.studies.learning_montage", lambda: _montage(build_parser().parse_args(argv)))


def _montage(args) -> int:
    import torch

    from quadpilot.console import check_output_path
    from quadpilot.train.algorithms import load_policy
    from quadpilot.train.runs.checkpoint import CheckpointError, list_snapshots
    from quadpilot.viz import VizUnavailable, check_video_output, render_montage

    size = _size(args.size)
    if args.seconds is not None and not (math.isfinite(args.seconds) and 0 < args.seconds <= MAX_SECONDS):
        raise UsageError(f"--seconds must be a positive number of at most {MAX_SECONDS:g}, got {args.seconds}")
    out = args.out or args.run / "montage.gif"
    try:
        check_video_output(out)
    except (ValueError, VizUnavailable) as e:
        raise UsageError(str(e)) from None
    if not args.run.is_dir():
        raise UsageError(f"{args.run} is not a directory; expected a quad-train run directory")
    try:
        check_output_path(out, "--out")
    except ValueError as e:
        raise UsageError(str(e)) from None
    found = list_snapshots(args.run)
    if not found:
        raise UsageError(
            f"{args.run / 'snapshots'} holds no policy-<steps>.pt; train with quad-train ... --snapshot-every N"
        )
    chosen = nearest_snapshots(found, args.steps) if args.steps else pick_snapshots(found, args.snapshots)
    torch.set_num_threads(1)  # one drone: threads only cost
    try:
        policies = [(steps, load_policy(path)) for steps, path in chosen]
    except CheckpointError as e:  # a snapshot that cannot be used: a bad file, exit 1
        raise BadFile(str(e)) from None
    cfg = flight_config(policies[-1][1], args.seconds)  # one environment for all: the final policy's
    traces, labels = [], []
    print(f"montage of {args.run}: {len(chosen)} of {len(found)} snapshots, start seed {args.seed}")
    for steps, policy in policies:
        trace, result = fly(policy, cfg, args.seed, label=steps_text(steps))
        updates = int(policy.extra.get("metrics", {}).get("update", 0)) if policy.extra else 0
        head = f"update {updates} · {steps_text(steps)}" if steps else "untrained · 0 steps"
        labels.append(f"{head}\n{result_text(result, cfg.success_window)}")
        traces.append(trace)
        print(f"  {labels[-1].replace(chr(10), ': ')}")
    try:
        render_montage(traces, labels, out, fps=args.fps, arm_length=cfg.params.arm, size_px=size)
    except (ValueError, VizUnavailable) as e:
        raise UsageError(str(e)) from None
    print(f"  written {out} ({out.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
