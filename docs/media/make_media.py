"""Regenerate the README's pictures in docs/media/ (about 3 minutes on 2 cores):

    .venv/bin/python docs/media/make_media.py

  hover.gif     the shipped hover policy (models/hover/policy.onnx) flown through quad-sitl
  circle.gif    the shipped circle policy, two laps, flown through quad-sitl
  montage.gif   one start state flown by the untrained, an early and the final policy of a hover
                run trained with --snapshot-every (python -m quadpilot.studies.learning_montage)
  curves.png    that run's learning curves, with the montage's snapshots marked

Every step is an ordinary command of the project, printed before it runs; the training run goes to
--run (default runs/media-hover) and is reused when it has finished. --only picks steps.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MEDIA = Path(__file__).resolve().parent
BIN = Path(sys.executable).parent  # the venv's console scripts sit beside its python
STEPS = ("hover", "circle", "train", "montage", "curves")
MONTAGE_STEPS = "0,120k,1M"  # untrained (crashes), early (survives, ~20 cm off), final (~2 mm)
MONTAGE_SEED = 1  # a start about 1 m from the target
HOVER_SEED = 1  # quad-sitl's start seed: an approach from ~0.8 m, more to see than seed 0's
BUDGET = {".gif": 1_500_000, ".png": 200_000}  # bytes per file, so the README stays light


def run(cmd: list[str]) -> None:
    shown = [str(Path(c).relative_to(ROOT)) if c.startswith(str(ROOT)) else c for c in map(str, cmd)]
    print("$", shlex.join(shown), flush=True)
    subprocess.run([str(c) for c in cmd], cwd=ROOT, check=True)


def sitl(policy: str, out: Path, *extra: str) -> None:
    run([BIN / "quad-sitl", ROOT / policy, "--episodes", "1", "--gcs", "none", "--video", out, *extra])


def train(run_dir: Path) -> None:
    if (run_dir / "eval.json").exists():
        print(f"# {run_dir} has finished: reused (delete it to train again)")
        return
    resume = ["--resume"] if (run_dir / "checkpoint.pt").exists() else []
    run([BIN / "quad-train", "--task", "hover", "--snapshot-every", "5", "--threads", "1", "--out", run_dir, *resume])


def montage(run_dir: Path, out: Path) -> None:
    run(
        [
            sys.executable,
            "-m",
            "quadpilot.studies.learning_montage",
            run_dir,
            "-o",
            out,
            "--steps",
            MONTAGE_STEPS,
            "--seed",
            str(MONTAGE_SEED),
        ]
    )


def curves(run_dir: Path, out: Path) -> None:
    """Episode return and success rate (training episodes and the periodic deterministic
    evaluation) against environment steps, the montage's snapshots as dotted lines."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from quadpilot.studies.learning_montage import nearest_snapshots, parse_steps
    from quadpilot.train.runs.checkpoint import list_snapshots
    from quadpilot.train.runs.runlog import read_metrics

    print(f"# learning curves of {run_dir} → {out}")
    m = read_metrics(run_dir / "metrics.csv")
    ev = json.loads((run_dir / "eval.json").read_text())
    x = m["global_step"] / 1e6
    marks = [s for s, _ in nearest_snapshots(list_snapshots(run_dir), parse_steps(MONTAGE_STEPS))]

    fig = Figure(figsize=(7.2, 2.5), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    ax_ret, ax_succ = fig.subplots(1, 2)
    ax_ret.plot(x, m["ep_return"], lw=1.2, color="tab:blue")
    ax_ret.set_ylabel("episode return", fontsize=8)
    ax_succ.plot(x, m["success_rate"], lw=1.2, color="tab:blue", label="training episodes")
    done = m["eval_success_rate"] == m["eval_success_rate"]  # not NaN: the rows with an evaluation
    ax_succ.plot(x[done], m["eval_success_rate"][done], "o-", ms=2.5, lw=1, color="tab:green", label="evaluation")
    ax_succ.set_ylim(-0.03, 1.03)
    ax_succ.set_ylabel("hover success", fontsize=8)
    ax_succ.legend(loc="lower right", fontsize=7)
    for ax in (ax_ret, ax_succ):
        for s in marks:
            ax.axvline(s / 1e6, color="0.5", ls=":", lw=1)
        ax.set_xlabel("environment steps [M]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    first = ev.get("first_success") or {}
    note = f"hover, 128 drones, 1 torch thread: {ev['global_step'] / 1e6:.2f} M steps in {ev['train_time_s']:.0f} s"
    if first:
        note += f"; 95 % success first at {first['global_step'] / 1e6:.2f} M steps ({first['train_time_s']:.0f} s)"
    fig.suptitle(note + ";\ndotted lines: the montage's snapshots", fontsize=8)
    fig.savefig(out, dpi=100)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1])
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--run", type=Path, default=ROOT / "runs" / "media-hover", help="Training run directory.")
    p.add_argument("--only", default=",".join(STEPS), help=f"Comma-separated steps. Default: {','.join(STEPS)}.")
    args = p.parse_args(argv)
    only = [s.strip() for s in args.only.split(",") if s.strip()]
    unknown = sorted(set(only) - set(STEPS))
    if unknown:
        p.error(f"unknown step(s) {unknown}; known: {', '.join(STEPS)}")
    run_dir = args.run.resolve()
    if "hover" in only:
        sitl("models/hover/policy.onnx", MEDIA / "hover.gif", "--seed", str(HOVER_SEED))
    if "circle" in only:
        sitl("models/circle/policy.onnx", MEDIA / "circle.gif")
    if "train" in only or (("montage" in only or "curves" in only) and not (run_dir / "eval.json").exists()):
        train(run_dir)
    if "montage" in only:
        montage(run_dir, MEDIA / "montage.gif")
    if "curves" in only:
        curves(run_dir, MEDIA / "curves.png")
    over = []
    for f in sorted(MEDIA.glob("*.*")):
        if f.suffix in BUDGET:
            print(f"  {f.relative_to(ROOT)}  {f.stat().st_size / 1e3:,.0f} kB")
            if f.stat().st_size > BUDGET[f.suffix]:
                over.append(f.name)
    if over:
        print(f"warning: over the size budget {BUDGET}: {', '.join(over)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
