"""The node through a silent state stream in RotorPy's PX4 simulator, every episode kept:

    .venv/bin/python benchmarks/state_loss_rotorpy.py docs/bench/state_loss_rotorpy.json   # 20 and 5 episodes
    .venv/bin/python benchmarks/report_state_loss.py docs/bench/state_loss.json docs/bench/state_loss_rotorpy.json

Each flight is tests/sitl/test_rotorpy_state_loss.py's `state_loss_flight` (rotorpy_px4.py
--state-dropout --lockstep and `quad-sitl --node-only` in two processes, models/hover_px4_sih holding
its start 5 m up, judged on RotorPy's ground truth), per rate (100 and 250 Hz): the 0.5 s dropout at
2 s of a 5 s flight, N episodes (seeds 0..N-1: RotorPy's IMU noise), and a 5 s and an endless dropout
at 2 s of 14 s flights (the time to come down from 5 m at 0.7 m/s after 2 s of estimate and hold), M
episodes each, with RotorPy's HIL_SENSOR as it is (no barometer) and with the barometer
`rotorpy_px4.py --baro` gives it. The JSON has benchmarks/state_loss.py's shape (`cells`), so one
report shows both simulators.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import importlib.util
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from quadpilot.console import quick

ROOT = Path(__file__).resolve().parents[1]
SHORT_S, SHORT_FLIGHT_S = 0.5, 5.0
LONG = ((5.0, 14.0), (math.inf, 14.0))
"""(dropout s, flight s) of the flights that land."""


def _load_test_module():
    """tests/sitl/test_rotorpy_state_loss.py, for its `state_loss_flight` (it imports test_rotorpy)."""
    sitl = str(ROOT / "tests" / "sitl")
    if sitl not in sys.path:
        sys.path.insert(0, sitl)
    spec = importlib.util.spec_from_file_location("rotorpy_state_loss_test", Path(sitl) / "test_rotorpy_state_loss.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _episode(t, dropout_s: float, rate_hz: float, duration_s: float, seed: int, baro: bool) -> dict:
    load = os.getloadavg()[0]
    wall0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="state-loss-rotorpy-") as tmp:
        try:
            flight = t.state_loss_flight(dropout_s, rate_hz, duration_s, Path(tmp), seed=seed, baro=baro)
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as e:  # the harness's own checks (pytest.fail: RotorPy did not finish): a row that says so
            flight = {"dropout": f"2+{dropout_s:g}", "rate_hz": rate_hz, "seed": seed, "duration_s": duration_s}
            flight["failed"] = (str(e).strip().splitlines() or [type(e).__name__])[0][:300]
    flight.update(load_average_before=load, wall_s=time.perf_counter() - wall0)
    return flight


def _row(k: int, f: dict) -> dict:
    """One flight in benchmarks/state_loss.py's terms."""
    if "failed" in f:
        return {"episode": k, "failed": f["failed"], "hover_rule": False, "crashed": False, "phases": []}
    return {
        "episode": k,
        "hover_rule": bool(f["success"]),
        "error_last_2s_m": f["error_last_2s_m"],
        "crashed": bool(f["crashed"]),
        "touchdown_speed_mps": f["touchdown_speed"],
        "touchdown_tilt_deg": f["touchdown_tilt_deg"],
        "max_descent_speed_mps": f["max_descent_speed"],
        "motors_off_airborne_steps": f["motors_off_airborne_steps"],
        "final_height_m": f["final_height_m"],
        "failsafe": f["failsafe"],
        "state_lost_steps": f["state_lost_steps"],
        "phases": f["phases"],
        "missed_steps": f["missed_steps"],
        "airborne_after_touchdown_steps": f["airborne_after_touchdown_steps"],
        "wall_s": f["wall_s"],
    }


def run(
    rates=(100, 250), episodes: int = 20, out: Path | None = None, long_episodes: int = 5, cells: int | None = None
) -> dict:
    """Fly every rate's dropouts (module docstring) and write the JSON to `out` (when given); the data.
    `cells` keeps only the first that many of each rate's conditions (a smoke test; None: all)."""
    t = _load_test_module()
    t0 = time.perf_counter()
    data = {
        "simulator": "RotorPy",
        "command": "benchmarks/state_loss_rotorpy.py " + " ".join(sys.argv[1:]),
        "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "machine": {"processor": platform.processor(), "cpus": os.cpu_count(), "python": platform.python_version()},
        "commit": subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip(),
        "policy": str(t.SIH.relative_to(ROOT)),
        "crash": f"first ground contact faster than {t.TOUCHDOWN_MAX_SPEED:g} m/s or tilted "
        f"{t.TOUCHDOWN_MAX_TILT_DEG:g} deg or more, or any step tilted beyond {t.MAX_TILT_DEG:g} deg",
        "cells": [],
    }
    plan = [("dropout 0.5 s", SHORT_S, SHORT_FLIGHT_S, episodes, False)]
    for baro in (False, True):
        for name, (dropout_s, flight_s) in zip(("dropout 5 s", "dropout never ends"), LONG, strict=True):
            plan.append((name, dropout_s, flight_s, long_episodes, baro))
    plan = plan[:cells]
    for rate in rates:
        for name, dropout_s, flight_s, n, baro in plan:
            c0 = time.perf_counter()
            rows = [_row(k, _episode(t, dropout_s, rate, flight_s, k, baro)) for k in range(n)]
            imu = "RotorPy's + barometer" if baro else "RotorPy's, no barometer"
            data["cells"].append(
                {"condition": name, "rate_hz": int(rate), "imu": imu, "flight_s": flight_s}
                | {"wall_s": time.perf_counter() - c0, "episodes": rows}
            )
            print(
                f"{name:>20} at {rate:g} Hz, {imu}: {sum(r['hover_rule'] for r in rows)}/{n} hover rule, "
                f"{sum(r['crashed'] for r in rows)} crashed, {sum('landed' in r['phases'] for r in rows)} landed",
                flush=True,
            )
    data["wall_s"] = time.perf_counter() - t0
    if out is not None:
        Path(out).write_text(json.dumps(data, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return data


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", type=Path)
    p.add_argument("--episodes", type=int, default=20, help="episodes of the 0.5 s dropout per rate (20)")
    p.add_argument("--long-episodes", type=int, default=5, help="episodes of each landing flight per rate (5)")
    p.add_argument("--rates", default="100,250", help="simulator rates, Hz")
    a = p.parse_args(argv)
    rates = tuple(float(r) for r in a.rates.split(","))
    # QUADPILOT_DOCS_QUICK (console.docs_quick): one episode of the first two conditions, at the first rate
    rates, a.episodes, a.long_episodes = rates[: quick(len(rates), 1)], quick(a.episodes, 1), quick(a.long_episodes, 1)
    run(rates, a.episodes, a.out, a.long_episodes, cells=quick(None, 2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
