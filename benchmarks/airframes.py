"""RAPTOR's foundation policy against policies trained here, airframe by airframe, in our simulator,
kept as data for docs/raptor.md:

    .venv/bin/python benchmarks/airframes.py run docs/bench/airframes.json          # every airframe
    .venv/bin/python benchmarks/airframes.py run out.json --airframe px4_sih_quadx  # one
    .venv/bin/python benchmarks/airframes.py run docs/bench/airframes.json --merge --airframe x500  # one, into the rest

Controllers, the same flights for each:
- `raptor`: the RAPTOR foundation policy zero-shot (`quad-sitl raptor:foundation --vehicle AIRFRAME`),
  through the px4-raptor contract code, its outputs mapped to the airframe's rotors by their corners
  (`core.px4_raptor.policy_order`), so that a failure is RAPTOR's and not a motor mapping's;
- `ours`: a policy trained in this run from the airframe's vehicle file alone (`TRAIN`: `quad-train
  --task hover --vehicle FILE`, then `quad-export`, which checks the ONNX file against torch); the
  wall time from the file to the checked policy.onnx is recorded per airframe (`ours_training`), with
  the training's own evaluation. `--policies DIR` keeps the policies (DIR/AIRFRAME/); `--reuse` flies
  the ones already there instead of training again (their recorded time is kept).
Flights (`quad-sitl`, 100 Hz, seeded): `hover` (random starts within 1 m, commanded headings within
30°, rotors anywhere from rest to hover; 5 s); `wind` (a steady 2 m/s wind and 1 m/s gusts);
`mass+30%`, `mass-30%` (the plant heavier or lighter than the vehicle file says: what a user gets
wrong), `thrust+20%`, `thrust-20%` (the rotors' thrust coefficient off by as much); `impulse` (a hit
3 s into a 7 s hover: the velocity jumps by 1 m/s east; judged over the last 2 s); `step` (1 m from
rest: overshoot, settling time); `figure8 V` (PX4 mc_raptor's figure-eight at a peak speed of V m/s,
`core.maneuver`: tracking error over a lap). Per flight: success (the hover rule: mean error over
the last 2 s at most 5 cm, yaw rules), the mean error over the last 2 s, the worst heading error,
crashes, and what the maneuver measures.

RotorPy's side (`rotorpy`, after `run`, with the policies it kept; `--controller` also the generalist
and tuned, after their subcommands): RAPTOR and ours in RotorPy's PX4 simulator with each vehicle
file's dynamics, `ROTORPY_FLIGHTS`, measured from RotorPy's ground truth.

The generalist (`generalist OUT --policy generalist.pt --policies DIR`, after `run`): one recurrent
policy trained once over drawn airframes (`GENERALIST_TRAIN`: quad-train --arch lstm --randomize
airframes; `core.randomization.AIRFRAMES`), exported for each airframe with `quad-export --vehicle
FILE` (its file's hover command and rotor order, nothing retrained; `train.ppo.retarget`) and flown on
the same flights in both simulators, under each airframe's "generalist" and "rotorpy"/"generalist".

`tuned` (`tuned OUT --policy generalist.pt --policies DIR`, after `run`): ours made the other way,
the generalist trained on with the airframe's vehicle file for a minute or two (`TUNE`: quad-train
--vehicle FILE --init-from generalist.pt), timed from the file to a checked policy.onnx as `ours` is
(`tuned_training`), flown under "tuned" in both simulators.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import hashlib
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from quadpilot.console import docs_quick, quick
from report_airframes import TUNED_FROM
from rotorpy_flights import ATTEMPTS, ROTORPY_DEFAULT, ROTORPY_FLIGHTS, rotorpy_flight

ROOT = Path(__file__).resolve().parents[1]
SET = ROOT / "benchmarks" / "airframes"
AIRFRAMES = {
    "px4_sih_quadx": "px4_sih_quadx",
    "crazyflie": "crazyflie",
    **{p.stem: str(p) for p in sorted(SET.glob("*.toml"))},
}
"""name → what `--vehicle` takes (a shipped name or a vehicle file): two shipped presets and the
airframe set of benchmarks/airframes/ (docs/raptor.md)."""
TRAIN = ["--task", "hover", "--init-rotor", "random", "--seed", "0", "--total-steps", "2000000"]
"""quad-train's flags for `ours`, with --vehicle FILE: the shipped hover recipe at 2M steps (1M left
the racer at 55 % success), rotors from rest to hover at the starts, as the flights start them."""
FLIGHTS = {
    "hover": [],
    "wind": ["--wind", "2,0,0", "--gust", "1"],
    "mass+30%": ["--mass-scale", "1.3"],
    "mass-30%": ["--mass-scale", "0.7"],
    "thrust+20%": ["--motor-scale", "1.2"],
    "thrust-20%": ["--motor-scale", "0.8"],
    "impulse": ["--impulse", "1@3", "--duration", "7"],
    "step": ["--maneuver", "step"],
    "figure8 1 m/s": ["--maneuver", "figure8:1"],
    "figure8 2 m/s": ["--maneuver", "figure8:2"],
    "figure8 4 m/s": ["--maneuver", "figure8:4"],
}
GENERALIST_TRAIN = [
    *("--task", "hover", "--arch", "lstm", "--randomize", "airframes", "--init-rotor", "random"),
    *("--num-envs", "256", "--seed", "0", "--total-steps", "12000000"),
]
"""quad-train's flags for the generalist (no --vehicle: the seed's quad-X layout, every episode a drawn
airframe): the recurrent hover recipe over 256 drones."""
TUNE = [
    *("--task", "hover", "--init-rotor", "random", "--seed", "0"),
    *("--num-envs", "256", "--total-steps", "600000", "--lr", "0.0001"),
]
"""quad-train's flags for `tuned`, with --vehicle FILE --init-from GENERALIST.pt: the generalist's
network trained on for 600k steps on the one file, at a third of its learning rate (about 100 s on
2 cores, under the 3 minutes from file to policy that the per-airframe policies are held to)."""
EPISODES = 10
EVAL_KEYS = ("eval_success_rate", "eval_mean_final_distance_m")
KEPT = (
    "success_rate",
    "crashes",
    "mean_error_last_2s_m",
    "max_heading_error_last_2s_deg",
    "max_abs_yaw_rate_last_2s_radps",
    "fallback_steps",
    "overshoot_pct",
    "rise_s",
    "settling_s",
    "not_settled",
    "tracking_rms_m",
    "tracking_max_m",
)


def _commit() -> str:
    """The commit the figures are flown at (HEAD)."""
    return subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()


def _digest(policy: Path) -> str:
    """The sha256 of the generalist's policy file (--policy): which generalist a record belongs to."""
    if not policy.is_file():
        raise SystemExit(f"airframes: --policy {policy}: no such file; give the generalist's policy.pt")
    return hashlib.sha256(policy.read_bytes()).hexdigest()


