"""The node through a silent state stream in RotorPy's PX4 simulator, episodes kept as data:

    .venv/bin/python benchmarks/state_loss_rotorpy.py OUT.json [--episodes N] [--long-episodes M] [--rates 100,250]

Each flight is tests/sitl/test_rotorpy_state_loss.py's `state_loss_flight` (rotorpy_px4.py
--state-dropout and `quad-sitl --node-only` in two processes, models/hover_px4_sih holding its start
5 m up, RotorPy's ground truth judged), flown per rate: the 0.5 s dropout at 2 s in a 6 s flight, N
episodes (seeds 0..N-1: RotorPy's IMU and rotor noise); a 5 s dropout and an endless one at 2 s, in
14 s flights (time to come down from 5 m at 0.7 m/s after the 2 s of estimate and hold), M episodes
each (M = min(N, 3) unless given). Every episode's values are kept, with a summary per rate and dropout
(the success rate of the short dropout, the landings' worst touchdown speed and fastest descent), the
host's load average before each flight and its wall time: RotorPy waits 10 ms of wall time for each
answer, so on a loaded host steps are missed (measured, `missed_steps`), and a missed step is flown on
zero motors."""

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

ROOT = Path(__file__).resolve().parents[1]
SHORT_S, SHORT_FLIGHT_S = 0.5, 6.0
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


def _episode(t, dropout_s: float, rate_hz: float, duration_s: float, seed: int) -> dict:
    load = os.getloadavg()[0]
    wall0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="state-loss-rotorpy-") as tmp:
        try:
            flight = t.state_loss_flight(dropout_s, rate_hz, duration_s, Path(tmp), seed=seed)
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as e:  # the harness's own checks (pytest.fail: RotorPy did not finish): a row that says so
            flight = {"dropout": f"2+{dropout_s:g}", "rate_hz": rate_hz, "seed": seed, "duration_s": duration_s}
            flight["failed"] = (str(e).strip().splitlines() or [type(e).__name__])[0][:300]
    flight.update(load_average_before=load, wall_s=time.perf_counter() - wall0)
    return flight


def _summary(episodes: list[dict]) -> dict:
    flown = [e for e in episodes if "failed" not in e]
    touch = [e["touchdown_speed"] for e in flown if e.get("touchdown_speed") is not None]
    out = {
        "episodes": len(episodes),
        "failed_to_run": len(episodes) - len(flown),
        "success_rate": sum(e["success"] for e in flown) / len(flown) if flown else math.nan,
        "crashes": sum(e["crashed"] for e in flown),
        "landed": sum(e["phases"][-1:] == ["landed"] for e in flown),
        "touchdowns": len(touch),
        "max_touchdown_speed": max(touch, default=None),
        "max_descent_speed": max((e["max_descent_speed"] for e in flown), default=None),
        "motors_off_airborne_steps": sum(e["motors_off_airborne_steps"] for e in flown),
        "missed_steps": sum(e["missed_steps"] for e in flown),
        "wall_s_per_flight": sum(e["wall_s"] for e in episodes) / len(episodes) if episodes else math.nan,
    }
    return out


def run(rates=(100, 250), episodes: int = 10, out: Path | None = None, long_episodes: int | None = None) -> dict:
    """Fly every rate's dropouts (module docstring) and write the JSON to `out` (when given); the data."""
    t = _load_test_module()
    long_episodes = min(episodes, 3) if long_episodes is None else long_episodes
    data = {
        "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "machine": {"processor": platform.processor(), "cpus": os.cpu_count(), "python": platform.python_version()},
        "commit": subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip(),
        "policy": str(t.SIH.relative_to(ROOT)),
        "dropout_at_s": t.DROPOUT_AT_S,
        "crash": f"first ground contact faster than {t.TOUCHDOWN_MAX_SPEED:g} m/s or tilted "
        f"{t.TOUCHDOWN_MAX_TILT_DEG:g} deg or more, or any step tilted beyond {t.MAX_TILT_DEG:g} deg",
        "rates": {},
    }
    plan = [(SHORT_S, SHORT_FLIGHT_S, episodes), *((d, f, long_episodes) for d, f in LONG)]
    for rate in rates:
        per_rate = data["rates"][f"{rate:g}"] = {}
        for dropout_s, duration_s, n in plan:
            eps = [_episode(t, dropout_s, rate, duration_s, seed) for seed in range(n)]
            per_rate[f"{dropout_s:g}"] = {"summary": _summary(eps), "episodes": eps}
            print(f"{rate:g} Hz, dropout {dropout_s:g} s: {json.dumps(per_rate[f'{dropout_s:g}']['summary'])}")
    data["finished"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    if out is not None:
        Path(out).write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    return data


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", type=Path)
    p.add_argument("--episodes", type=int, default=10, help="episodes of the 0.5 s dropout per rate")
    p.add_argument("--long-episodes", type=int, help="episodes of the 5 s and the endless dropout (min(N, 3))")
    p.add_argument("--rates", default="100,250", help="simulator rates, Hz")
    a = p.parse_args(argv)
    run(tuple(float(r) for r in a.rates.split(",")), a.episodes, a.out, a.long_episodes)
    return 0


if __name__ == "__main__":
    sys.exit(main())
