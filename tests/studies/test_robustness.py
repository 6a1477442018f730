"""The robustness harness (docs/robustness.md): the scenario runner reproduces `evaluate` for a policy, flies
a trivial controller exactly as the physics says, measures settling and overshoot correctly, and
the grid cells are the plants quad-sitl's flags make."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from quadpilot.core.vehicle_file import SEED_VEHICLE
from quadpilot.simulator import DEFAULT_WIND_DRAG, SimConfig
from quadpilot.studies.robustness import (
    SCENARIOS,
    Cell,
    FallbackBank,
    Flight,
    PolicyController,
    evaluate_grid,
    fly,
    grid,
    grid_table,
    hover_config,
    run_scenario,
    scenario_metrics,
    scenario_table,
    summarise,
)
from quadpilot.train.algorithms import load_policy
from quadpilot.train.envs.evaluate import evaluate

HOVER = Path(__file__).parents[2] / "models" / "hover" / "policy.pt"
M = SEED_VEHICLE.mass


class Trim:
    """Holds the nominal hover command whatever it sees: no feedback at all."""

    output = "action"
    name = "trim"

    def reset(self, n):
        pass

    def __call__(self, obs):
        return np.zeros((obs.shape[0], 4), np.float32)


@pytest.mark.parametrize("cell", [Cell(), Cell(1.15, 0.92, 1.0)], ids=["nominal", "heavy-weak-windy"])
def test_the_runner_reproduces_evaluate_for_a_policy(cell):
    policy = load_policy(HOVER)
    cfg = dataclasses.replace(hover_config(), randomization=cell.plant)
    want = evaluate(policy, cfg, episodes=12, seed=3)
    flight = fly(PolicyController(policy), cfg, 12, seed=3)
    got = summarise(flight, cfg)
    for k, v in got.items():
        assert v == pytest.approx(want[k], rel=0, abs=0, nan_ok=True), k
    assert flight.ep_return.mean() == pytest.approx(want["mean_return"], rel=1e-12)


def test_push_on_a_trim_controller_follows_newton():
    """No feedback: 1 N for 0.2 s gives 0.2/m m/s, then the vehicle coasts (no drag)."""
    sc = SCENARIOS[0]
    assert sc.kind == "push"
    cfg = hover_config(dtype="float64")
    r = run_scenario(Trim(), sc, cfg, n=3)
    a = sc.magnitude / M
    t_after = sc.seconds - sc.onset_s - sc.duration_s
    x_end = 0.5 * a * sc.duration_s**2 + a * sc.duration_s * t_after
    assert r["peak_error_m"] == pytest.approx(x_end, rel=1e-6)
    assert r["settled"] == 0 and math.isnan(r["settling_time_s"])  # it never comes back
    assert r["overshoot_m"] == 0.0 and r["crashes"] == 0


def test_wind_step_on_a_trim_controller_drifts_towards_wind_speed():
    sc = next(s for s in SCENARIOS if s.kind == "wind")
    k = sc.drag / M
    out = run_scenario(Trim(), sc, hover_config(dtype="float64"), n=2)
    t = sc.seconds - sc.onset_s
    x = sc.magnitude * (t - (1 - math.exp(-k * t)) / k)  # ∫ w(1 − e^(−kτ)) dτ
    assert out["peak_error_m"] == pytest.approx(x, rel=2e-3)


def test_fallback_settles_after_the_push_and_the_wind_step():
    cfg = hover_config(dtype="float64")
    bank = FallbackBank(cfg.params, cfg.dt)
    push = run_scenario(bank, SCENARIOS[0], cfg, n=3)
    assert push["settled"] == 3 and push["settling_time_max_s"] < 3.0 and push["crashes"] == 0
    assert 0.02 < push["peak_error_m"] < 0.1
    wind = run_scenario(bank, SCENARIOS[1], cfg, n=2)
    assert wind["settled"] == 2 and wind["steady_error_m"] < 0.01  # the integrator takes the wind


def test_scenario_metrics_on_a_known_profile():
    """x(t) = e^(−t)·cos(2t) along +x from 1 m: overshoot = −min after the peak, settling = last
    time |x| > 5 cm."""
    dt = 0.01
    t = np.arange(0, 6.0 + dt / 2, dt)
    x = np.exp(-t) * np.cos(2 * t)
    states = np.zeros((t.size, 1, 12))
    states[:, 0, 0] = x
    flight = Flight(states, np.zeros((1, 3)), np.array([-1]), np.zeros(1), np.zeros(1), np.zeros(1), dt)
    m = scenario_metrics(flight, np.zeros(3), np.array([1.0, 0.0, 0.0]), 0)
    assert m["peak_error_m"] == pytest.approx(1.0)
    assert m["overshoot_m"] == pytest.approx(-x.min(), abs=1e-4)
    last_out = np.flatnonzero(np.abs(x) > 0.05)[-1]
    assert m["settling_time_s"] == pytest.approx((last_out + 1) * dt)


def test_cells_are_the_plants_quad_sitl_flies():
    cells = grid()
    assert len(cells) == 18 and Cell(1.15, 0.92, 1.0) in cells
    cell = Cell(1.15, 0.92, 1.0)
    sim = SimConfig(mass_scale=1.15, motor_scale=0.92, wind=(1.0, 0.0, 0.0))
    plant = cell.plant
    assert plant.mass == (1.15, 1.15) and plant.k_f == (0.92, 0.92)
    assert plant.drag == (sim.effective_drag, sim.effective_drag) == (DEFAULT_WIND_DRAG, DEFAULT_WIND_DRAG)
    assert plant.wind_speed == (1.0, 1.0) and plant.wind_direction_deg == 0.0
    assert cell.sitl_flags() == ["--mass-scale", "1.15", "--motor-scale", "0.92", "--wind", "1,0,0"]
    assert Cell().plant.drag is None and "--wind" not in Cell().sitl_flags()


def test_grid_and_tables_smoke():
    cfg = hover_config()
    cells = [Cell(), Cell(1.15, 1.0, 0.0)]
    res = {"trim": evaluate_grid(Trim(), cfg, cells, episodes=3)}
    text = grid_table(res)
    assert "| ×1.15 | ×1 | 0 |" in text and text.count("\n") == 3
    row = run_scenario(Trim(), SCENARIOS[0], hover_config(dtype="float64"), n=2)
    assert "2 of 2 never" in scenario_table([row])


def test_the_command_writes_json_markdown_and_a_model_eval(tmp_path):
    import json
    import shutil

    from quadpilot.studies.robustness import main

    eval_json = tmp_path / "eval.json"
    shutil.copy(HOVER.with_name("eval.json"), eval_json)
    args = ["--policy", f"hover={HOVER}", "--episodes", "1", "--drones", "1", "--out", str(tmp_path)]
    assert main([*args, "--write-eval", f"hover={eval_json}"]) == 0
    report = json.loads((tmp_path / "robustness.json").read_text())
    assert set(report["grid"]) == {"hover"} and len(report["grid"]["hover"]) == 18
    assert len(report["scenarios"]) == len(SCENARIOS) and "sitl" not in report
    md = (tmp_path / "robustness.md").read_text()
    assert "## In-process grid" in md and "| 1 m offset | hover |" in md
    ev = json.loads(eval_json.read_text())
    kept = json.loads(HOVER.with_name("eval.json").read_text())["success_rate"]  # the file's own entries stay
    assert ev["nominal"]["episodes"] == 100 and len(ev["grid_in_process"]) == 18 and ev["success_rate"] == kept