def _when(commit: str) -> dict:
    """When a run starts: the time, the commit and the machine's load (each run's record)."""
    return {
        "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "commit": commit,
        "load_1min_before": os.getloadavg()[0],
    }


def _forget_rotorpy(rows: dict, controller: str) -> None:
    """Drop an airframe's RotorPy flights of `controller` and their run records: flown by a policy
    trained again."""
    side = rows.get("rotorpy") or {}
    for k in [k for k in side if k == controller or k.startswith(f"run {controller}")]:
        del side[k]


def _stamp(rows: dict, key: str, flown: dict, when: dict, added: bool) -> None:
    """Record under rows[key] when flights `added` to the others were flown; when every flight was
    flown now, there is nothing to add to the run's own record."""
    if added:
        rows.setdefault(key, {}).update({f: when for f in flown})
    else:
        rows.pop(key, None)


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


def train(vehicle: str, folder: Path, extra: list[str], flags: list[str] = TRAIN) -> dict:
    """`ours` (`flags`: `tuned`'s) for `vehicle`: quad-train then quad-export into `folder`, timed (s of
    wall clock)."""
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "quadpilot.train.cli", *flags, "--vehicle", vehicle, "--out", str(folder), *extra]
    done = subprocess.run(cmd, capture_output=True, text=True)
    t1 = time.perf_counter()
    if done.returncode != 0:
        said = done.stderr.strip().splitlines()
        raise SystemExit(f"airframes: quad-train --vehicle {vehicle} failed: {said[-1] if said else done.returncode}")
    exported = subprocess.run(
        [sys.executable, "-m", "quadpilot.export.cli", str(folder / "policy.pt")], capture_output=True, text=True
    )
    t2 = time.perf_counter()
    if exported.returncode != 0:
        raise SystemExit(f"airframes: quad-export {folder / 'policy.pt'} failed: {exported.stderr.strip()[-300:]}")
    ev = json.loads((folder / "eval.json").read_text())
    return {
        "command": "quad-train "
        + " ".join([*flags, "--vehicle", vehicle.replace(str(ROOT) + "/", ""), *extra])
        + "; quad-export policy.pt",
        "train_s": t1 - t0,
        "export_s": t2 - t1,
        "file_to_policy_s": t2 - t0,
        "load_1min_before": load,
        "eval_success_rate": ev["success_rate"],
        "eval_mean_final_distance_m": ev["mean_final_distance_m"],
    }


