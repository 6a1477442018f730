"""Markdown table of batch-1 policy latency from one run of benchmarks/test_policy_latency.py.

    .venv/bin/python benchmarks/report_latency.py docs/bench/policy_latency.json --strip-data

Prints p50 and p99 per case (µs, from the per-call round times), each case's speed-up over torch
eager on the same network in the same run (ratio of p50), and whether the export issue's targets
are met: MLP p50 ≤ 8 µs and p99 ≤ 20 µs on the faster monitored NumPy / ONNX Runtime backend
(validation included) and ≥ 5× faster than torch eager; LSTM monitored step p50 ≤ 25 µs.

Then the C kernel: its own latency from the timing loop in C (median of the repeats),
the ctypes call overhead (the `ctypes_c` p50 minus that), what the c backend's `Policy.act` and the
safety monitor add on top, the target (MLP kernel ≤ 1 µs), and the Cortex-M4F estimate from the
operation count (`quadpilot.ccode.bench.cortex_m4_estimate`; its assumptions are documented in
`ccode.bench.CORTEX_M4_CYCLES`).

pytest-benchmark stores every round's time (about 9 MB for this suite); `--strip-data` rewrites the
file without them (p50/p99 are kept in each benchmark's extra_info), small enough to keep in docs/.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path

MLP_P50, MLP_P99, MLP_SPEEDUP, LSTM_P50 = 8.0, 20.0, 5.0, 25.0
C_KERNEL_US = 1.0
ORDER = (
    "monitored_numpy",
    "monitored_onnxruntime",
    "monitored_c",
    "bare_numpy",
    "bare_onnxruntime",
    "bare_c",
    "ctypes_c",
    "kernel_loop_expf",
    "kernel_loop_tanhf",
    "session_run",
    "torch_eager",
)
LABEL = {
    "monitored_numpy": "NumPy backend + safety monitor",
    "monitored_onnxruntime": "ONNX Runtime backend (I/O binding) + safety monitor",
    "monitored_c": "C backend + safety monitor",
    "bare_numpy": "NumPy backend alone",
    "bare_onnxruntime": "ONNX Runtime backend alone",
    "bare_c": "C backend alone (`Policy.act`)",
    "ctypes_c": "C kernel through ctypes (bare call)",
    "kernel_loop_expf": "C kernel, timing loop in C (median of repeats)",
    "kernel_loop_tanhf": "C kernel with libm `tanhf` (-DQP_USE_TANHF), loop in C",
    "session_run": "plain `InferenceSession.run`",
    "torch_eager": "torch eager, inference_mode (baseline)",
}


def load(path: Path) -> tuple[dict, dict]:
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise SystemExit(f"cannot read pytest-benchmark JSON {path}: {e}") from None
    res: dict[tuple[str, str], dict] = {}
    for b in data.get("benchmarks", []):
        info = b.get("extra_info", {})
        if "p50_us" in info and "case" in info:
            res[(info["net"], info["case"])] = info
    if not res:
        raise SystemExit(f"{path} holds no result of test_policy_latency.py run with --benchmark-enable")
    return res, data.get("machine_info", {})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("json", type=Path, help="file written by pytest --benchmark-json")
    ap.add_argument("--strip-data", action="store_true", help="rewrite the JSON without the per-round times")
    ap.add_argument(
        "--table",
        choices=TABLES,
        help="print only this part (as quoted in docs/benchmarks.md): latency, targets, c (where a c-backend "
        "step's time goes) or m4 (the Cortex-M4F estimate). Default: everything, with the machine.",
    )
    args = ap.parse_args(argv)
    res, machine = load(args.json)
    if args.strip_data:
        data = json.loads(args.json.read_text())
        for b in data.get("benchmarks", []):
            b.get("stats", {}).pop("data", None)
        args.json.write_text(json.dumps(data, indent=1) + "\n")
    if args.table is None:
        cpu = machine.get("cpu", {}).get("brand_raw", platform.processor() or "?")
        print(
            f"Machine: {cpu}, {machine.get('cpu', {}).get('count', '?')} cores; Python {machine.get('python_version')}."
        )
        print()
        for part in TABLES:
            PARTS[part](res)
            print()
    else:
        PARTS[args.table](res)
    return 0


def _latency(res: dict) -> None:
    print("| network | case | p50 (µs) | p99 (µs) | torch eager p50 ÷ this p50 |")
    print("|---|---|---:|---:|---:|")
    for net in ("mlp", "lstm"):
        base = res.get((net, "torch_eager"), {}).get("p50_us")
        for case in ORDER:
            r = res.get((net, case))
            if r is None:
                continue
            ratio = "–" if base is None else f"{base / r['p50_us']:.1f}×"
            p99 = f"{r['p99_us']:.2f}" if "p99_us" in r else "–"
            print(f"| {net} | {LABEL[case]} | {r['p50_us']:.2f} | {p99} | {ratio} |")


def _targets(res: dict) -> None:
    monitored = [res[("mlp", c)] for c in ("monitored_numpy", "monitored_onnxruntime") if ("mlp", c) in res]
    if monitored:
        best = min(monitored, key=lambda r: r["p50_us"])
        base = res.get(("mlp", "torch_eager"), {}).get("p50_us")
        checks = [
            (f"MLP p50 ≤ {MLP_P50:g} µs ({best['case']})", best["p50_us"] <= MLP_P50, f"{best['p50_us']:.2f} µs"),
            (f"MLP p99 ≤ {MLP_P99:g} µs ({best['case']})", best["p99_us"] <= MLP_P99, f"{best['p99_us']:.2f} µs"),
        ]
        if base is not None:
            speedup = base / best["p50_us"]
            checks.append((f"MLP ≥ {MLP_SPEEDUP:g}× torch eager", speedup >= MLP_SPEEDUP, f"{speedup:.1f}×"))
        lstm = [res[("lstm", c)] for c in ("monitored_numpy", "monitored_onnxruntime") if ("lstm", c) in res]
        if lstm:
            lb = min(lstm, key=lambda r: r["p50_us"])
            checks.append(
                (f"LSTM step p50 ≤ {LSTM_P50:g} µs ({lb['case']})", lb["p50_us"] <= LSTM_P50, f"{lb['p50_us']:.2f} µs")
            )
        for label, ok, value in checks:
            print(f"- Target {label}: {'met' if ok else 'NOT met'} ({value})")
    mlp = res.get(("mlp", "kernel_loop_expf"))
    if mlp is not None:
        us = mlp["p50_us"]
        print(
            f"- Target MLP kernel ≤ {C_KERNEL_US:g} µs (loop in C): {'met' if us <= C_KERNEL_US else 'NOT met'} "
            f"({us * 1e3:.0f} ns; min of {mlp['repeats']} repeats {mlp['min_us'] * 1e3:.0f} ns)"
        )
        print(f"- Built with: {_compile_flags(mlp.get('compile', '?'))}")


def _compile_flags(cmd: str) -> str:
    """The compiler flags of the timing build, without its temporary paths."""
    return " ".join(w for w in cmd.split() if w.startswith("-") and w != "-o")


def _report_c(res: dict) -> None:
    """The C kernel's figures: own latency, ctypes overhead, what the backend and monitor add."""
    if not any(case == "kernel_loop_expf" for _, case in res):
        return
    print(
        "| network | C kernel, loop in C (ns) | through ctypes (ns) | ctypes overhead (ns) | "
        "+ `Policy.act` (ns) | + safety monitor (ns) |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for net in ("mlp", "lstm"):
        loop = res.get((net, "kernel_loop_expf"))
        if loop is None:
            continue
        kernel = loop["p50_us"] * 1e3
        cells = [f"{kernel:.0f}"]
        prev = kernel
        for case in ("ctypes_c", "bare_c", "monitored_c"):
            r = res.get((net, case))
            if r is None:
                cells.append("–")
                continue
            t = r["p50_us"] * 1e3
            cells.append(f"{t:.0f} (+{t - prev:.0f})" if case != "ctypes_c" else f"{t:.0f}")
            if case == "ctypes_c":
                cells.append(f"{t - kernel:.0f}")
            prev = t
        print(f"| {net} | " + " | ".join(cells) + " |")


def _report_m4(res: dict) -> None:
    """The Cortex-M4F estimate from the operation count (not a measurement on hardware)."""
    if not any(case == "kernel_loop_expf" for _, case in res):
        return
    print("| network | MACs | tanh | expf (σ) | div | sqrt | weights (KiB) | cycles | µs at 168 MHz |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for net in ("mlp", "lstm"):
        loop = res.get((net, "kernel_loop_expf"))
        if loop is None or "operations" not in loop:
            continue
        ops, m4 = loop["operations"], loop["cortex_m4"]
        print(
            f"| {net} | {ops['mac']:,} | {ops['tanh']} | {ops['expf']} | {ops['div']} | {ops['sqrtf']} | "
            f"{4 * ops['weights'] / 1024:.1f} | {m4['cycles_low']:,.0f}–{m4['cycles_high']:,.0f} | "
            f"{m4['us_low']:.0f}–{m4['us_high']:.0f} |"
        )


TABLES = ("latency", "targets", "c", "m4")
PARTS = {"latency": _latency, "targets": _targets, "c": _report_c, "m4": _report_m4}


if __name__ == "__main__":
    sys.exit(main())
