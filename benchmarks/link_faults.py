"""Hover through a bad link and through sensor faults: what the shipped hover policies, RAPTOR and the node do.

    .venv/bin/python benchmarks/link_faults.py --out docs/bench/link_faults.json
    .venv/bin/python benchmarks/link_faults.py --models hover hover_px4_sih raptor --links-only \
        --only "delay 20 ms" "jitter 10±10 ms" "delay 40 ms" none --out docs/bench/link_delay.json
    .venv/bin/python benchmarks/report_link_faults.py docs/bench/link_faults.json   # the tables of docs/robustness.md

For each condition below, each simulator rate (100 and 250 Hz) and each model (`--models`, `MODELS`:
models/hover by default) it runs one `quad-sitl --realtime` (`--episodes N --seed 0`: the same start
states in every condition; 5 episodes, 20 for the conditions with a target, `GOALS` and `NO_CRASH`)
as its own process, a few at a time (`--jobs`), and keeps from its --json the success rate (the
project's one hover rule, `core.mission.judge`: within 5 cm over the last 2 s, heading held, no crash;
a failsafe is never a success), the error, crashes, and what the node did: steps flown by the safety
monitor's fallback, blind steps, failsafes (link loss), packets it dropped, and what the proxy did
(`quad-sitl --link-impair`, `quadpilot.link.impair`) or which fault fired (`--sensor-fault`,
`quadpilot.simulator.faults`). A run whose process exits with anything but 0 or 1 (1: the flight
ended early, a failsafe), or prints a traceback, is a crash of ours and is recorded as one.

The conditions: none; frame loss 1, 5, 10, 20 %; delay 10, 20, 40, 50 ms (each direction); jitter
(10 ms ± 10 ms); reordering 5 %; duplication 5 %; burst loss (Gilbert, 1 % per frame into a burst of 5
frames on average); and the sensor faults at 2 s into each 5 s flight: a 20 rad/s gyro spike, a stuck
accelerometer, a 0.5 s frozen position, a 0.5 s state dropout, a 5 m barometer step, NaN in the state.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from quadpilot.console import docs_quick, quick

IMPAIRMENTS = {
    "none": None,
    "loss 1%": "loss=1%",
    "loss 5%": "loss=5%",
    "loss 10%": "loss=10%",
    "loss 20%": "loss=20%",
    "delay 10 ms": "delay=10ms",
    "delay 20 ms": "delay=20ms",
    "delay 40 ms": "delay=40ms",
    "delay 50 ms": "delay=50ms",
    "jitter 10±10 ms": "delay=10ms,jitter=10ms",
    "reorder 5%": "reorder=5%",
    "duplicate 5%": "duplicate=5%",
    "burst loss": "burst=1%,burst-len=5",
}
FAULTS = {
    "gyro spike": "gyro-spike@2s",
    "accel stuck": "accel-stuck@2s",
    "position frozen 0.5 s": "pos-freeze@2s+0.5s",
    "state dropout 0.5 s": "state-dropout@2s+0.5s",
    "baro step 5 m": "baro-step@2s:5",
    "NaN in state": "nan@2s:state",
}
RATES_HZ = (100, 250)
GOALS = {"loss 5%": 0.95, "delay 20 ms": 0.95, "jitter 10±10 ms": 0.95}
"""Conditions with a success target; they fly `--goal-episodes` (a rate near 95 % needs more than a few)."""
NO_CRASH = ("delay 40 ms",)
"""Conditions whose target is that no episode crashes; they fly `--goal-episodes` too."""
MODELS = {
    "hover": ["--model", "hover"],
    "hover_px4_sih": ["--model", "hover_px4_sih"],
    "raptor": ["raptor:foundation", "--vehicle", "px4_sih_quadx"],
}
"""What `--models` can fly: the shipped hover policies (each on its own vehicle) and RAPTOR's foundation
policy (PX4's mc_raptor's, `runtime.raptor`) on PX4's SIH quad-X, the airframe hover_px4_sih is for."""
QUICK_CONDITIONS = ("none", "loss 20%", "delay 10 ms", *GOALS, *NO_CRASH, "gyro spike")
"""What QUADPILOT_DOCS_QUICK flies: the conditions docs/robustness.md's text quotes, and one sensor fault."""


def _command(
    model: str, rate: int, episodes: int, seed: int, impair: str | None, fault: str | None, out: Path
) -> list[str]:
    cmd = [sys.executable, "-m", "quadpilot.sitl", *MODELS[model], "--realtime", "--gcs", "none"]
    cmd += ["--episodes", str(episodes)]
    cmd += ["--seed", str(seed), f"--rate={rate}", "--json", str(out)]
    if impair:
        cmd.append(f"--link-impair={impair}")
    if fault:
        cmd.append(f"--sensor-fault={fault}")
    return cmd