RUN_ROWS = ("vehicle", "run", "flights_run", "raptor", "ours", "ours_training", "ours_retraining")
"""An airframe's rows that `run` writes: flying the airframe again whole, it keeps every other row
(the generalist's, tuned's, RotorPy's), whichever subcommand wrote them."""
TUNED = "tuned"
"""`tuned`'s run folder in an airframe's policy folder."""


def _clear_training(folder: Path) -> None:
    """Remove an earlier training of `ours` from `folder`, not the generalist exported there nor the
    generalist fine-tuned there (`tuned`)."""
    if not folder.is_dir():
        return
    for item in folder.iterdir():
        if item.name.startswith("generalist.") or item.name == TUNED:
            continue
        shutil.rmtree(item) if item.is_dir() else item.unlink()


def run(
    out: Path,
    airframes: list[str],
    episodes: int = EPISODES,
    merge: bool = False,
    policies: Path | None = None,
    reuse: bool = False,
    train_flags: list[str] | None = None,
    flights: dict | None = None,
) -> dict:
    """Fly `airframes` and write the JSON; `merge`: into the one at `out`, keeping its other airframes
    (each airframe's entry says when, at which commit and under which load it was flown)."""
    commit = _commit()
    data = {
        "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "command": "benchmarks/airframes.py run " + str(out),
        "machine": {"processor": platform.processor(), "cpus": os.cpu_count(), "python": platform.python_version()},
        "load_1min_before": os.getloadavg()[0],
        "commit": commit,
        "episodes": episodes,
        "flights": {k: " ".join(v) for k, v in (flights or FLIGHTS).items()},
        "airframes": {},
    }
    if merge and out.is_file():
        old = json.loads(out.read_text())
        redefined = [f for f, v in data["flights"].items() if old.get("flights", {}).get(f, v) != v]
        if old.get("episodes") != episodes or redefined:
            raise SystemExit(f"airframes: {out} holds other episode counts or flights {redefined}; run it whole")
        for rows in old["airframes"].values():  # the earlier runs' airframes, with their own run data
            rows.setdefault("run", {k: old[k] for k in ("started", "commit", "load_1min_before")})
        data["airframes"] = old["airframes"]
        data["flights"] = {**old["flights"], **data["flights"]}  # a flight added to the others
        data.update({k: v for k, v in old.items() if k not in data and k != "load_1min_after"})  # the generalist's
    with tempfile.TemporaryDirectory() as tmp:
        keep = Path(tmp) / "policies" if policies is None else policies
        for name in airframes:
            vehicle = AIRFRAMES[name]
            rows = data["airframes"].setdefault(name, {})
            rows["vehicle"] = vehicle.replace(str(ROOT) + "/", "")
            when = {"started": data["started"], "commit": commit, "load_1min_before": os.getloadavg()[0]}
            if flights is None:  # the whole airframe again; the other subcommands' rows stay
                kept = {k: v for k, v in rows.items() if k not in RUN_ROWS}
                rows = data["airframes"][name] = {"vehicle": rows["vehicle"], "run": when, **kept}
            else:  # these flights added to the airframe's others, with when they were flown
                rows.setdefault("flights_run", {}).update({f: when for f in flights})
            folder = keep / name
            made = folder / "policy.onnx"
            if reuse and made.is_file() and (folder / "training.json").is_file():
                if flights is None or "ours_training" not in rows:  # else the first training's record stays
                    rows["ours_training"] = json.loads((folder / "training.json").read_text())
            else:
                _clear_training(folder)  # an earlier run's, never finished: trained again
                _forget_rotorpy(rows, "ours")  # flown by the old policy
                trained = train(vehicle, folder, train_flags or [])
                (folder / "training.json").write_text(json.dumps(trained, indent=1) + "\n")
                if flights is not None and "ours_training" in rows:
                    # trained again to fly added flights: the other flights' policy is the first one,
                    # the same if the seeded training is (its evaluation says whether it is)
                    same = all(trained[k] == rows["ours_training"][k] for k in EVAL_KEYS)
                    rows["ours_retraining"] = {**trained, "same_evaluation_as_first": same}
                else:
                    rows["ours_training"] = trained
            print(f"{name} ours trained: {rows['ours_training']}", flush=True)
            for controller, policy in (("raptor", "raptor:foundation"), ("ours", str(made))):
                flown = {f: fly(policy, vehicle, args, Path(tmp), episodes) for f, args in (flights or FLIGHTS).items()}
                rows[controller] = {**rows.get(controller, {}), **flown}
                for f, r in flown.items():
                    print(f"{name} {controller} {f}: {r}", flush=True)
            out.write_text(json.dumps(data, indent=1) + "\n")  # after each airframe: a long run keeps what it flew
    data["load_1min_after"] = os.getloadavg()[0]
    out.write_text(json.dumps(data, indent=1) + "\n")
    return data


