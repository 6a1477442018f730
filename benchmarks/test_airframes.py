"""Smoke test of benchmarks/airframes.py (the whole table is `benchmarks/airframes.py run`, then
`rotorpy`): one airframe from its vehicle file, every controller, in both simulators. `ours` is
trained for a few thousand steps only (the table's shape, not its figures), so only RAPTOR's hover
is held to the hover rule here (it flies the X500: docs/raptor.md). The generalist likewise: trained
for a few thousand steps over drawn airframes, exported for the X500's file, flown in both; and
`tuned`, that generalist trained on with the X500's file for a few thousand steps more."""

import hashlib
import json
import math
import subprocess
import sys

import pytest

import airframes
import report_airframes

FLIGHTS = {f: airframes.FLIGHTS[f] for f in ("hover", "mass+30%", "impulse", "step", "figure8 1 m/s")}


def test_one_airframe_from_its_file_in_both_simulators_for_every_controller(tmp_path):
    out, policies = tmp_path / "a.json", tmp_path / "policies"
    data = airframes.run(
        out, ["x500"], episodes=1, policies=policies, train_flags=["--total-steps", "8192"], flights=FLIGHTS
    )
    rows = data["airframes"]["x500"]
    t = rows["ours_training"]
    assert t["file_to_policy_s"] == t["train_s"] + t["export_s"] and 0.0 <= t["eval_success_rate"] <= 1.0
    assert (policies / "x500" / "policy.onnx").is_file() and (policies / "x500" / "training.json").is_file()
    for controller in ("raptor", "ours"):
        assert set(rows[controller]) == set(FLIGHTS)
        assert all("refused" not in r for r in rows[controller].values()), rows[controller]
        assert rows[controller]["step"]["overshoot_pct"] >= 0.0
        assert math.isfinite(rows[controller]["figure8 1 m/s"]["tracking_rms_m"])
    hover = rows["raptor"]["hover"]
    assert hover["success_rate"] == 1.0 and hover["mean_error_last_2s_m"] <= 0.05, hover

    data = airframes.run_rotorpy(out, ["x500"], policies, flights=["hover", "step"])
    side = json.loads(out.read_text())["airframes"]["x500"]["rotorpy"]
    for controller in ("raptor", "ours"):
        for f in ("hover", "step"):
            r = side[controller][f]
            assert "failed" not in r and r["steps"] == 500 and r["node_returncode"] in (0, 1), r
    step = side["raptor"]["step"]  # RAPTOR from rest with its rotors at rest, in RotorPy
    assert 0.0 <= step["overshoot_pct"] < 50.0 and step["final_error_m"] < 0.2, step
    assert side["raptor"]["hover"]["mean_error_last_2s_m"] <= 0.05, side["raptor"]
    r = report_airframes
    for table in (r.holding, r.moving, r.rotorpy):
        assert "| x500 | raptor |" in table(data) and "| x500 | ours |" in table(data)
    assert "| x500 |" in r.training(data)

    # the generalist: quad-train's recipe cut short, exported for the file, flown in both simulators
    brief = ["--total-steps", "4096", "--num-envs", "16", "--eval-episodes", "4", "--eval-every", "0"]
    cmd = [sys.executable, "-m", "quadpilot.train.cli", *airframes.GENERALIST_TRAIN, *brief]
    subprocess.run([*cmd, "--out", str(tmp_path / "generalist")], check=True, capture_output=True)
    policy = tmp_path / "generalist" / "policy.pt"
    data = airframes.run_generalist(out, ["x500"], policy, policies, 1, {f: FLIGHTS[f] for f in ("hover", "impulse")})
    rows = data["airframes"]["x500"]
    assert rows["generalist_export"]["file_to_policy_s"] > 0.0 and data["generalist_training"]["steps"] >= 4096
    assert set(rows["generalist"]) == {"hover", "impulse"} and "refused" not in rows["generalist"]["hover"]
    assert set(rows["ours"]) == set(FLIGHTS)  # the others' rows kept
    data = airframes.run_rotorpy(out, ["x500"], policies, flights=["hover"], controllers=["generalist"])
    side = data["airframes"]["x500"]["rotorpy"]
    assert "failed" not in side["generalist"]["hover"] and side["raptor"]["step"] == step  # RAPTOR's kept
    # a wrong file in RotorPy: its plant 30 % heavier than the file RAPTOR is flown with
    data = airframes.run_rotorpy(out, ["x500"], policies, flights=["mass+30%"], controllers=["raptor"])
    raptor = data["airframes"]["x500"]["rotorpy"]["raptor"]
    heavy, nominal = raptor["mass+30%"]["mean_error_last_2s_m"], raptor["hover"]["mean_error_last_2s_m"]
    assert "failed" not in raptor["mass+30%"] and heavy != nominal  # the same flight on another plant
    assert "| x500 | generalist |" in r.holding(data) and "| x500 | generalist |" in r.rotorpy(data)

    # tuned: that generalist trained on with the X500's file, timed, flown in both simulators
    data = airframes.run_tuned(out, ["x500"], policy, policies, 1, {"hover": FLIGHTS["hover"]}, brief)
    rows = data["airframes"]["x500"]
    t = rows["tuned_training"]
    assert t["file_to_policy_s"] == t["train_s"] + t["export_s"] and "--init-from" in t["command"]
    assert t["init_from_sha256"] == hashlib.sha256(policy.read_bytes()).hexdigest()
    assert set(rows["tuned"]) == {"hover"} and "refused" not in rows["tuned"]["hover"]
    data = airframes.run_rotorpy(out, ["x500"], policies, flights=["hover"], controllers=["tuned"])
    assert "failed" not in data["airframes"]["x500"]["rotorpy"]["tuned"]["hover"]
    for table in (r.holding, r.rotorpy, r.training):
        assert "| x500 | tuned |" in table(data)


