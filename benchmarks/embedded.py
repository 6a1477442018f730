"""The exported C policy on an emulated Cortex-M4F and Cortex-M7: footprint and instructions per step.

    .venv/bin/python benchmarks/embedded.py --out docs/bench/embedded.json
    .venv/bin/python benchmarks/report_embedded.py docs/bench/embedded.json    # the tables of docs/embedded.md

For the shipped hover MLP and hover LSTM and each core (`quadpilot.ccode.target.TARGETS`) it
cross-builds the image `quad-export --format c --target` builds and boots it in QEMU
(`-icount shift=0`) on the golden vectors, 1,000 random in-envelope observations and a 300-step
recorded flight (the LSTM's state carried across steps), the inputs of tests/runtime/test_ctarget.py:
- flash and RAM by part, from the link map (ctarget.footprint): policy.o, libm, harness.o, libc,
  libgcc, alignment; the stack high-water mark of the whole run and of one kernel call, measured by
  painting the stack;
- instructions per step: SysTick ticks around each call times the instructions per tick the image's
  calibration loop measured (40: QEMU's 25 MHz SysTick at 1 ns per instruction), mean, min and max
  over the steps; each record is within one tick (40 instructions), the mean over 1,308 steps far
  closer. They include the call into a wrapper and one SysTick read;
- per stage (a second image built with the kernel's QP_PROBE hooks, which cost a load and a store
  each): normalisation, LSTM cell, each dense layer with its activation, the command map;
- the same MLP at -Os: GCC then uses VMLA (a multiply-accumulate that rounds like VMUL + VADD) where
  -O2 emits VMUL + VADD, so fewer instructions, but VMLA takes 3 cycles on the Cortex-M4 against 1 + 1
  (ARM DDI 0439B, table 7-1): fewer instructions are not fewer cycles here;
- the max abs difference of the commands from the NumPy backend.
With them, the operation-count estimate of cycles on a Cortex-M4F (`ccode.bench.cortex_m4_estimate`,
its assumptions in `ccode.bench.CORTEX_M4_CYCLES`), the only cycle figure here.
`--quick` runs 100 random observations and a 50-step flight (the smoke test's).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from quadpilot.ccode import generate as cgen
from quadpilot.ccode import target as ctarget
from quadpilot.ccode.bench import cortex_m4_estimate, operation_count
from quadpilot.console import docs_quick
from quadpilot.modelfile.model import initializer_arrays, read_model
from quadpilot.runtime.backends import load_policy
from quadpilot.train.runs.loop import cpu_model

ROOT = Path(__file__).resolve().parents[1]
MODELS = ("hover", "hover_lstm")
GOALS = {"policy_flash_bytes": 32 * 1024, "image_flash_bytes": 48 * 1024, "ram_bytes": 8 * 1024, "instructions": 30_000}
"""For the shipped hover MLP: policy flash (policy.o and the libm it calls), whole image flash, RAM
(.data + .bss + stack high-water), instructions per inference."""
FLASH_SECTIONS = (".text", ".rodata", ".ARM.exidx", ".data")
""".data's initial values are stored in flash too (copied to RAM at reset)."""


def _footprint(image: ctarget.Image, run: ctarget.RunResult) -> dict:
    parts = ctarget.footprint(image)
    flash = {p: sum(parts[s].get(p, 0) for s in FLASH_SECTIONS) for p in {p for s in parts.values() for p in s}}
    static_ram = sum(sum(parts[s].values()) for s in (".data", ".bss"))
    stack = run.trailer["stack_high_water_bytes"]
    return {
        "sections": parts,
        "flash_bytes": dict(sorted(flash.items())),
        "policy_flash_bytes": flash.get("policy", 0) + flash.get("libm", 0),
        "image_flash_bytes": sum(flash.values()),
        "data_bytes": sum(parts[".data"].values()),
        "bss_bytes": sum(parts[".bss"].values()),
        "stack_high_water_bytes": stack,
        "kernel_stack_bytes": run.trailer["kernel_stack_bytes"],
        "ram_bytes": static_ram + stack,
    }


def _instructions(run: ctarget.RunResult) -> dict:
    per = run.instructions[:, 0]
    return {"mean": float(per.mean()), "min": float(per.min()), "max": float(per.max()), "steps": len(per)}


