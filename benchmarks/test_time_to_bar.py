"""Smoke test of benchmarks/time_to_bar.py: both versions train (a short run each) from the same
command and the JSON holds what docs/benchmarks.md reads. The measurement itself is run on purpose
(its docstring has the command); a 16,384-step run does not reach the bar."""

from __future__ import annotations

import json

import report_time_to_bar
import time_to_bar


def test_time_to_bar_smoke(tmp_path, capsys):
    out = tmp_path / "ttb.json"
    assert time_to_bar.main(["--seeds", "0", "--total-steps", "16384", "--out", str(out), "--work", str(tmp_path)]) == 0
    r = json.loads(out.read_text())
    assert r["baseline_commit"] == "bb5efb7"
    for name in ("baseline", "today"):
        (run,) = r["runs"][name]
        assert run["global_step"] == 16384 and 0.0 <= run["final_success_rate"] <= 1.0
        assert (tmp_path / f"{name}-seed0" / "eval.json").is_file()
    # the baseline really is the old code: its hover judge did not look at the heading yet
    heading = "max_mean_heading_error_last_window_deg"
    assert heading in json.loads((tmp_path / "today-seed0" / "eval.json").read_text())
    assert heading not in json.loads((tmp_path / "baseline-seed0" / "eval.json").read_text())
    assert r["speedup_median"] is None and r["every_seed_reached"] == {"baseline": False, "today": False}
    assert report_time_to_bar.main([str(out)]) == 0
    assert "| 0 | not reached | not reached |" in capsys.readouterr().out
