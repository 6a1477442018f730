"""Markdown tables of the emulated Cortex-M measurements of benchmarks/embedded.py.

    .venv/bin/python benchmarks/report_embedded.py docs/bench/embedded.json [--table NAME]

NAME is footprint, instructions, stages or goals (default: all, with the toolchain).

footprint: flash by part (policy.o, the libm code it calls, harness.o with the golden vectors and
the semihosting I/O, newlib-nano's libc and libgcc, alignment) and RAM (.data, .bss, the stack
high-water mark of the run and of one kernel call). instructions: per step (mean, min, max over
the run), -Os beside -O2 for the MLP, and the operation-count cycle estimate with its assumption.
stages: instructions per stage of one step (a build with the kernel's probes). goals: the hover
MLP's targets on the Cortex-M4F and what was reached.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

CORE = {"cortex-m4f": "Cortex-M4F", "cortex-m7": "Cortex-M7"}
MODEL = {"hover": "hover MLP", "hover_lstm": "hover LSTM"}


def footprint(doc: dict) -> list[str]:
    rows = [
        "| model | core | policy.c | libm | harness | libc + libgcc | flash total | .data | .bss "
        "| stack (run / kernel) | RAM total |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in doc["results"]:
        f = r["flash_bytes"]
        rows.append(
            f"| {MODEL[r['model']]} | {CORE[r['target']]} | {f.get('policy', 0):,} B | {f.get('libm', 0):,} B | "
            f"{f.get('harness', 0):,} B | {f.get('libc', 0) + f.get('libgcc', 0):,} B | {r['image_flash_bytes']:,} B | "
            f"{r['data_bytes']:,} B | {r['bss_bytes']:,} B | {r['stack_high_water_bytes']:,} / "
            f"{r['kernel_stack_bytes']:,} B | {r['ram_bytes']:,} B |"
        )
    return rows


def instructions(doc: dict) -> list[str]:
    rows = [
        "| model | core | instructions per step, -O2: mean (min–max) | -Os: mean | "
        "Cortex-M4F cycle estimate from the operation count |",
        "|---|---|---:|---:|---:|",
    ]
    for r in doc["results"]:
        i = r["instructions"]
        os_ = f"{r['os']['instructions']['mean']:,.0f}" if "os" in r else "–"
        est = r["cortex_m4_estimate"]
        cycles = f"{est['cycles_low']:,.0f}–{est['cycles_high']:,.0f}" if r["target"] == "cortex-m4f" else "–"
        rows.append(
            f"| {MODEL[r['model']]} | {CORE[r['target']]} | {i['mean']:,.0f} ({i['min']:,.0f}–{i['max']:,.0f}) | "
            f"{os_} | {cycles} |"
        )
    return rows


def stages(doc: dict) -> list[str]:
    rows = ["| model | core | stage | instructions | share |", "|---|---|---|---:|---:|"]
    for r in doc["results"]:
        for s in r["stages"]:
            rows.append(
                f"| {MODEL[r['model']]} | {CORE[r['target']]} | {s['stage']} | {s['instructions']:,.0f} | "
                f"{100 * s['share']:.1f} % |"
            )
    return rows


def goals(doc: dict) -> list[str]:
    g = doc["goals_hover_mlp"]
    rows = ["| hover MLP | goal | Cortex-M4F | Cortex-M7 | met on the M4F |", "|---|---:|---:|---:|---|"]
    by = {r["target"]: r for r in doc["results"] if r["model"] == "hover"}
    items = (
        ("policy flash (policy.c and its libm)", "policy_flash_bytes", lambda r: r["policy_flash_bytes"], "B"),
        ("whole image flash", "image_flash_bytes", lambda r: r["image_flash_bytes"], "B"),
        ("RAM (.data + .bss + stack high-water)", "ram_bytes", lambda r: r["ram_bytes"], "B"),
        ("instructions per inference (mean)", "instructions", lambda r: r["instructions"]["mean"], ""),
    )
    for label, key, get, unit in items:
        m4, m7 = get(by["cortex-m4f"]), get(by["cortex-m7"])
        u = f" {unit}" if unit else ""
        verdict = "yes" if m4 <= g[key] else f"no, {100 * (m4 / g[key] - 1):.1f} % over"
        rows.append(f"| {label} | ≤ {g[key]:,}{u} | {m4:,.0f}{u} | {m7:,.0f}{u} | {verdict} |")
    return rows


TABLES = {"footprint": footprint, "instructions": instructions, "stages": stages, "goals": goals}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("json", type=Path)
    p.add_argument("--table", choices=tuple(TABLES), help="print only this table. Default: all, with the toolchain")
    args = p.parse_args(argv)
    try:
        doc = json.loads(args.json.read_text())
    except (OSError, json.JSONDecodeError) as e:
        print(f"report_embedded: cannot read {args.json}: {e}", file=sys.stderr)
        return 2
    if args.table is None:
        print(f"{doc['toolchain']['gcc']}; {doc['toolchain']['qemu']}; {doc['datetime']}\n")
    for name, table in TABLES.items():
        if args.table in (None, name):
            print("\n".join(table(doc)))
            if args.table is None:
                print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
