"""Smoke test of benchmarks/waypoint_seeds.py: a short waypoint run per seed and the JSON that
docs/benchmarks.md reads. The measurement itself is run on purpose (its docstring has the command);
a 16,384-step run does not reach the bar."""

from __future__ import annotations

import json

import waypoint_seeds


def test_waypoint_seeds_smoke(tmp_path):
    out = tmp_path / "wps.json"
    assert waypoint_seeds.main(["--seeds", "0", "1", "--total-steps", "16384", "--out", str(out)]) == 0
    r = json.loads(out.read_text())
    assert [run["seed"] for run in r["runs"]] == [0, 1]
    for run in r["runs"]:
        assert run["global_step"] == 16384 and 0.0 <= run["success_rate"] <= 1.0
        assert run["worst_heading_error_deg"] is None or run["worst_heading_error_deg"] >= 0.0  # None: all crashed
    assert r["seeds_at_bar"] == 0
    assert r["worst_heading_error_deg"] == max(run["worst_heading_error_deg"] or 0.0 for run in r["runs"])
