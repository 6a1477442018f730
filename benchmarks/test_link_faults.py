"""Smoke test of benchmarks/link_faults.py and its report: one short episode per condition of a few
conditions, the JSON docs/robustness.md is generated from, and the tables. The measurement itself is run
on purpose (its docstring has the command)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import link_faults
import report_link_faults


def test_link_faults_smoke(tmp_path, capsys):
    out = tmp_path / "lf.json"
    only = ["none", "loss 5%", "NaN in state", "state dropout 0.5 s"]
    argv = ["--episodes", "1", "--goal-episodes", "1", "--rates", "100", "--jobs", "2", "--only", *only]
    assert link_faults.main([*argv, "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    rows = {r["condition"]: r for r in doc["rows"]}
    assert set(rows) == set(only) and doc["process_crashes"] == 0
    for r in rows.values():
        assert r["episodes"] == 1 and r["rate_hz"] == 100 and not r["crashed_process"]
    lossy = rows["loss 5%"]["link_impair"]
    assert lossy["up"]["frames"] > 400 and lossy["down"]["frames"] > 900  # both ways relayed, frame by frame
    assert rows["NaN in state"]["monitor_events"]["blind_steps"] == 1  # the fault reached the node
    dropout = rows["state dropout 0.5 s"]  # flown through on the node's estimate, in real time too
    assert dropout["failsafes"] == 0 and dropout["successes"] == 1 and dropout["state_lost_steps"] == 50
    capsys.readouterr()
    assert report_link_faults.main([str(out)]) == 0
    text = capsys.readouterr().out
    assert "| loss 5%: `loss=5%` | 100 | 1/1 | 0 |" in text
    assert "50 steps without a state flown on the node's estimate" in text


def test_link_faults_help_exits_0():
    # a goal's name holds a % ("loss 5%"), which argparse's help formatting would read as a format
    script = Path(link_faults.__file__)
    proc = subprocess.run([sys.executable, str(script), "--help"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    assert "episodes of loss 5%, delay 20 ms" in proc.stdout
