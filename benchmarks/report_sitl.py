"""Markdown tables of the SITL speed and real-time jitter benchmarks from one run of
benchmarks/test_sitl_speed.py.

    .venv/bin/python benchmarks/report_sitl.py docs/bench/sitl_speed.json [--strip-data]

Lockstep: control steps per second of each backend (steps per round / mean round time), as a
ratio to real time at 100 Hz and to the in-process loop of the same run; target ≥ 2,000 steps/s.
Against bb5efb7: that commit's node and simulator and today's, flown side by side in alternating
rounds (the same policy file and episode), each version's steps/s from its own round times, and
their ratio; target ≥ 2× (SPEEDUP_TARGET) on an idle machine. With them, today's code with the
lockstep spin off, and the same three with one CPU kept busy by another process.
Real time: loop-period jitter |period − dt| at the node and at the simulator, p50/p99/max; target
p99 ≤ 1 ms at 100 Hz and 250 Hz.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

STEPS_TARGET, JITTER_TARGET_MS = 2000.0, 1.0
SPEEDUP_TARGET = 2.0
"""Lockstep steps/s of today's code over bb5efb7's, measured side by side."""


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("json", type=Path)
    p.add_argument(
        "--strip-data",
        action="store_true",
        help="rewrite the file without per-round data, with each loop's control steps/s and its ratio to the "
        "in-process loop in extra_info (steps_per_s, vs_in_process)",
    )
    p.add_argument(
        "--table",
        choices=("speed", "baseline", "jitter", "targets"),
        help="print only this part (as quoted in docs/benchmarks.md). Default: everything, with the machine.",
    )
    args = p.parse_args(argv)
    try:
        doc = json.loads(args.json.read_text())
    except (OSError, json.JSONDecodeError) as e:
        print(f"report_sitl: cannot read {args.json}: {e}", file=sys.stderr)
        return 2
    by = {b["name"]: b for b in doc["benchmarks"]}
    rate = {}
    for name, b in by.items():
        if "steps_per_round" in b["extra_info"]:
            rate[name] = b["extra_info"]["steps_per_round"] / b["stats"]["mean"]
    base = rate.get("test_in_process_baseline")
    m = doc.get("machine_info", {})
    show = (lambda part: True) if args.table is None else (lambda part: part == args.table)
    if args.table is None:
        print(
            f"Machine: {m.get('cpu', {}).get('brand_raw', m.get('processor', '?'))}, {m.get('system')} "
            f"{m.get('release')}, Python {m.get('python_version')}; {doc.get('datetime', '')[:19]}\n"
        )
    if show("speed"):
        _speed(by, rate, base)
    if show("baseline"):
        if args.table is None:
            print()
        _vs_baseline(by)
    if show("jitter"):
        if args.table is None:
            print()
        worst = _jitter(by)
    else:
        worst = max(
            (
                max(b["extra_info"]["node_jitter_p99_ms"], b["extra_info"]["sim_jitter_p99_ms"])
                for n, b in by.items()
                if n.startswith("test_realtime_loop_jitter")
            ),
            default=0.0,
        )
    if show("targets"):
        if args.table is None:
            print()
        _targets(rate, worst, by)
    if args.strip_data:
        for b in doc["benchmarks"]:
            b["stats"].pop("data", None)
            if b["name"] in rate:  # the figure docs quote, kept with the data it comes from
                b["extra_info"]["steps_per_s"] = rate[b["name"]]
                if base:
                    b["extra_info"]["vs_in_process"] = rate[b["name"]] / base
        args.json.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


def _speed(by: dict, rate: dict, base: float | None) -> None:
    print(
        "| loop | control steps/s (mean of 5 × 2,000) | × real time (100 Hz) | vs in-process | node latency p50 / p99 |"
    )
    print("|---|---:|---:|---:|---:|")
    for name in (
        "test_lockstep_closed_loop[numpy]",
        "test_lockstep_closed_loop[onnxruntime]",
        "test_in_process_baseline",
    ):
        if name not in by:
            continue
        info = by[name]["extra_info"]
        if name == "test_in_process_baseline":
            label = "in process, no wire (baseline)"
        else:
            label = "SITL lockstep, " + name.split("[")[1].rstrip("]") + " backend"
        lat = (
            f"{info['node_latency_p50_us']:.0f} / {info['node_latency_p99_us']:.0f} µs"
            if "node_latency_p50_us" in info
            else "—"
        )
        ratio = f"{rate[name] / base:.2f}" if base else "—"
        print(f"| {label} | {rate[name]:,.0f} | {rate[name] / 100:.1f}× | {ratio} | {lat} |")


def _vs_baseline(by: dict) -> None:
    print(
        "| machine | lockstep, node and simulator of | control steps/s (5 × 2,000, alternating) | "
        "node latency p50 | × bb5efb7 | load average before / after |"
    )
    print("|---|---|---:|---:|---:|---|")
    for name, b in sorted(by.items()):
        if not name.startswith("test_lockstep_vs_baseline"):
            continue
        i = b["extra_info"]
        machine = {"idle": "idle", "busy": "one CPU kept busy"}.get(i.get("load"), "?")
        load = " / ".join(f"{x[0]:.2f}" for x in i.get("load_average_1_5_15", []))
        print(
            f"| {machine} | {i['baseline_commit']} | {i['baseline_steps_per_s']:,.0f} | "
            f"{i['baseline_latency_p50_us']:.0f} µs | 1.00 | {load} |"
        )
        print(
            f"| | today, spin off | {i['today_no_spin_steps_per_s']:,.0f} | "
            f"{i['today_no_spin_latency_p50_us']:.0f} µs | {i['no_spin_vs_baseline']:.2f} | |"
        )
        print(
            f"| | today | {i['today_steps_per_s']:,.0f} | {i['today_latency_p50_us']:.0f} µs | "
            f"{i['vs_baseline']:.2f} | |"
        )
    print(
        "\nNode latency as each version logs it: bb5efb7's ends after the command's send, today's where the "
        "command is handed to the socket (on one CPU the woken simulator may run inside the send). "
        "Spin off: `--spin-us 0` for both sides."
    )


def _jitter(by: dict) -> float:
    print("| real time | steps | node jitter p50 / p99 / max | simulator jitter p50 / p99 / max | overruns |")
    print("|---|---:|---:|---:|---:|")
    worst = 0.0
    for hz in (100, 250):
        b = by.get(f"test_realtime_loop_jitter[{hz}]")
        if b is None:
            continue
        i = b["extra_info"]
        worst = max(worst, i["node_jitter_p99_ms"], i["sim_jitter_p99_ms"])
        print(
            f"| {hz} Hz | {i['steps']} | {i['node_jitter_p50_ms']:.3f} / {i['node_jitter_p99_ms']:.3f} / "
            f"{i['node_jitter_max_ms']:.2f} ms | {i['sim_jitter_p50_ms']:.3f} / {i['sim_jitter_p99_ms']:.3f} / "
            f"{i['sim_jitter_max_ms']:.2f} ms | {i['sim_overruns']} |"
        )
    return worst


def _targets(rate: dict, worst: float, by: dict) -> None:
    lock = [v for k, v in rate.items() if k.startswith("test_lockstep_closed_loop")]
    if lock:
        ok = min(lock) >= STEPS_TARGET
        print(
            f"- Lockstep ≥ {STEPS_TARGET:,.0f} steps/s on both backends: {'**met**' if ok else '**not met**'} "
            f"(slowest {min(lock):,.0f})."
        )
    vs = {
        b["extra_info"].get("load"): b["extra_info"] for n, b in by.items() if n.startswith("test_lockstep_vs_baseline")
    }
    if "idle" in vs:
        r = vs["idle"]["vs_baseline"]
        print(
            f"- Lockstep ≥ {SPEEDUP_TARGET:g}× bb5efb7's, side by side on an idle machine: "
            f"{'**met**' if r >= SPEEDUP_TARGET else '**not met**'} ({r:.2f}×)."
        )
    if "busy" in vs:
        i = vs["busy"]
        print(
            f"- With one CPU kept busy: {i['vs_baseline']:.2f}× bb5efb7's with the spin, "
            f"{i['no_spin_vs_baseline']:.2f}× with it off (no target)."
        )
    print(
        f"- Real-time jitter p99 ≤ {JITTER_TARGET_MS} ms at 100 and 250 Hz: "
        f"{'**met**' if worst <= JITTER_TARGET_MS else '**not met**'} (worst p99 {worst:.3f} ms)."
    )


if __name__ == "__main__":
    sys.exit(main())
