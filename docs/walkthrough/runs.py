"""The runs behind docs/ppo_walkthrough.md section 9 as data: record a run directory's metrics.csv and
eval.json into docs/walkthrough/runs.json, and print the section's tables from that file.

    .venv/bin/python docs/walkthrough/runs.py record --out docs/walkthrough/runs.json reference=runs/walk-hover-1m
    .venv/bin/python docs/walkthrough/runs.py table docs/walkthrough/runs.json reference --updates 1,5,10 --eval

`record` keeps, per run: the command that made it (config.json's; for a diagnose.py run its PPOConfig
overrides from eval.json), seed and torch threads, every metrics.csv row (the training-health columns; the
timing columns are dropped except `time_s`), and the final evaluation. Training health is
deterministic for a seed, thread count and machine; times are not.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

COLUMNS = (
    "global_step",
    "update",
    "time_s",
    "policy_loss",
    "value_loss",
    "entropy",
    "approx_kl",
    "clip_fraction",
    "explained_variance",
    "grad_norm",
    "lr",
    "ep_length",
    "ep_return",
    "success_rate",
    "eval_success_rate",
    "eval_error_m",
)
EVAL_KEYS = ("success_rate", "crash_rate", "mean_length", "mean_error_last_window_m", "first_success")


def _number(text: str):
    if text == "":
        return None
    v = float(text)
    return int(v) if v.is_integer() and "." not in text and "e" not in text.lower() else v


def read_run(run: Path) -> dict:
    try:
        with (run / "metrics.csv").open(newline="") as f:
            rows = [{k: _number(r[k]) for k in COLUMNS if k in r} for r in csv.DictReader(f)]
        ev = json.loads((run / "eval.json").read_text())
    except (OSError, json.JSONDecodeError, ValueError) as e:
        raise SystemExit(f"runs.py: {run}: {e}") from None
    config = json.loads((run / "config.json").read_text()) if (run / "config.json").exists() else {}
    ppo = config.get("ppo", ev.get("overrides", {}))  # diagnose.py records its PPOConfig overrides
    return {
        "command": config.get("command"),
        "overrides": ev.get("overrides"),
        "seed": ppo.get("seed", 0),
        "threads": ppo.get("threads"),
        "train_time_s": ev.get("train_time_s", rows[-1]["time_s"] if rows else None),
        "eval": {k: ev[k] for k in EVAL_KEYS if k in ev},
        "rows": rows,
    }


def _g(v, spec: str = ".3g") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    return format(v, spec)


def table(run: dict, updates: list[int], with_eval: bool, with_lr: bool) -> str:
    by = {r["update"]: r for r in run["rows"]}
    missing = [u for u in updates if u not in by]
    if missing:
        raise SystemExit(f"runs.py: no metrics row for update(s) {missing}")
    head = ["global_step", "update", "policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction"]
    head += ["explained_variance", "grad_norm"] + (["lr"] if with_lr else []) + ["ep_length", "ep_return"]
    head += ["success_rate"] + (["eval_success_rate", "eval_error_m"] if with_eval else [])
    lines = ["| " + " | ".join(head) + " |", "|" + "---:|" * len(head)]
    for u in updates:
        r = by[u]
        cells = []
        for k in head:
            v = r.get(k)
            spec = {
                "global_step": ",d",
                "update": "d",
                "ep_length": ".0f",
                "ep_return": ".1f",
                "success_rate": ".2f",
                "eval_success_rate": ".2f",
                "eval_error_m": ".3f",
            }.get(k, ".3g")
            cells.append(_g(v, spec))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("runs", nargs="+", metavar="NAME=RUN_DIR")
    t = sub.add_parser("table")
    t.add_argument("json", type=Path)
    t.add_argument("name")
    t.add_argument("--updates", required=True, help="comma-separated update numbers")
    t.add_argument("--eval", action="store_true", help="with the periodic evaluation columns")
    t.add_argument("--lr", action="store_true", help="with the learning-rate column")
    args = p.parse_args(argv)
    if args.cmd == "record":
        data = json.loads(args.out.read_text()) if args.out.exists() else {"runs": {}}
        for item in args.runs:
            name, sep, path = item.partition("=")
            if not sep:
                p.error(f"expected NAME=RUN_DIR, got {item!r}")
            data["runs"][name] = read_run(Path(path))
        args.out.write_text(json.dumps(data, indent=1) + "\n")
        return 0
    try:
        data = json.loads(args.json.read_text())
    except (OSError, json.JSONDecodeError) as e:
        print(f"runs.py: cannot read {args.json}: {e}", file=sys.stderr)
        return 1
    if args.name not in data["runs"]:
        print(f"runs.py: no run {args.name!r} in {args.json} (runs: {', '.join(data['runs'])})", file=sys.stderr)
        return 1
    updates = [int(u) for u in args.updates.split(",")]
    print(table(data["runs"][args.name], updates, args.eval, args.lr), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
