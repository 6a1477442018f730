"""Smoke test of benchmarks/soak.py: a few thousand lockstep steps and a few seconds of real time,
the same code and JSON as the 1,000,000-step and 30-minute soaks (their commands are in its docstring)."""

from __future__ import annotations

import json

import pytest

import soak


@pytest.mark.parametrize(
    "flags", [["--steps", "3000", "--episodes", "3"], ["--realtime", "--seconds", "3", "--episodes", "2"]]
)
def test_soak_smoke(tmp_path, flags):
    out = tmp_path / "soak.json"
    assert soak.main([*flags, "--out", str(out)]) == 0
    r = json.loads(out.read_text())
    episodes = int(flags[-1])
    assert len(r["episodes"]) == episodes and r["sim_steps"] >= r["steps"] - episodes > 0
    assert all(e["node_rss_mib"] > 10 and e["sim_rss_mib"] > 10 for e in r["episodes"])  # both processes read
    assert r["node_rss_growth_mib"] == r["episodes"][-1]["node_rss_mib"] - r["episodes"][0]["node_rss_mib"]
    assert r["step_time_ms"]["n"] >= r["steps"] - 2 * episodes  # one period per step after the first
    if "--realtime" not in flags:
        assert r["steps"] == 3000 and r["lost_steps"] == 0 and r["failsafes"] == 0  # lockstep loses nothing
        assert all(e["sim_end"] == "peer_closed" for e in r["episodes"])