def generalist_policy(policy: Path, vehicle: str, folder: Path) -> dict:
    """The generalist for `vehicle`: `quad-export --vehicle` into folder/generalist.onnx, timed."""
    folder.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "quadpilot.export.cli", str(policy), "-o", str(folder / "generalist.onnx")]
    done = subprocess.run([*cmd, "--vehicle", vehicle], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"airframes: quad-export --vehicle {vehicle} failed: {done.stderr.strip()[-300:]}")
    return {"command": f"quad-export {policy.name} --vehicle FILE", "file_to_policy_s": time.perf_counter() - t0}


def training_record(run_dir: Path) -> dict:
    """A training run's command, steps, time and evaluation (config.json, metrics.csv, eval.json);
    for a run started from another policy (quad-train --init-from), that run's record too, when its
    folder is beside the policy it names."""
    from quadpilot.train.runs.runlog import read_metrics

    def read(name: str) -> dict:
        return json.loads((run_dir / name).read_text()) if (run_dir / name).is_file() else {}

    ev, config = read("eval.json"), read("config.json")
    m = read_metrics(run_dir / "metrics.csv") if (run_dir / "metrics.csv").is_file() else {}
    rows = len(m.get("update", ()))
    out = {
        "command": config.get("command", "quad-train " + " ".join(GENERALIST_TRAIN)),
        "steps": int(m["global_step"][-1]) if rows else 0,
        "train_s": float(m["time_s"][-1]) if rows else math.nan,
        "eval_success_rate": ev.get("success_rate"),
        "eval_mean_final_distance_m": ev.get("mean_final_distance_m"),
    }
    if "init_from" in config:  # the run it started from, when its folder is there
        source = Path(config["init_from"]["policy"]).parent
        there = source != run_dir and (source / "config.json").is_file()
        out["init_from"] = {**config["init_from"], **(training_record(source) if there else {})}
    return out


def _flown_json(out: Path, episodes: int | None) -> tuple[dict, int]:
    """The JSON `run` wrote, and the episodes per cell to fly (its own unless `episodes` is given,
    which must then match)."""
    if not out.is_file():
        raise SystemExit(f"airframes: {out}: no such file; `airframes.py run {out}` writes it first")
    data = json.loads(out.read_text())
    if episodes is not None and data.get("episodes") != episodes:
        raise SystemExit(f"airframes: {out} was flown with {data.get('episodes')} episodes; give --episodes to match")
    return data, data["episodes"]


