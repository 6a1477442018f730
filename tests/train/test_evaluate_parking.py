"""Evaluation parks a drone once it has crashed: out of the evaluation, it is put back at rest at its
target instead of being stepped on while it tumbles to overflow and NaN, and nothing it reports
changes (every figure of a crashed drone is masked from its crash on)."""

from __future__ import annotations

import json
import warnings

import numpy as np

from quadpilot.train.envs import evaluate as evaluation
from quadpilot.train.envs import make_config


def one_motor(obs: np.ndarray) -> np.ndarray:
    """Full speed on one motor, the others off: every drone spins up and crashes."""
    return np.tile(np.array([1.0, 0.0, 0.0, 0.0], np.float32), (obs.shape[0], 1))


def test_crashed_drones_are_parked_and_the_report_is_the_same(monkeypatch):
    cfg = make_config("hover")
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # nothing overflows
        parked = evaluation.evaluate(one_motor, cfg, episodes=8, seed=1)
    assert parked["crash_rate"] == 1.0
    monkeypatch.setattr(evaluation, "_park", lambda batch, out: None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        free = evaluation.evaluate(one_motor, cfg, episodes=8, seed=1)
    # without parking the same flight overflows: the case tests what parking is for
    assert any(issubclass(w.category, RuntimeWarning) for w in caught)
    assert json.dumps(parked, sort_keys=True) == json.dumps(free, sort_keys=True)


def test_an_evaluation_in_which_every_episode_crashes_is_standard_json():
    for task in ("hover", "circle"):
        r = evaluation.evaluate(one_motor, make_config(task), episodes=4, seed=1)
        assert r["crash_rate"] == 1.0 and r["success_rate"] == 0.0
        json.dumps(r, allow_nan=False)  # no NaN: RFC 8259 has none, so other readers refuse the file
        over_survivors = [k for k in r if k.endswith(("_last_window_m", "_distance_m", "_rad_s", "_deg"))]
        assert over_survivors and all(r[k] is None for k in over_survivors)
        if task == "circle":
            assert r["radial_rms_m"] is None and r["speed_error_mps"] is None