def test_rerunning_a_subcommand_keeps_what_the_others_wrote(tmp_path, monkeypatch):
    """The table is built by four subcommands into one JSON: `run` again (whole, or one flight)
    keeps the generalist's, tuned's and RotorPy's rows and the generalist and tuned policies beside
    the policy, `generalist --flight` and `tuned --flight` add their flights to the earlier ones, and
    `tuned` trained again drops its earlier RotorPy rows. Training and flying are stood in for: this
    is the JSON's and the folder's bookkeeping, which the smoke test above flies."""
    out, policies = tmp_path / "a.json", tmp_path / "policies"

    def fly(policy, vehicle, flight, tmp, episodes=airframes.EPISODES):
        return {"success_rate": 1.0, "flight": " ".join(flight)}

    def train(vehicle, folder, extra, flags=airframes.TRAIN):
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "policy.onnx").write_text("trained")
        return {k: 1.0 for k in ("train_s", "export_s", "file_to_policy_s", *airframes.EVAL_KEYS)}

    monkeypatch.setattr(airframes, "train", train)
    monkeypatch.setattr(airframes, "fly", fly)
    monkeypatch.setattr(airframes, "generalist_policy", lambda p, v, folder: {"command": "x", "file_to_policy_s": 1})
    airframes.run(out, ["x500"], episodes=1, policies=policies)
    (policies / "x500" / "generalist.onnx").write_text("exported")
    run_dir = tmp_path / "gen"
    run_dir.mkdir()
    general = run_dir / "policy.pt"
    general.write_bytes(b"the generalist")
    airframes.run_generalist(out, ["x500"], general, policies, 1)
    airframes.run_tuned(out, ["x500"], general, policies, 1)
    airframes.run_tuned(out, ["x500"], general, policies, None, {"wind": airframes.FLIGHTS["wind"]})  # OUT's episodes
    data = json.loads(out.read_text())
    flown = {"hover": {"success": True}}
    side = {"ours": flown, "generalist": flown, "tuned": flown, "run ours: hover": {}, "run tuned: hover": {}}
    data["airframes"]["x500"]["rotorpy"] = side
    out.write_text(json.dumps(data))

    airframes.run(out, ["x500"], episodes=1, merge=True, policies=policies)  # the whole airframe again
    rows = json.loads(out.read_text())["airframes"]["x500"]
    assert set(rows["generalist"]) == set(airframes.FLIGHTS) and "generalist_export" in rows
    digest = hashlib.sha256(b"the generalist").hexdigest()
    assert set(rows["tuned"]) == set(airframes.FLIGHTS) and rows["tuned_training"]["init_from_sha256"] == digest
    assert set(rows["tuned_flights_run"]) == {"wind"}  # when the added flight was flown: kept
    kept = {"generalist": flown, "tuned": flown, "run tuned: hover": {}}
    assert rows["rotorpy"] == kept  # ours was trained again: its RotorPy rows went
    assert (policies / "x500" / "generalist.onnx").read_text() == "exported"  # retraining kept it
    assert (policies / "x500" / "tuned" / "policy.onnx").read_text() == "trained"

    general.write_bytes(b"another generalist")  # a flight added must be flown by the policy made from it
    with pytest.raises(SystemExit, match="made from another generalist"):
        airframes.run_tuned(out, ["x500"], general, policies, 1, {"step": airframes.FLIGHTS["step"]})
    with pytest.raises(SystemExit, match="no such file"):
        airframes.run_tuned(out, ["x500"], run_dir / "missing.pt", policies, 1)
    with pytest.raises(SystemExit, match="no such file"):
        airframes.run_generalist(out, ["x500"], run_dir / "missing.pt", policies, 1)
    airframes.run_tuned(out, ["x500"], general, policies, 1)  # all again: trained again
    rows = json.loads(out.read_text())["airframes"]["x500"]
    assert rows["rotorpy"] == {"generalist": flown} and "tuned_flights_run" not in rows
    assert rows["tuned_training"]["init_from_sha256"] == hashlib.sha256(b"another generalist").hexdigest()

    with pytest.raises(SystemExit, match="flown by another policy file"):  # its rows are the first generalist's
        airframes.run_generalist(out, ["x500"], general, policies, 1, {"wind": airframes.FLIGHTS["wind"]})
    airframes.run_generalist(out, ["x500"], general, policies, 1)  # exported again: RotorPy flew the old one
    data = json.loads(out.read_text())
    assert data["airframes"]["x500"]["rotorpy"] == {} and airframes.TUNED_FROM not in data  # tuned is from this one
    data["airframes"]["x500"]["rotorpy"] = {"generalist": flown, "ours": flown, "run generalist: hover": {}}
    out.write_text(json.dumps(data))
    airframes.run_generalist(out, ["x500"], general, policies, 1, {"wind": airframes.FLIGHTS["wind"]})
    rows = json.loads(out.read_text())["airframes"]["x500"]
    assert set(rows["generalist"]) == set(airframes.FLIGHTS) and set(rows["generalist_flights_run"]) == {"wind"}
    assert rows["rotorpy"]["generalist"] == flown  # a flight added to the same export keeps RotorPy's rows

    # a new generalist: the record of the one tuned came from is kept until no tuned policy comes from it
    def generalist(content: bytes) -> dict:
        general.write_bytes(content)
        airframes.run_generalist(out, ["x500"], general, policies, 1)
        return json.loads(out.read_text())

    data = generalist(b"a third generalist")
    assert data["airframes"]["x500"]["rotorpy"] == {"ours": flown}  # only the generalist's rows went
    assert data[airframes.TUNED_FROM]["sha256"] == hashlib.sha256(b"another generalist").hexdigest()
    assert data["generalist_training"]["sha256"] == hashlib.sha256(b"a third generalist").hexdigest()
    airframes.run_tuned(out, ["x500"], general, policies, 1)
    assert airframes.TUNED_FROM not in json.loads(out.read_text())
    data = generalist(b"a fourth generalist")  # tuned came from the third
    assert data[airframes.TUNED_FROM]["sha256"] == hashlib.sha256(b"a third generalist").hexdigest()
    general.write_bytes(b"neither")  # tuned made from a file that is neither: the kept record is not tuned's
    airframes.run_tuned(out, ["x500"], general, policies, 1)
    data = json.loads(out.read_text())
    assert airframes.TUNED_FROM not in data
    # a record written before records held a checksum is taken to be tuned's
    del data["generalist_training"]["sha256"]
    out.write_text(json.dumps(data))
    data = generalist(b"a fifth generalist")
    assert data[airframes.TUNED_FROM]["command"] and "sha256" not in data[airframes.TUNED_FROM]