def _one(model: str, kind: str, name: str, spec: str | None, rate: int, episodes: int, seed: int, tmp: Path) -> dict:
    load = os.getloadavg()[0]
    out = tmp / f"{model}-{kind}-{name.replace(' ', '_').replace('%', 'pct').replace('±', 'pm')}-{rate}.json"
    cmd = _command(
        model, rate, episodes, seed, spec if kind == "link" else None, spec if kind == "fault" else None, out
    )
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60 + 30 * episodes)
    row = {
        "model": model,
        "kind": kind,
        "condition": name,
        "spec": spec,
        "rate_hz": rate,
        "exit_code": proc.returncode,
        "load_average_1min_at_start": load,
        "traceback": "Traceback" in proc.stderr or "Traceback" in proc.stdout,
        "wall_s": time.perf_counter() - t0,
    }
    row["crashed_process"] = row["traceback"] or proc.returncode not in (0, 1)
    if not out.exists():
        row["stderr"] = proc.stderr.strip().splitlines()[-3:]
        return row
    s = json.loads(out.read_text())
    eps = s["per_episode"]
    row.update(
        episodes=s["episodes"],
        success_rate=s["success_rate"],
        successes=sum(e["success"] for e in eps),
        crashes=s["crashes"],
        mean_error_last_2s_m=s["mean_error_last_2s_m"],
        max_error_last_2s_m=max((e["mean_error_last_window_m"] for e in eps), default=None),
        failsafes=s["failsafe_events"],
        failsafe_reasons=sorted({e["failsafe"] for e in eps if e.get("failsafe")}),
        fallback_steps=s["fallback_steps"],
        episodes_with_fallback=sum(e.get("fallback_steps", 0) > 0 for e in eps),
        steps=s["steps"],
        monitor_events=s["monitor_events"],
        packets_dropped=s["packets_dropped"],
        state_lost_steps=s.get("state_lost_steps", 0),
        control_latency_p99_us=s["control_latency_p99_us"],
    )
    if "link_impair" in s:
        row["link_impair"] = s["link_impair"]
    return row


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo), without importing torch (`quadpilot.train.run.cpu_model`
    does): benchmarks/soak.py measures the memory of a torch-free node process with this."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            name = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), None)
    except OSError:
        name = None
    return name or platform.processor() or platform.machine()


def machine() -> dict:
    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "load_average_1min_at_start": os.getloadavg()[0],
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--episodes", type=int, default=5, help="episodes per condition and rate (default 5)")
    goals = ", ".join(GOALS).replace("%", "%%")  # argparse formats help with %: "loss 5%" would break it
    p.add_argument("--goal-episodes", type=int, default=20, help=f"episodes of {goals} (default 20)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--rates", type=int, nargs="+", default=list(RATES_HZ))
    p.add_argument("--only", nargs="+", help="only these conditions (names as in the tables)")
    p.add_argument("--models", nargs="+", choices=sorted(MODELS), default=["hover"], help="what flies (default: hover)")
    p.add_argument("--links-only", action="store_true", help="the link conditions alone, no sensor faults")
    p.add_argument("--jobs", type=int, default=3, help="quad-sitl runs at once (default 3)")
    p.add_argument("--note", default="", help="a line on the machine's state (e.g. loaded by other work)")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    todo = [("link", n, s) for n, s in IMPAIRMENTS.items()]
    if not args.links_only:
        todo += [("fault", n, s) for n, s in FAULTS.items()]
    if args.only:
        todo = [t for t in todo if t[1] in args.only]
    elif docs_quick():  # console.docs_quick: the flights docs/robustness.md quotes, and one sensor fault
        todo = [t for t in todo if t[1] in QUICK_CONDITIONS]
    # and one episode each, at the first rate (quad-sitl flies one episode under the switch anyway)
    args.rates, args.episodes = args.rates[: quick(len(args.rates), 1)], quick(args.episodes, 1)
    args.goal_episodes = quick(args.goal_episodes, 1)
    info = machine()

    def n(name: str) -> int:
        return max(args.episodes, args.goal_episodes) if name in GOALS or name in NO_CRASH else args.episodes

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="link-faults-") as tmp, ThreadPoolExecutor(args.jobs) as pool:
        jobs = [
            pool.submit(_one, model, kind, name, spec, rate, n(name), args.seed, Path(tmp))
            for model in args.models
            for rate in args.rates
            for kind, name, spec in todo
        ]
        rows = []
        for j in jobs:
            r = j.result()
            rows.append(r)
            ok = f"{r['success_rate']:.0%}" if "success_rate" in r else f"no result (exit {r['exit_code']})"
            print(f"{r['model']:<14} {r['rate_hz']} Hz {r['condition']:<24} success {ok}", flush=True)
    info["load_average_1min_at_end"] = os.getloadavg()[0]
    doc = {
        "command": " ".join(["python", "benchmarks/link_faults.py", *(argv if argv is not None else sys.argv[1:])]),
        "flights": "quad-sitl MODEL --realtime --gcs none --episodes N --seed S --rate HZ [--link-impair SPEC] "
        "[--sensor-fault SPEC] (MODEL: " + "; ".join(f"{k}: {' '.join(v)}" for k, v in MODELS.items()) + ")",
        "machine": info,
        "note": args.note,
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "wall_s": time.perf_counter() - t0,
        "episodes": args.episodes,
        "goals": GOALS,
        "no_crash": list(NO_CRASH),
        "models": args.models,
        "rows": rows,
        "process_crashes": sum(r["crashed_process"] for r in rows),
    }
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
