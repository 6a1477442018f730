"""Markdown table of the state-loss flights (docs/robustness.md quotes it, generated).

    .venv/bin/python benchmarks/report_state_loss.py docs/bench/state_loss.json [docs/bench/state_loss_rotorpy.json]
    .venv/bin/python benchmarks/report_state_loss.py docs/bench/state_loss.json --plot docs/media/state_loss.png

One row per simulator, condition and rate: the episodes that met the hover rule (with the Wilson
95 % interval of that share), crashes, landings (the node said landed), the fastest touchdown, the
largest tilt before it, the fastest descent anywhere in the flight, steps flown with every motor off
in the air, and how the node ended the flights. A file may hold its simulator's name (`simulator`);
without one it is ours. `--plot` draws the flight whose trace the first file keeps: height and
vertical speed, the simulator's truth against the node's estimate, with the phases marked.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter
from pathlib import Path


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a share k/n (95 % for z = 1.96)."""
    if n == 0:
        return math.nan, math.nan
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def _max(rows, key: str, fmt: str) -> str:
    vals = [r[key] for r in rows if r.get(key) is not None]
    return format(max(vals), fmt) if vals else "–"


def table(files: list[Path]) -> str:
    lines = [
        "| simulator | IMU | condition | rate (Hz) | hover rule met (95 % interval) | crashes | landed | "
        "touchdown, fastest (m/s) | tilt before it, largest (°) | fastest descent (m/s) | "
        "steps with motors off in the air | how the node ended them |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for path in files:
        data = json.loads(path.read_text())
        sim = data.get("simulator", "ours")
        for cell in data["cells"]:
            rows = cell["episodes"]
            n = len(rows)
            k = sum(r["hover_rule"] for r in rows)
            lo, hi = wilson(k, n)
            ends = Counter(
                f"did not run: {r['failed']}" if "failed" in r else (r["failsafe"] or "flew on") for r in rows
            )
            lines.append(
                f"| {sim} | {cell.get('imu', '–')} | {cell['condition']} | {cell['rate_hz']} | "
                f"{k}/{n} ({lo:.0%}–{hi:.0%}) | "
                f"{sum(r['crashed'] for r in rows)} | {sum('landed' in r['phases'] for r in rows)} | "
                f"{_max(rows, 'touchdown_speed_mps', '.2f')} | {_max(rows, 'touchdown_tilt_deg', '.1f')} | "
                f"{_max(rows, 'max_descent_speed_mps', '.2f')} | "
                f"{sum(r.get('motors_off_airborne_steps', 0) for r in rows)} | "
                + "; ".join(f"{why} ({c})" for why, c in ends.most_common())
                + " |"
            )
    return "\n".join(lines)


def plot(data: dict, out: Path) -> None:
    """Height and vertical speed of the traced flight, truth against estimate, phases marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tr = data["trace"]
    fig, (ax_z, ax_v) = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    ax_z.plot(tr["t_s"], tr["z_m"], color="black", label="simulator: truth")
    ax_z.plot(tr["estimate_t_s"], tr["estimate_z_m"], color="tab:orange", ls="--", label="node: estimate")
    ax_v.plot(tr["t_s"], tr["vz_mps"], color="black")
    ax_v.plot(tr["estimate_t_s"], tr["estimate_vz_mps"], color="tab:orange", ls="--")
    ax_v.axhline(-1.0, color="tab:red", lw=0.8, ls=":", label="goal: no faster than 1 m/s down")
    for t, why in tr["phases"]:
        for ax in (ax_z, ax_v):
            ax.axvline(t, color="tab:blue", lw=0.8, alpha=0.6)
        ax_z.annotate(why.split(":")[0], (t, ax_z.get_ylim()[1]), rotation=90, va="top", ha="right", fontsize=8)
    ax_z.set_ylabel("height (m)")
    ax_v.set_ylabel("vertical speed (m/s)")
    ax_v.set_xlabel("simulated time (s)")
    ax_z.legend(loc="lower left", fontsize=8)
    ax_v.legend(loc="lower left", fontsize=8)
    fig.suptitle(
        f"state lost from 2 s, never back: {tr['rate_hz']} Hz, {tr['imu']} IMU, episode {tr['episode']}", fontsize=10
    )
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("json", type=Path, nargs="+", help="benchmarks/state_loss.py's result (and RotorPy's)")
    p.add_argument("--plot", type=Path, metavar="PNG", help="draw the first file's traced flight here instead")
    args = p.parse_args(argv)
    if args.plot is not None:
        plot(json.loads(args.json[0].read_text()), args.plot)
        print(f"wrote {args.plot}")
        return 0
    print(table(args.json))
    return 0


if __name__ == "__main__":
    sys.exit(main())
