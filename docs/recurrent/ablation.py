"""Ablation under sensor noise and motor lag (issue 7): evaluate trained hover runs on a grid of
conditions with the project's one evaluator (100 deterministic episodes, seed 12345, success =
no crash and mean error over the last 2 s ≤ 5 cm) and write a JSON file and Markdown tables. The
committed ablation.json was measured on policies trained before hover success included the heading
(observation layout version 1), under the success rule of that time.

    .venv/bin/python docs/recurrent/ablation.py eval --out docs/recurrent/ablation.json \\
        mlp=runs/issue7/mlp-s0,runs/issue7/mlp-s1,runs/issue7/mlp-s2 \\
        hist3=runs/issue7/hist3-s0,runs/issue7/hist3-s1,runs/issue7/hist3-s2 \\
        lstm=runs/issue7/lstm-s0,runs/issue7/lstm-s1,runs/issue7/lstm-s2
    .venv/bin/python docs/recurrent/ablation.py table docs/recurrent/ablation.json

Conditions: the training one (the seed vehicle's sensor noise, `core.sensor_noise` "seed", and a
30 ms motor time constant), exact states with the same lag, each half of the noise alone (the IMU,
the estimator), twice the noise, and twice the lag.
Through the library API only: `load_policy`, `evaluate`, `EnvConfig`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from quadpilot.core.sensor_noise import get_sensor_noise
from quadpilot.train.algorithms import load_policy
from quadpilot.train.envs.evaluate import evaluate

CONDITIONS = {
    "trained: noise, τ 30 ms": {"noise": 1.0, "tau": 0.03},
    "exact states, τ 30 ms": {"noise": 0.0, "tau": 0.03},
    "IMU noise only": {"noise": 1.0, "tau": 0.03, "estimator": False},
    "estimator noise only": {"noise": 1.0, "tau": 0.03, "imu": False},
    "2× noise, τ 30 ms": {"noise": 2.0, "tau": 0.03},
    "noise, τ 60 ms": {"noise": 1.0, "tau": 0.06},
}
LABELS = {
    "mlp_exact": "MLP trained on exact states, no lag (models/hover before the yaw rule)",
    "mlp": "MLP",
    "hist3": "MLP + history k=3",
    "lstm": "LSTM",
    "lstm2m": "LSTM, 2 M steps (shipped before the yaw rule)",
}


def condition_config(env_cfg, noise: float, tau: float, imu: bool = True, estimator: bool = True):
    spec = None
    if noise > 0:
        spec = get_sensor_noise("seed").with_parts(imu=imu, estimator=estimator)
        spec = spec.scaled(noise) if noise != 1 else spec
    vehicle = dataclasses.replace(env_cfg.params, motor_tau=tau)
    return dataclasses.replace(env_cfg, sensor_noise=spec, vehicle=vehicle)


def eval_runs(groups: dict[str, list[Path]], episodes: int) -> dict:
    torch.set_num_threads(1)
    out: dict = {"episodes": episodes, "conditions": CONDITIONS, "runs": {}}
    for group, dirs in groups.items():
        for d in dirs:
            policy = load_policy(d / "policy.pt")
            trained = json.loads((d / "eval.json").read_text())
            row = {
                "group": group,
                "arch": policy.config.arch,
                "obs_history": policy.config.obs_history,
                "seed": policy.config.seed,
                "steps": trained["global_step"],
                "train_time_s": trained["train_time_s"],
                "first_success": trained.get("first_success"),
                "command": json.loads((d / "config.json").read_text())["command"],
                "results": {},
            }
            for name, c in CONDITIONS.items():
                t0 = time.perf_counter()
                r = evaluate(policy, condition_config(policy.env_config, **c), episodes=episodes)
                row["results"][name] = {
                    k: r[k]
                    for k in ("success_rate", "crash_rate", "mean_error_last_window_m", "max_error_last_window_m")
                }
                err = r["mean_error_last_window_m"]  # None: every episode crashed
                err_text = "– (every episode crashed)" if err is None else f"{err * 100:.2f} cm"
                print(
                    f"{d.name:12s} {name:26s} success {r['success_rate']:.2f} error {err_text} "
                    f"({time.perf_counter() - t0:.1f} s)",
                    flush=True,
                )
            out["runs"][str(d)] = row
    return out


def _cell(values: list, fmt: str) -> str:
    """Mean over seeds (min–max) of the values that exist: a seed whose every episode crashed has no
    error (None) and is left out; "–" when no seed has one."""
    v = np.asarray([x for x in values if x is not None], float)
    if len(v) == 0:
        return "–"
    if len(v) == 1:
        return fmt.format(v[0])
    return f"{fmt.format(v.mean())} ({fmt.format(v.min())}–{fmt.format(v.max())})"


def _cm(value):
    return None if value is None else value * 100


def tables(data: dict) -> str:
    groups: dict[str, list[dict]] = {}
    for row in data["runs"].values():
        groups.setdefault(row["group"], []).append(row)
    conds = list(data["conditions"])
    lines = [
        "Success rate, mean over seeds (min–max), 100 episodes per cell:",
        "",
        "| policy | seeds | " + " | ".join(conds) + " |",
        "|---|---:|" + "---:|" * len(conds),
    ]
    for g, rows in groups.items():
        cells = [_cell([r["results"][c]["success_rate"] * 100 for r in rows], "{:.0f} %") for c in conds]
        lines.append(f"| {LABELS.get(g, g)} | {len(rows)} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Mean position error over the last 2 s (cm) of the episodes that did not crash, mean over seeds (min–max):",
        "",
        "| policy | " + " | ".join(conds) + " |",
        "|---|" + "---:|" * len(conds),
    ]
    for g, rows in groups.items():
        cells = [_cell([_cm(r["results"][c]["mean_error_last_window_m"]) for r in rows], "{:.2f}") for c in conds]
        lines.append(f"| {LABELS.get(g, g)} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Training (the trained condition; eval every 10 updates, 100 episodes):",
        "",
        "| policy | seed | steps | training time | first ≥ 95 % at |",
        "|---|---:|---:|---:|---:|",
    ]
    for g, rows in groups.items():
        for r in rows:
            fs = r["first_success"]
            first = f"{fs['global_step'] / 1e6:.2f} M steps, {fs['train_time_s']:.0f} s" if fs else "not reached"
            lines.append(
                f"| {LABELS.get(g, g)} | {r['seed']} | {r['steps'] / 1e6:.2f} M | {r['train_time_s']:.0f} s | {first} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("eval")
    e.add_argument("--out", type=Path, required=True)
    e.add_argument("--episodes", type=int, default=100)
    e.add_argument("groups", nargs="+", metavar="NAME=DIR[,DIR...]")
    t = sub.add_parser("table")
    t.add_argument("json", type=Path)
    args = p.parse_args(argv)
    if args.cmd == "eval":
        groups = {}
        for g in args.groups:
            name, _, dirs = g.partition("=")
            groups[name] = [Path(x) for x in dirs.split(",")]
        data = eval_runs(groups, args.episodes)
        args.out.write_text(json.dumps(data, indent=1) + "\n")
        print(tables(data))
    else:
        print(tables(json.loads(args.json.read_text())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
