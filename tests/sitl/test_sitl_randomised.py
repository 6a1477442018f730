"""The shipped domain-randomised hover policy flown by quad-sitl on the perturbed
plant where the nominal policy sags 18 cm: mass ×1.15, k_f ×0.92, 1 m/s wind."""

import json
from pathlib import Path

import pytest

from quadpilot.sitl import main

pytestmark = pytest.mark.sitl

HOVER_DR = Path(__file__).parents[2] / "models" / "hover_dr" / "policy.onnx"


def test_randomised_hover_policy_holds_a_heavy_weak_vehicle_in_wind(tmp_path, capsys):
    out = tmp_path / "dr.json"
    flags = ["--mass-scale", "1.15", "--motor-scale", "0.92", "--wind", "1,0,0"]
    assert (
        main([str(HOVER_DR), "--episodes", "2", "--gcs", "none", "--json", str(out), "--min-success", "1", *flags]) == 0
    )
    s = json.loads(out.read_text())
    assert s["success_rate"] == 1.0 and s["crashes"] == 0, s
    assert s["mean_error_last_2s_m"] < 0.03, s  # 1.9 cm over 100 episodes in-process
    assert s["fallback_steps"] == 0
