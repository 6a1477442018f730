"""The reports of a study still come out for runs too short to have figures: a seed whose every
evaluation episode crashed has no error (None, `train.envs.evaluate`), and a run too short to clock a
positive training time has no point on a log-scale seconds axis."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np

from quadpilot.studies import sac_compare

ROOT = Path(__file__).resolve().parents[2]


def _ablation():
    spec = importlib.util.spec_from_file_location("recurrent_ablation", ROOT / "docs" / "recurrent" / "ablation.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_the_ablation_table_leaves_out_a_seed_without_an_error_and_dashes_a_cell_without_any():
    def row(seed, err):
        res = {"success_rate": 0.0, "crash_rate": 1.0, "mean_error_last_window_m": err, "max_error_last_window_m": err}
        return {"group": "mlp", "seed": seed, "steps": 1, "train_time_s": 1.0, "first_success": None,
                "results": {"trained": dict(res), "delay": dict(res, mean_error_last_window_m=None)}}  # fmt: skip

    data = {"conditions": {"trained": {}, "delay": {}}, "runs": {"a": row(0, 0.02), "b": row(1, None)}}
    text = _ablation().tables(data)
    error_row = next(line for line in text.splitlines() if line.startswith("|") and "2.00" in line)
    assert error_row.split("|")[2:4] == [" 2.00 ", " – "]


def test_the_sac_figure_is_drawn_for_runs_that_clocked_no_time(tmp_path):
    def run(algo):
        metrics = {
            "global_step": np.array([8192.0]),
            "time_s": np.array([0.0]),
            "eval_success_rate": np.array([0.0]),
            "eval_error_m": np.array([np.nan]),
        }
        return {"algo": algo, "metrics": metrics}

    png = sac_compare.plot([run("ppo"), run("sac")], tmp_path / "f.png", "short")
    assert Path(png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_sac_figure_is_drawn_when_runs_clocked_time_but_have_no_error(tmp_path):
    """Seconds on the clock (a log axis for them) but every evaluation crashed: the error panel against
    seconds has no point, so its own x axis stays linear (the SAC block of docs/comparison.md, run short)."""

    def run(algo, evaluated):
        metrics = {
            "global_step": np.array([2048.0]),
            "time_s": np.array([0.05]),
            "eval_success_rate": np.array([0.0 if evaluated else np.nan]),
            "eval_error_m": np.array([np.nan]),
        }
        return {"algo": algo, "metrics": metrics}

    png = sac_compare.plot([run("ppo", True), run("sac", False)], tmp_path / "f.png", "short")
    assert Path(png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
