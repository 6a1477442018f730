"""core.mission: one task and success definition for training evaluation and SITL."""

import math

import numpy as np
import pytest

from quadpilot.core import mission
from quadpilot.train.envs import EnvConfig, QuadBatch, make_config


def test_the_environments_use_the_core_definitions():
    for task in mission.TASKS:
        cfg = make_config(task)
        assert cfg.home == mission.HOME[task]
        assert cfg.init_pos_radius == mission.START_RADIUS[task]
        assert cfg.success_tolerance == mission.SUCCESS_TOLERANCE_M
        assert cfg.success_window == mission.SUCCESS_WINDOW_S


def test_plan_episode_is_deterministic_and_matches_the_environment_task():
    a, b = mission.plan_episode("waypoint", 3, 7), mission.plan_episode("waypoint", 3, 7)
    assert a == b and a != mission.plan_episode("waypoint", 3, 8)
    assert np.linalg.norm(np.subtract(a.target, mission.HOME["waypoint"])) <= mission.WAYPOINT_RADIUS
    c = mission.plan_episode("circle", 0, 0)
    assert c.start_centre == pytest.approx(tuple(c.target_at(0)[0]))
    with pytest.raises(ValueError, match="unknown task"):
        mission.plan_episode("loop", 0, 0)


def test_the_circle_target_moves_as_the_training_environment_moves_it():
    cfg = make_config("circle", dtype="float64")
    batch = QuadBatch(cfg, 1)
    batch.reset(np.ones(1, bool), np.random.default_rng(0))
    m = mission.Mission("circle", cfg.home, cfg.home, 0.0, cfg.home, phase=float(batch.phase[0]), dt=cfg.dt)
    for k in range(1, 50):
        batch.step(np.zeros((1, 4)))
        pos, vel = m.target_at(k)
        assert pos == pytest.approx(batch.target[0], abs=1e-9) and vel == pytest.approx(batch.target_vel[0], abs=1e-9)


def test_judge_hover_window_and_crash():
    dt, n = 0.01, 500
    states = np.zeros((n, 12))
    states[:, 2] = 2.0
    states[:, 0] = np.exp(-np.arange(n) * dt)  # 1 m decaying: 5 to 1.8 cm over the last 2 s
    ok = mission.judge("hover", states, (0, 0, 2), dt)
    assert ok["success"] and ok["mean_error_last_window_m"] == pytest.approx(np.mean(states[-200:, 0]))
    states[-1, 6] = math.radians(70)  # tilted past 60° once: a crash
    assert not mission.judge("hover", states, (0, 0, 2), dt)["success"]
    assert not mission.judge("hover", states[:100], (0, 0, 2), dt)["success"]  # shorter than the window


def test_judge_circle_uses_the_second_lap():
    m = mission.plan_episode("circle", 0, 0)
    n = round(mission.default_duration_s("circle") / m.dt)
    targets = np.array([m.target_at(k)[0] for k in range(n)])
    vels = np.array([m.target_at(k)[1] for k in range(n)])
    states = np.zeros((n, 12))
    states[:, 0:3], states[:, 3:6] = targets, vels
    states[: n // 2, 0:3] += 0.3  # a poor first lap does not count
    out = mission.judge("circle", states, targets, m.dt)
    assert out["success"] and out["radial_rms_m"] < 1e-9 and out["speed_error_mps"] < 1e-9
    states[n // 2 :, 0] *= 1.1  # 10 % off the radius on the judged lap
    assert not mission.judge("circle", states, targets, m.dt)["success"]


def test_env_config_default_is_the_hover_mission():
    assert EnvConfig().home == mission.HOME["hover"]