def measure(model: str, target: str, random: int, flight: int, work: Path) -> dict:
    path = ROOT / "models" / model / "policy.onnx"
    onnx_model, info = read_model(path)
    code = cgen.generate(info, initializer_arrays(onnx_model))
    policy = load_policy(path, backend="numpy")
    obs, resets = ctarget.check_inputs(policy, random, flight)
    data = ctarget.encode_inputs(obs, resets)
    want = ctarget.replay(policy, obs, resets)
    out = {"case": f"{model}@{target}", "model": model, "target": target, "machine": ctarget.TARGETS[target].machine}
    for variant, opt, profile in (("plain", "-O2", False), ("profile", "-O2", True), ("os", "-Os", False)):
        if variant == "os" and model != "hover":
            continue
        d = work / f"{model}_{target}_{variant}"
        d.mkdir()
        image = ctarget.build_image(code, info, d, target, profile=profile, opt=opt)
        t0 = time.perf_counter()
        run = ctarget.run_image(image, data)
        boot_s = time.perf_counter() - t0
        if run.status != 0:
            raise SystemExit(f"embedded: {model} on {target} ({variant}) exits with {run.status}: {run.console}")
        diff = float(np.abs(run.motors - want).max())
        if variant == "plain":
            out |= _footprint(image, run)
            out["instructions"] = _instructions(run)
            out["instructions_per_tick"] = run.instructions_per_tick
            out["max_abs_diff_vs_numpy"] = diff
            out["boot_s"] = round(boot_s, 2)
        elif variant == "profile":
            stages = run.instructions[:, 1:].mean(axis=0)
            out["profile_total_instructions"] = float(run.instructions[:, 0].mean())
            out["profile_overhead_instructions"] = out["profile_total_instructions"] - out["instructions"]["mean"]
            out["stages"] = [
                {"stage": s, "instructions": float(v), "share": float(v / stages.sum())}
                for s, v in zip(image.stages, stages, strict=True)
            ]
        else:
            out["os"] = {
                "instructions": _instructions(run),
                "policy_flash_bytes": _footprint(image, run)["policy_flash_bytes"],
                "max_abs_diff_vs_numpy": diff,
            }
    counts = operation_count(code.network)
    out["operation_count"] = counts
    out["cortex_m4_estimate"] = cortex_m4_estimate(counts)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--quick", action="store_true", help="100 random observations and a 50-step flight")
    args = p.parse_args(argv)
    args.quick = args.quick or docs_quick()  # QUADPILOT_DOCS_QUICK (console.docs_quick): the smoke test's inputs
    random, flight = (100, 50) if args.quick else (1_000, 300)
    results = []
    with tempfile.TemporaryDirectory(prefix="embedded-") as tmp:
        for model in MODELS:
            for target in ctarget.TARGETS:
                results.append(measure(model, target, random, flight, Path(tmp)))
                r = results[-1]
                print(
                    f"{model} {target}: {r['instructions']['mean']:,.0f} instructions/step, "
                    f"flash {r['image_flash_bytes']:,} B, RAM {r['ram_bytes']:,} B",
                    file=sys.stderr,
                )
    reached = {}
    for r in results:
        if r["model"] == "hover":
            values = {k: r[k] for k in GOALS if k != "instructions"} | {"instructions": r["instructions"]["mean"]}
            reached[r["target"]] = {
                k: {"value": v, "goal": GOALS[k], "met": v <= GOALS[k], "over_percent": 100 * (v / GOALS[k] - 1)}
                for k, v in values.items()
            }
    doc = {
        "command": "benchmarks/embedded.py" + (" --quick" if args.quick else "") + f" --out {args.out}",
        "datetime": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "host": {
            "cpu": cpu_model(),
            "cpus": os.cpu_count(),
            "system": f"{platform.system()} {platform.release()}",
            "note": "instruction counts are QEMU's deterministic count, independent of the host and its load; they "
            "depend on the toolchain (below) and on the inputs, which include a flight on the code's core.dynamics",
        },
        "toolchain": ctarget.toolchain_versions(),
        "inputs": {"random_in_envelope": random, "flight_steps": flight, "golden": "the model's own"},
        "goals_hover_mlp": GOALS,
        "hover_mlp_against_goals": reached,
        "results": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