def run_generalist(
    out: Path, airframes: list[str], policy: Path, policies: Path, episodes: int | None, flights: dict | None = None
) -> dict:
    """The generalist on `airframes` in our simulator, into `out` (the JSON `run` wrote), with the
    training run's record (policy's folder: config.json, eval.json, metrics.csv)."""
    data, episodes = _flown_json(out, episodes)
    digest = _digest(policy)
    if flights and data.get("generalist_training", {}).get("sha256", digest) != digest:
        raise SystemExit(
            f"airframes: the generalist's flights in {out} were flown by another policy file than {policy}; "
            "run `generalist` without --flight to export and fly it whole"
        )
    _keep_tuneds_generalist(data, digest)
    data["generalist_training"] = {**training_record(policy.parent), "sha256": digest}
    commit = _commit()
    with tempfile.TemporaryDirectory() as tmp:
        for name in airframes:
            vehicle = AIRFRAMES[name]
            rows = data["airframes"].setdefault(name, {"vehicle": vehicle.replace(str(ROOT) + "/", "")})
            rows["generalist_export"] = generalist_policy(policy, vehicle, policies / name)
            if not flights:  # a new export, perhaps of another policy file: RotorPy's rows flew the old one
                _forget_rotorpy(rows, "generalist")
            rows["generalist_export"]["run"] = {"commit": commit, "load_1min_before": os.getloadavg()[0]}
            made = str(policies / name / "generalist.onnx")
            flown = {f: fly(made, vehicle, args, Path(tmp), episodes) for f, args in (flights or FLIGHTS).items()}
            # named flights join the others (a new export of the same policy file flies as the old)
            rows["generalist"] = {**rows.get("generalist", {}), **flown} if flights else flown
            _stamp(rows, "generalist_flights_run", flown, rows["generalist_export"]["run"], bool(flights))
            for f, r in flown.items():
                print(f"{name} generalist {f}: {r}", flush=True)
            out.write_text(json.dumps(data, indent=1) + "\n")
    return data


def _keep_tuneds_generalist(data: dict, digest: str) -> None:
    """Keep, under `TUNED_FROM`, the record of the generalist the tuned policies were trained on
    from, while the generalist of the JSON (`digest`, its policy file's sha256) is another one; drop
    it once no tuned policy comes from it. A record from before the records held a checksum is taken
    to be the one tuned came from."""
    made_from = {r["tuned_training"]["init_from_sha256"] for r in data["airframes"].values() if "tuned_training" in r}
    kept = data.get(TUNED_FROM)
    if kept is not None and (made_from <= {digest} or kept.get("sha256") not in (None, *made_from)):
        del data[TUNED_FROM]
    old = data.get("generalist_training")
    if TUNED_FROM not in data and made_from - {digest} and old and old.get("sha256") in (None, *made_from):
        data[TUNED_FROM] = old


def run_tuned(
    out: Path,
    airframes: list[str],
    policy: Path,
    policies: Path,
    episodes: int | None,
    flights: dict | None = None,
    train_flags: list[str] | None = None,
) -> dict:
    """`tuned` on `airframes`, into `out` (the JSON `run` wrote): the generalist `policy` trained on
    with each airframe's vehicle file (`TUNE`, into DIR/AIRFRAME/tuned/), timed from the file to a
    checked policy.onnx like `ours`, and flown on the same flights. Named `flights` are added to an
    airframe's earlier ones with the policy already there; without them it is trained again (its
    RotorPy rows, of the earlier policy, are dropped)."""
    data, episodes = _flown_json(out, episodes)
    digest = _digest(policy)
    commit = _commit()
    with tempfile.TemporaryDirectory() as tmp:
        for name in airframes:
            vehicle = AIRFRAMES[name]
            rows = data["airframes"].setdefault(name, {"vehicle": vehicle.replace(str(ROOT) + "/", "")})
            folder = policies / name / TUNED
            when = _when(commit)
            if flights is None or not (folder / "policy.onnx").is_file() or TUNED not in rows:
                fresh = folder.with_name(f"{TUNED}.new")  # the earlier policy stays until this one is made
                shutil.rmtree(fresh, ignore_errors=True)
                trained = train(vehicle, fresh, ["--init-from", str(policy), *(train_flags or [])], TUNE)
                shutil.rmtree(folder, ignore_errors=True)
                fresh.rename(folder)
                _forget_rotorpy(rows, TUNED)  # flown by the earlier policy
                rows["tuned_training"] = {**trained, "init_from_sha256": digest, "run": when}
                rows[TUNED] = {}
                rows.pop("tuned_flights_run", None)
                print(f"{name} tuned trained: {rows['tuned_training']}", flush=True)
            elif rows.get("tuned_training", {}).get("init_from_sha256") != digest:
                raise SystemExit(
                    f"airframes: {name}: its tuned policy was made from another generalist than {policy}; "
                    "run `tuned` without --flight to train it again"
                )
            made = str(folder / "policy.onnx")
            flown = {f: fly(made, vehicle, args, Path(tmp), episodes) for f, args in (flights or FLIGHTS).items()}
            rows[TUNED] = {**rows[TUNED], **flown}
            _stamp(rows, "tuned_flights_run", flown, when, bool(flights))
            for f, r in flown.items():
                print(f"{name} tuned {f}: {r}", flush=True)
            _keep_tuneds_generalist(data, data.get("generalist_training", {}).get("sha256", ""))
            out.write_text(json.dumps(data, indent=1) + "\n")
    return data


