"""Markdown table of the RAPTOR GRU step latency from one run of benchmarks/test_gru_step.py.

    .venv/bin/python benchmarks/report_gru.py docs/bench/gru_step.json --strip-data

Prints p50 and p99 per case (µs, from the per-call round times) and each case's p50 as a ratio of
RAPTOR's own package step (foundation_policy, NumPy) measured in the same run, and whether the
target is met: the NumPy GRU step p50 ≤ 30 µs. `--strip-data` rewrites the file without the
per-round times (p50/p99 are kept in extra_info).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

TARGET_C_P50_US = 5.0  # the C step's goal, a ctypes call from Python included
TARGET_P50_US = 30.0
LABEL = {
    "gru_numpy": "NumPy GRU step (`runtime.gru.GruStep`)",
    "gru_onnxruntime": "ONNX graph in ONNX Runtime (`OnnxGruStep`)",
    "gru_c": "generated C through ctypes (`runtime.cgru.CGruStep`)",
    "executor_numpy": "NumPy step in mc_raptor's executor (`RaptorPolicy.act`)",
    "node_step_numpy": "the node's per-step work: contract observation + safety monitor + executor",
    "package": "RAPTOR's own package, `foundation_policy` `evaluate_step` (baseline)",
}


def load(path: Path) -> tuple[dict, dict]:
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise SystemExit(f"cannot read pytest-benchmark JSON {path}: {e}") from None
    res = {b["extra_info"]["case"]: b["extra_info"] for b in data.get("benchmarks", []) if "p50_us" in b["extra_info"]}
    if "package" not in res:
        raise SystemExit(f"{path} holds no baseline of test_gru_step.py run with --benchmark-enable")
    return res, data


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("json", type=Path)
    ap.add_argument("--strip-data", action="store_true", help="rewrite the JSON without the per-round times")
    args = ap.parse_args(argv)
    res, data = load(args.json)
    if args.strip_data:
        for b in data["benchmarks"]:
            b.get("stats", {}).pop("data", None)
        args.json.write_text(json.dumps(data, indent=1) + "\n")
    base = res["package"]["p50_us"]
    print("| step | p50 µs | p99 µs | p50 / package p50 |")
    print("|---|---:|---:|---:|")
    for case, label in LABEL.items():
        if case in res:
            r = res[case]
            print(f"| {label} | {r['p50_us']:.1f} | {r['p99_us']:.1f} | {r['p50_us'] / base:.2f} |")
    p50 = res["gru_numpy"]["p50_us"]
    verdict = "met" if p50 <= TARGET_P50_US else "NOT met"
    print(f"\nTarget NumPy GRU step p50 ≤ {TARGET_P50_US:g} µs: {p50:.1f} µs, {verdict}.")
    if "gru_c" in res:
        c = res["gru_c"]["p50_us"]
        c_verdict = "met" if c <= TARGET_C_P50_US else "NOT met"
        print(f"Target C GRU step p50 ≤ {TARGET_C_P50_US:g} µs: {c:.1f} µs, {c_verdict}.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
