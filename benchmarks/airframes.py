"""RAPTOR's foundation policy against policies trained here, airframe by airframe, in our simulator,
kept as data for docs/raptor.md:

    .venv/bin/python benchmarks/airframes.py run docs/bench/airframes.json          # every airframe
    .venv/bin/python benchmarks/airframes.py run out.json --airframe px4_sih_quadx  # one
    .venv/bin/python benchmarks/airframes.py run docs/bench/airframes.json --merge --airframe x500  # one, into the rest

Controllers, the same flights for each:
- `raptor`: the RAPTOR foundation policy zero-shot (`quad-sitl raptor:foundation --vehicle AIRFRAME`),
  through the px4-raptor contract code, its outputs mapped to the airframe's rotors by their corners
  (`core.px4_raptor.policy_order`), so that a failure is RAPTOR's and not a motor mapping's;
- `ours`: the policy trained here for that airframe (`OURS`: the shipped MLP trained from its vehicle
  file, `quad-train --vehicle`), where one exists; an airframe without one has no row.
Flights (`quad-sitl`, 100 Hz, 10 episodes of 5 s each, seeded): `hover` (random starts within 1 m,
commanded headings within 30°, rotors anywhere from rest to hover); `wind` (a steady 2 m/s wind and
1 m/s gusts); `mass+30%`, `mass-30%` (the plant heavier or lighter than the vehicle file says: what a
user gets wrong), `thrust+20%`, `thrust-20%` (the rotors' thrust coefficient off by as much). Per
flight: success (the hover rule: mean error over the last 2 s at most 5 cm, yaw rules), the mean
error over the last 2 s, the worst heading error, crashes.

Not here yet: RotorPy's side, the step and figure-eight flights, and a generalist policy.
`rotorpy_hummingbird`'s `ours` is models/hover_hummingbird, trained on tests/data/vehicles/
rotorpy_hummingbird.toml (RotorPy's Hummingbird without its drag and rotor aerodynamics, which the
model did not have then); the set's file has them.
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
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SET = ROOT / "benchmarks" / "airframes"
AIRFRAMES = {
    "px4_sih_quadx": "px4_sih_quadx",
    "crazyflie": "crazyflie",
    **{p.stem: str(p) for p in sorted(SET.glob("*.toml"))},
}
"""name → what `--vehicle` takes (a shipped name or a vehicle file): two shipped presets and the
airframe set of benchmarks/airframes/ (docs/raptor.md)."""
OURS = {
    "px4_sih_quadx": ROOT / "models/hover_px4_sih/policy.onnx",
    "rotorpy_hummingbird": ROOT / "models/hover_hummingbird/policy.onnx",
    "crazyflie": ROOT / "models/hover_crazyflie/policy.onnx",
}
"""The policy trained here for an airframe (its command is in its folder's config.json)."""
FLIGHTS = {
    "hover": [],
    "wind": ["--wind", "2,0,0", "--gust", "1"],
    "mass+30%": ["--mass-scale", "1.3"],
    "mass-30%": ["--mass-scale", "0.7"],
    "thrust+20%": ["--motor-scale", "1.2"],
    "thrust-20%": ["--motor-scale", "0.8"],
}
EPISODES = 10
KEPT = (
    "success_rate",
    "crashes",
    "mean_error_last_2s_m",
    "max_heading_error_last_2s_deg",
    "max_abs_yaw_rate_last_2s_radps",
    "fallback_steps",
)


def fly(policy: str, vehicle: str, flight: list[str], tmp: Path, episodes: int = EPISODES) -> dict:
    """One `quad-sitl` run: the summary's figures (or the one-line refusal, if it refused)."""
    out = tmp / "s.json"
    out.unlink(missing_ok=True)
    cmd = [sys.executable, "-m", "quadpilot.sitl", policy, "--vehicle", vehicle, "--episodes", str(episodes)]
    cmd += ["--gcs", "none", "--seed", "7", "--json", str(out), *flight]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    if not out.is_file():
        return {"refused": done.stderr.strip().splitlines()[-1] if done.stderr.strip() else f"exit {done.returncode}"}
    s = json.loads(out.read_text())
    return {k: s[k] for k in KEPT if k in s}


def run(out: Path, airframes: list[str], episodes: int = EPISODES, merge: bool = False) -> dict:
    """Fly `airframes` and write the JSON; `merge`: into the one at `out`, keeping its other airframes
    (each airframe's entry says when, at which commit and under which load it was flown)."""
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    data = {
        "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "command": "benchmarks/airframes.py run " + str(out),
        "machine": {"processor": platform.processor(), "cpus": os.cpu_count(), "python": platform.python_version()},
        "load_1min_before": os.getloadavg()[0],
        "commit": commit,
        "episodes": episodes,
        "flights": {k: " ".join(v) for k, v in FLIGHTS.items()},
        "airframes": {},
    }
    if merge and out.is_file():
        old = json.loads(out.read_text())
        if old.get("episodes") != episodes or old.get("flights") != data["flights"]:
            raise SystemExit(f"airframes: {out} holds other flights or episode counts; run it whole")
        for rows in old["airframes"].values():  # the earlier runs' airframes, with their own run data
            rows.setdefault("run", {k: old[k] for k in ("started", "commit", "load_1min_before")})
        data["airframes"] = old["airframes"]
    with tempfile.TemporaryDirectory() as tmp:
        for name in airframes:
            vehicle = AIRFRAMES[name]
            controllers = {"raptor": "raptor:foundation"}
            if name in OURS:
                controllers["ours"] = str(OURS[name])
            rows = data["airframes"][name] = {"vehicle": vehicle.replace(str(ROOT) + "/", "")}
            rows["run"] = {"started": data["started"], "commit": commit, "load_1min_before": os.getloadavg()[0]}
            for controller, policy in controllers.items():
                rows[controller] = {f: fly(policy, vehicle, args, Path(tmp), episodes) for f, args in FLIGHTS.items()}
                for f, r in rows[controller].items():
                    print(f"{name} {controller} {f}: {r}", flush=True)
    data["load_1min_after"] = os.getloadavg()[0]
    out.write_text(json.dumps(data, indent=1) + "\n")
    return data


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("out", type=Path)
    r.add_argument("--airframe", action="append", choices=sorted(AIRFRAMES), help="Default: every one.")
    r.add_argument("--episodes", type=int, default=EPISODES)
    r.add_argument("--merge", action="store_true", help="Update these airframes in OUT, keep the others.")
    args = p.parse_args(argv)
    run(args.out, args.airframe or list(AIRFRAMES), args.episodes, args.merge)
    return 0


if __name__ == "__main__":
    sys.exit(main())