def run_rotorpy(
    out: Path,
    airframes: list[str],
    policies: Path,
    flights: list[str] | None = None,
    controllers: list[str] | None = None,
    missed_only: bool = False,
) -> dict:
    """RotorPy's side of `airframes` (vehicle files only), RAPTOR, the policies `run` trained into
    `policies`, the generalist exported there and tuned trained there, written into `out` (the JSON `run` wrote) under
    each airframe's "rotorpy"; `controllers`: only these (the others' rows are kept). A flight in
    which RotorPy stepped on without the node's answer (`missed_steps`: RotorPy waits 10 ms, and a
    late answer then lags every later step by one) is flown again, up to `ATTEMPTS` times in all;
    `attempts` records how many it took. `missed_only`: only the cells of `out` that have missed steps."""
    import rotorpy_flights

    t = rotorpy_flights._load_test_module()
    data = json.loads(out.read_text())
    commit = _commit()
    files = {"ours": "policy.onnx", "generalist": "generalist.onnx", TUNED: f"{TUNED}/policy.onnx"}
    for name in airframes:
        vehicle = AIRFRAMES[name]
        if not vehicle.endswith(".toml"):  # a preset: RotorPy flies vehicle files
            continue
        for c in [c for c in controllers or ("ours",) if c in files]:
            if name not in data["airframes"] or not (policies / name / files[c]).is_file():
                made_by = {
                    "ours": "run",
                    "generalist": "generalist --policy GENERALIST.pt",
                    TUNED: "tuned --policy GENERALIST.pt",
                }
                raise SystemExit(
                    f"airframes: {name}: no {policies / name / files[c]}; "
                    f"run `airframes.py {made_by[c]} {out} --policies {policies}` first"
                )
        rows = data["airframes"][name]
        side = rows.setdefault("rotorpy", {})
        when = _when(commit)
        chosen = {"raptor": "raptor:foundation", **{c: str(policies / name / f) for c, f in files.items()}}
        for controller in controllers or ("raptor", "ours"):
            policy = chosen[controller]
            whole = controllers is None and flights is None and not missed_only
            what = "the flights with missed steps, again" if missed_only else ", ".join(flights or ROTORPY_DEFAULT)
            side["run" if whole else f"run {controller}: {what}"] = when
            side[controller] = {**side.get(controller, {})}  # flights flown before and not now are kept
            named = flights or (list(side[controller]) if missed_only else ROTORPY_DEFAULT)  # --missed: every cell
            for f in named:
                if missed_only and not side[controller].get(f, {}).get("missed_steps"):
                    continue
                for attempt in range(1, ATTEMPTS + 1):
                    with tempfile.TemporaryDirectory() as tmp:
                        flown = rotorpy_flight(t, policy, vehicle, f, Path(tmp))
                    side[controller][f] = {**flown, "attempts": attempt}
                    if not flown.get("missed_steps"):
                        break
                print(f"{name} rotorpy {controller} {f}: {side[controller][f]}", flush=True)
        out.write_text(json.dumps(data, indent=1) + "\n")  # after each airframe: a long run keeps what it flew
    return data


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("out", type=Path)
    r.add_argument("--airframe", action="append", choices=sorted(AIRFRAMES), help="Default: every one.")
    r.add_argument("--episodes", type=int, default=EPISODES)
    r.add_argument("--merge", action="store_true", help="Update these airframes in OUT, keep the others.")
    r.add_argument("--policies", type=Path, help="Keep the trained policies in DIR/AIRFRAME/. Default: discarded.")
    r.add_argument("--reuse", action="store_true", help="Fly the policies already in --policies, train the others.")
    r.add_argument("--train", action="append", default=[], metavar="FLAG", help="More quad-train flags (smoke runs).")
    r.add_argument("--flight", action="append", choices=sorted(FLIGHTS), help="Default: every one.")
    rp = sub.add_parser("rotorpy", help="RotorPy's side, into the JSON `run` wrote, with the policies it kept.")
    rp.add_argument("out", type=Path)
    rp.add_argument("--policies", type=Path, required=True)
    rp.add_argument("--airframe", action="append", choices=sorted(AIRFRAMES), help="Default: every vehicle file.")
    rp.add_argument(
        "--flight", action="append", choices=sorted(ROTORPY_FLIGHTS), help=f"Default: {', '.join(ROTORPY_DEFAULT)}."
    )
    rp.add_argument(
        "--controller", action="append", choices=("raptor", "ours", "generalist", TUNED), help="Default: raptor, ours."
    )
    rp.add_argument("--missed", action="store_true", help="Fly again only the cells of OUT with missed steps.")
    for cmd, what, policy, writes, flight in (
        (
            "generalist",
            "The generalist, exported per airframe, in our simulator.",
            "The generalist's policy.pt (GENERALIST_TRAIN).",
            "Writes DIR/AIRFRAME/generalist.onnx (and .pt).",
            "Default: every one.",
        ),
        (
            TUNED,
            "The generalist trained on per vehicle file (TUNE), in our simulator.",
            "The generalist's policy.pt, to start from.",
            "Writes DIR/AIRFRAME/tuned/.",
            "Fly these with the tuned policy already there. Default: train DIR/AIRFRAME/tuned/ again, fly every one.",
        ),
    ):
        g = sub.add_parser(cmd, help=what)
        g.add_argument("out", type=Path)
        g.add_argument("--policy", type=Path, required=True, help=policy)
        g.add_argument("--policies", type=Path, required=True, help=writes)
        g.add_argument("--airframe", action="append", choices=sorted(AIRFRAMES), help="Default: every one.")
        g.add_argument("--episodes", type=int, help="Episodes per cell. Default: OUT's.")
        g.add_argument("--flight", action="append", choices=sorted(FLIGHTS), help=flight)
    args = p.parse_args(argv)
    airframes = args.airframe or list(AIRFRAMES)
    if docs_quick() and args.cmd != "rotorpy":  # console.docs_quick: one airframe, flight and episode
        airframes, args.flight, args.episodes = airframes[:1], args.flight or list(FLIGHTS)[:1], quick(args.episodes, 1)
    if args.cmd == "rotorpy":  # its --flight names RotorPy's flights
        run_rotorpy(args.out, airframes, args.policies, args.flight, args.controller, args.missed)
        return 0
    chosen = {f: FLIGHTS[f] for f in args.flight} if args.flight else None
    if args.cmd in ("generalist", TUNED):
        if args.cmd == "generalist":
            run_generalist(args.out, airframes, args.policy, args.policies, args.episodes, chosen)
        else:  # under the switch, one short rollout of a few drones (TUNE's 256 make one rollout long)
            quick_flags = ["--num-envs", "16"] if docs_quick() else []
            run_tuned(args.out, airframes, args.policy, args.policies, args.episodes, chosen, quick_flags)
        return 0
    run(args.out, airframes, args.episodes, args.merge, args.policies, args.reuse, args.train, chosen)
    return 0


if __name__ == "__main__":
    sys.exit(main())
