"""The policies trained here for PX4's mc_raptor (models/hover_px4_raptor_*: `quad-train --contract
px4-raptor`, then `quad-export --format px4-raptor`), flown from their policy.tar, and the time from a
vehicle to a checked policy.tar, kept as data for docs/px4.md:

    .venv/bin/python benchmarks/px4_raptor_models.py run docs/bench/px4_raptor_models.json   # ~15 minutes

- ours: `quad-sitl --model NAME --episodes 10` (100 Hz, random starts within 1 m, random headings; the
  vehicle the file was trained for, its vehicle.toml);
- RotorPy (rotorpy 3.0.0 PX4Multirotor, the same airframe) at 100 Hz (MAVLink 1) and 250 Hz (MAVLink 2),
  the GRU advancing every 100 Hz step, as benchmarks/raptor_flights.py flies RAPTOR's own policy;
- time to policy.tar: the wall time of `quad-train --task hover --contract px4-raptor --vehicle V`
  followed by `quad-export --format px4-raptor` (which replays the whole example), for PX4's SIH
  quad-X (its MLP teacher ships, so only the distillation runs) and for an airframe no teacher was
  trained for (the Crazyflie preset with a 30 ms rotor lag, as docs/px4.md flies RAPTOR on it: the
  teacher is trained first by our PPO with --total-steps TEACHER_STEPS), with the student's evaluation.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import raptor_flights as rf

ROOT = Path(__file__).resolve().parents[1]
MODELS = {"hover_px4_raptor_sih": "sih", "hover_px4_raptor_hummingbird": "hummingbird"}
TEACHER_STEPS = 1_000_000


def _run(cmd: list[str]) -> None:
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} exited {done.returncode}: {done.stderr.strip()[-500:]}")


def to_policy_tar(vehicle: str, tmp: Path, extra: list[str]) -> dict:
    """Wall time from the vehicle to an exported, checked policy.tar, and the student's evaluation."""
    out = tmp / "run"
    t0 = time.perf_counter()
    train = [sys.executable, "-m", "quadpilot.train.cli", "--task", "hover", "--contract", "px4-raptor"]
    _run([*train, "--vehicle", vehicle, "--out", str(out), *extra])
    trained = time.perf_counter() - t0
    _run([sys.executable, "-m", "quadpilot.export.cli", "--format", "px4-raptor", str(out / "policy.pt")])
    return {
        "vehicle": vehicle,
        "options": extra,
        "train_s": trained,
        "to_policy_tar_s": time.perf_counter() - t0,
        "teacher": json.loads((out / "config.json").read_text())["teacher"],
        "eval": json.loads((out / "eval.json").read_text()),
    }


def run(out: Path) -> dict:
    data = {
        "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "command": "benchmarks/px4_raptor_models.py run " + str(out),
        "machine": {"processor": platform.processor(), "cpus": os.cpu_count(), "python": platform.python_version()},
        "load_1min_before": os.getloadavg()[0],
        "commit": subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip(),
        "flights": {},
        "to_policy_tar": {},
    }
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name, airframe in MODELS.items():
            tar = str(ROOT / "models" / name / "policy.tar")
            data["flights"][f"{name}_ours_100hz"] = rf.quad_sitl(["--model", name, "--episodes", "10"], tmp, policy=())
            for rate, mavlink in ((100, 1), (250, 2)):
                with tempfile.TemporaryDirectory() as rp:
                    flight = rf.rotorpy(rate, mavlink, Path(rp), policy=tar, vehicle=airframe)
                    data["flights"][f"{name}_rotorpy_{rate}hz"] = flight
        with tempfile.TemporaryDirectory() as run_dir:
            data["to_policy_tar"]["px4_sih_quadx"] = to_policy_tar("px4_sih_quadx", Path(run_dir), [])
        with tempfile.TemporaryDirectory() as run_dir:
            lag = rf.crazyflie_with_lag(Path(run_dir))
            steps = ["--total-steps", str(TEACHER_STEPS)]
            data["to_policy_tar"]["crazyflie_lag30ms"] = to_policy_tar(lag, Path(run_dir), steps)
    data["load_1min_after"] = os.getloadavg()[0]
    for name, f in data["flights"].items():
        err = f.get("mean_error_last_2s_m", f.get("error_last_2s_m"))
        print(f"{name}: error last 2 s {err * 100:.2f} cm, success {f.get('success_rate', '-')}")
    for name, f in data["to_policy_tar"].items():
        print(f"{name}: {f['to_policy_tar_s']:.0f} s to policy.tar, success {f['eval']['success_rate']:.0%}")
    out.write_text(json.dumps(data, indent=1) + "\n")
    return data


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    sub.add_parser("run").add_argument("out", type=Path)
    args = p.parse_args(argv)
    run(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
