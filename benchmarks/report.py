"""Markdown table of drone-steps per second from one run of benchmarks/test_env_speed.py (or, with
--randomized, of benchmarks/test_env_speed_randomized.py).

    .venv/bin/python benchmarks/report.py docs/bench/env_speed.json [--stat min|median|mean] [--strip-data]
    .venv/bin/python benchmarks/report.py docs/bench/env_speed_randomized.json --randomized [--strip-data]

Reads a pytest-benchmark JSON (`--benchmark-json=FILE`) and prints, per N: the raw dynamics step
(float32, float64), the vector env and the vector env of the baseline commit (bb5efb7) in M
drone-steps/s, the vector env's speed relative to that baseline (today ÷ baseline), and the speeds
per drone-step relative to the single-environment loop of the same file, so every ratio comes from
one run. Throughput is n·steps_per_round / round time, the round time being the chosen statistic
(default: the fastest round, the least disturbed by other load on the machine). Then what the
vector env's step leaves allocated (page faults per step, traced memory growth per step and the
largest rise within a step beyond the arrays it returns) and the targets.

--randomized: per N, the vector env without randomisation and with each preset (median round: rounds
differ in how many drones reset), in M drone-steps/s and as a fraction of the unrandomised env.
--strip-data rewrites the JSON without pytest-benchmark's per-round times, small enough for docs/.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

DYNAMICS_TARGET = 10e6  # drone-steps/s at N = 4096 (issue "foundation")
VECTOR_ENV_TARGET = 10e6  # drone-steps/s at N = 4096, bit-identical to the baseline's outputs
RATIO_TARGET = 300.0  # × the single-environment loop, per drone-step
TARGET_N = 4096


def load(path: Path, stat: str) -> dict[tuple[str, str, int], dict]:
    """{(kind, dtype, n): extra_info + {"rate": drone-steps/s, "stat": stat}} from the JSON."""
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise SystemExit(f"cannot read pytest-benchmark JSON {path}: {e}") from None
    out = {}
    for b in data.get("benchmarks", []):
        info = b.get("extra_info", {})
        if not {"kind", "n", "dtype", "steps_per_round"} <= info.keys():
            continue  # some other suite's benchmark
        # a case timed in a child process (the baseline commit's vector env) carries its own round times
        seconds = info["round_s"][stat] if "round_s" in info else b["stats"][stat]
        key = (info["kind"], info["dtype"], int(info["n"]))
        if key in out:
            raise SystemExit(f"{path}: two benchmarks measure {key}; expected one run of test_env_speed.py")
        out[key] = dict(info, rate=info["n"] * info["steps_per_round"] / seconds, name=b["name"])
    if not out:
        raise SystemExit(f"{path} holds no benchmark of benchmarks/test_env_speed.py (no extra_info 'kind')")
    return out


def fmt_rate(r: float | None) -> str:
    return "–" if r is None else f"{r / 1e6:.3g}"


def fmt_ratio(r: float | None) -> str:
    return "–" if r is None or math.isnan(r) else f"{r:,.0f}×" if r >= 10 else f"{r:.2f}×"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("json", type=Path, help="file written by pytest --benchmark-json")
    ap.add_argument("--stat", choices=("min", "median", "mean"), default="min", help="round-time statistic")
    ap.add_argument("--randomized", action="store_true", help="the table of test_env_speed_randomized.py")
    ap.add_argument("--strip-data", action="store_true", help="rewrite the JSON without the per-round times")
    args = ap.parse_args(argv)
    if args.strip_data:
        data = json.loads(args.json.read_text())
        for b in data.get("benchmarks", []):
            b.get("stats", {}).pop("data", None)
        args.json.write_text(json.dumps(data, indent=1) + "\n")
    if args.randomized:
        return randomized(args.json)
    res = load(args.json, args.stat)

    def rate(kind: str, n: int, dtype: str | None = None) -> float | None:
        hits = [v["rate"] for (k, d, m), v in res.items() if k == kind and m == n and dtype in (None, d)]
        return hits[0] if hits else None

    base = rate("single_env", 1)
    ns = sorted({n for (k, _, n) in res if k in ("dynamics", "vector_env")})
    print(f"Round statistic: {args.stat}. Baseline, one gymnasium.make env in a Python loop: ", end="")
    print("not measured" if base is None else f"{base:,.0f} steps/s ({1e6 / base:.1f} µs/step).")
    print()
    print(
        "| N | dynamics f32 (M drone-steps/s) | dynamics f64 (M drone-steps/s) | vector env (M drone-steps/s)"
        " | vector env bb5efb7 (M drone-steps/s) | vector env ÷ bb5efb7 | vector env ÷ single-env loop"
        " | dynamics f32 ÷ single-env loop | dynamics f64 ÷ single-env loop |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n in ns:
        f32, f64, vec = rate("dynamics", n, "float32"), rate("dynamics", n, "float64"), rate("vector_env", n)
        old = rate("vector_env_baseline", n)
        ratio = [None if (r is None or base is None) else r / base for r in (vec, f32, f64)]
        now = None if vec is None or old is None else vec / old
        print(
            f"| {n} | {fmt_rate(f32)} | {fmt_rate(f64)} | {fmt_rate(vec)} | {fmt_rate(old)} | {fmt_ratio(now)} | "
            + " | ".join(fmt_ratio(r) for r in ratio)
            + " |"
        )

    allocs = [v for (k, _, _), v in sorted(res.items(), key=lambda kv: kv[0][2]) if k == "vector_env"]
    if any("traced_growth_bytes_per_step" in v for v in allocs):
        print()
        print("What the vector env's step leaves allocated (after the timed rounds, one block under tracemalloc):")
        for v in allocs:
            print(
                f"- N = {v['n']}: {v.get('page_faults_per_step', float('nan')):.2f} minor page faults per step; "
                f"traced memory {v.get('traced_growth_bytes_per_step', float('nan')):+.0f} bytes per step; "
                f"largest rise within a step beyond the arrays it returns: "
                f"{v.get('traced_peak_beyond_results_bytes', float('nan')):,.0f} bytes"
            )

    faulty = [v for v in res.values() if v.get("page_faults_per_step", 0.0) >= 1.0]
    if faulty:
        print()
        print(
            "Minor page faults per step ≥ 1 (memory handed back to the OS and faulted in again): "
            + ", ".join(f"{v['kind']} {v['dtype']} N={v['n']}: {v['page_faults_per_step']:.0f}" for v in faulty)
            + "."
        )

    print()
    f32, f64, vec = (
        rate("dynamics", TARGET_N, "float32"),
        rate("dynamics", TARGET_N, "float64"),
        rate("vector_env", TARGET_N),
    )
    at, speed, times = (
        f"N = {TARGET_N}",
        f"≥ {DYNAMICS_TARGET / 1e6:.0f} M drone-steps/s",
        f"≥ {RATIO_TARGET:.0f}× the single-env loop",
    )
    checks = [
        (f"dynamics step float32, {at}, {speed}", f32, DYNAMICS_TARGET),
        (f"dynamics step float64, {at}, {speed}", f64, DYNAMICS_TARGET),
        (f"vector env, {at}, ≥ {VECTOR_ENV_TARGET / 1e6:.0f} M drone-steps/s", vec, VECTOR_ENV_TARGET),
    ]
    if base is not None:
        checks += [
            (f"vector env, {at}, {times}", vec, RATIO_TARGET * base),
            (f"dynamics step float32, {at}, {times}", f32, RATIO_TARGET * base),
            (f"dynamics step float64, {at}, {times}", f64, RATIO_TARGET * base),
        ]
    for label, value, bar in checks:
        verdict = "not measured" if value is None else ("met" if value >= bar else "NOT met")
        print(f"- Target {label}: {verdict}")
    return 0


def randomized(path: Path) -> int:
    """The domain-randomisation cost table: median-round M drone-steps/s per N and preset."""
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise SystemExit(f"cannot read pytest-benchmark JSON {path}: {e}") from None
    rate = {}
    for b in data.get("benchmarks", []):
        info = b.get("extra_info", {})
        if str(info.get("kind", "")).startswith("dr:") and "drone_steps_per_s_median" in info:
            rate[(info["kind"][3:], int(info["n"]))] = info["drone_steps_per_s_median"]
    if not rate:
        raise SystemExit(f"{path} holds no benchmark of benchmarks/test_env_speed_randomized.py")
    modes = ("None", "params", "default", "pushes")
    print("| N | off (M drone-steps/s) | `params` | `default` | `pushes` |")
    print("|---:|---:|---:|---:|---:|")
    for n in sorted({n for _, n in rate}):
        off = rate.get(("None", n))
        cells = [fmt_rate(off)]
        for m in modes[1:]:
            r = rate.get((m, n))
            cells.append("–" if r is None else f"{fmt_rate(r)}" + (f" ({r / off:.2f}×)" if off else ""))
        print(f"| {n} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
