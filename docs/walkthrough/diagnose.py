"""The training runs and the figure of docs/ppo_walkthrough.md ("Diagnosing a run from metrics.csv").

    # a run with PPOConfig fields changed through the library API (quad-train exposes only a few of
    # them as flags); writes metrics.csv (same columns as quad-train) and eval.json into --out
    .venv/bin/python docs/walkthrough/diagnose.py run --out runs/walk-lr5e-2-1m --total-steps 1000000 --set lr=0.05

    # the figure: health columns of several metrics.csv files on shared axes, LABEL=PATH each
    .venv/bin/python docs/walkthrough/diagnose.py plot --out docs/walkthrough/diagnostics.png \
        "defaults (healthy)=runs/walk-hover-1m/metrics.csv" "lr 5e-2 (broken)=runs/walk-lr5e-2-1m/metrics.csv"

The exact commands behind the figure and the tables are in docs/ppo_walkthrough.md, section 9.

`run` uses only the public library API (`PPO`, `PPOConfig`, `make_config`, `MetricsLog`, `evaluate`);
nothing in the library is patched. Without --set it is the default hover run of quad-train (no
periodic evaluation, no checkpoints).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path


def _parse_sets(items: list[str]) -> dict:
    """key=value pairs for PPOConfig fields, each value parsed as the field's default type."""
    from quadpilot.train.ppo import PPOConfig

    defaults = PPOConfig()
    fields = {f.name for f in dataclasses.fields(PPOConfig)}
    out = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or key not in fields:
            raise SystemExit(f"--set {item!r}: expected FIELD=VALUE with FIELD one of {sorted(fields)}")
        default = getattr(defaults, key)
        if isinstance(default, bool):
            if text.lower() not in ("true", "false", "1", "0"):
                raise SystemExit(f"--set {item!r}: {key} is a bool, expected true or false")
            out[key] = text.lower() in ("true", "1")
        elif isinstance(default, int):
            out[key] = int(text)
        elif isinstance(default, float) or default is None:
            out[key] = None if text.lower() == "none" else float(text)
        elif isinstance(default, tuple):
            out[key] = tuple(int(x) for x in text.split(","))
        else:
            out[key] = text
    return out


def run(args: argparse.Namespace) -> int:
    from quadpilot.console import quick
    from quadpilot.train.envs import make_config
    from quadpilot.train.envs.evaluate import evaluate
    from quadpilot.train.ppo import PPO, NonFiniteError, PPOConfig
    from quadpilot.train.runs.runlog import MetricsLog, write_json

    # QUADPILOT_DOCS_QUICK (console.docs_quick): one rollout and two evaluation episodes, as quad-train's
    args.total_steps, args.eval_episodes = quick(args.total_steps, 2048), quick(args.eval_episodes, 2)
    overrides = {"threads": 1, "total_steps": args.total_steps, **_parse_sets(args.set)}
    out = Path(args.out)
    if out.exists() and any(out.iterdir()):
        raise SystemExit(f"{out} exists and is not empty; choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    cfg = PPOConfig(**overrides)
    env_cfg = make_config("hover")
    ppo = PPO(cfg, env_cfg)
    error = None
    t0 = time.perf_counter()
    with MetricsLog(out / "metrics.csv") as log:
        while ppo.updates < cfg.num_updates:
            try:
                m = ppo.iterate()
            except NonFiniteError as e:  # the trainer's own abort: report it like quad-train does
                error = str(e)
                break
            m["time_s"] = time.perf_counter() - t0
            log.write(m)
    result = evaluate(ppo.act_deterministic, env_cfg, episodes=args.eval_episodes)
    write_json(out / "eval.json", {"overrides": overrides, "error": error, "updates": ppo.updates, **result})
    print(
        f"{out}: {ppo.global_step:,} steps, {ppo.updates} updates, {time.perf_counter() - t0:.1f} s; "
        f"evaluation success {result['success_rate']:.0%}, crashes {result['crash_rate']:.0%}"
        + (f"; stopped: {error}" if error else "")
    )
    return 0


PANELS = (
    ("entropy", "entropy (nats, 4 dims)", False),
    ("value_loss", "value_loss", True),
    ("grad_norm", "grad_norm (before clip)", True),
    ("approx_kl", "approx_kl", True),
    ("clip_fraction", "clip_fraction", False),
    ("explained_variance", "explained_variance", False),
    ("ep_return", "ep_return (training)", False),
    ("success_rate", "success_rate (training)", False),
)


def plot(args: argparse.Namespace) -> int:
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from quadpilot.train.runs.runlog import read_metrics

    runs = []
    for item in args.runs:
        label, sep, path = item.partition("=")
        if not sep:
            raise SystemExit(f"{item!r}: expected LABEL=PATH/TO/metrics.csv")
        runs.append((label, read_metrics(path)))
    fig = Figure(figsize=(9, 8.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(4, 2, sharex=True).ravel()
    for ax, (key, title, log) in zip(axes, PANELS, strict=True):
        for i, (label, m) in enumerate(runs):
            y = m[key]
            ok = np.isfinite(y) & ((y > 0) if log else True)
            ax.plot(m["global_step"][ok] / 1e6, y[ok], lw=1.2, color=f"C{i}", label=label)
        if log:
            ax.set_yscale("log")
        if key == "grad_norm":
            ax.axhline(0.5, color="k", lw=0.8, ls="--")  # PPOConfig.max_grad_norm
        ax.set_title(title, fontsize=9)
        ax.tick_params(labelsize=8)
        ax.grid(alpha=0.3)
    for ax in axes[-2:]:
        ax.set_xlabel("environment steps (M)", fontsize=8)
    axes[0].legend(fontsize=7, loc="best")
    out = Path(args.out)
    fig.savefig(out, format="png", dpi=72)
    print(f"{out}: {out.stat().st_size / 1024:.0f} KiB")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="train hover with PPOConfig overrides, write metrics.csv and eval.json")
    r.add_argument("--out", required=True, help="run directory (must be new or empty)")
    r.add_argument("--total-steps", type=int, default=300_000, help="environment steps (default 300,000)")
    r.add_argument("--eval-episodes", type=int, default=100, help="deterministic evaluation episodes at the end")
    r.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="a PPOConfig field; repeatable")
    q = sub.add_parser("plot", help="plot the health columns of metrics.csv files")
    q.add_argument("--out", required=True, help="PNG to write")
    q.add_argument("runs", nargs="+", metavar="LABEL=PATH", help="metrics.csv of each run, with its legend label")
    args = p.parse_args(argv)
    return run(args) if args.cmd == "run" else plot(args)


if __name__ == "__main__":
    sys.exit(main())
