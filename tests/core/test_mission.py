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


# --- the yaw rule: hover means holding still, yaw included ------------------------------------

DT, N = 0.01, 500  # a 5 s hover, judged on its last 2 s
T = DT * np.arange(N)


def held(yaw, r=None) -> np.ndarray:
    """A hover exactly at (0, 0, 2) with the yaw angle `yaw` (N,) and body yaw rate `r` (N,) (its
    derivative if None): hand-made states, position perfect, so only the yaw rule can fail."""
    s = np.zeros((N, 12))
    s[:, 2] = 2.0
    s[:, 8] = mission.wrap_angle(yaw)
    s[:, 11] = np.gradient(np.unwrap(s[:, 8]), DT) if r is None else r
    return s


def judged(states, **kw) -> dict:
    return mission.judge("hover", states, (0, 0, 2), DT, **kw)


def test_holding_the_start_heading_succeeds():
    out = judged(held(np.full(N, 0.7)))
    assert out["success"] and out["mean_abs_yaw_rate_last_window_rad_s"] == 0.0
    assert out["mean_heading_error_last_window_deg"] == pytest.approx(0.0, abs=1e-12)


def test_spinning_at_0_3_rad_s_fails():
    out = judged(held(0.3 * T))
    assert not out["success"] and out["mean_abs_yaw_rate_last_window_rad_s"] == pytest.approx(0.3)


@pytest.mark.parametrize(("mean_rate", "success"), [(0.3, False), (0.21, False), (0.19, True), (0.1, True)])
def test_the_yaw_rate_bound_alone(mean_rate, success):
    """A fast yaw wobble about the start heading, ψ = A·sin(ωt) at 5 Hz (whole periods in the 2 s
    window), its amplitude A = mean_rate·π/(2ω) (mean |ψ̇| = 2Aω/π) under 1°: the heading holds
    (mean error under 1°), only the yaw rate bound can decide."""
    w = 10 * math.pi
    amp = mean_rate * math.pi / (2 * w)
    out = judged(held(amp * np.sin(w * T), amp * w * np.cos(w * T)))
    assert out["mean_abs_yaw_rate_last_window_rad_s"] == pytest.approx(mean_rate, rel=0.01)
    assert out["mean_heading_error_last_window_deg"] < 1.0
    assert (out["mean_abs_yaw_rate_last_window_rad_s"] <= mission.YAW_RATE_TOLERANCE_RAD_S) == success
    assert out["success"] == success


@pytest.mark.parametrize(("offset_deg", "success"), [(10.5, False), (-10.5, False), (9.0, True), (-9.0, True)])
def test_settling_off_the_start_heading(offset_deg, success):
    """Start at heading 1.2 rad, turn by `offset_deg` within the first second, hold it."""
    yaw = 1.2 + math.radians(offset_deg) * np.clip(T, 0.0, 1.0)
    out = judged(held(yaw))
    assert out["mean_heading_error_last_window_deg"] == pytest.approx(abs(offset_deg), rel=1e-9)
    assert out["success"] == success


@pytest.mark.parametrize(
    ("start", "offset_deg", "success"),
    [(math.pi - 0.05, 6.0, True), (-math.pi + 0.05, -6.0, True), (math.pi - 0.05, 10.5, False)],
)
def test_the_heading_error_wraps_at_plus_minus_pi(start, offset_deg, success):
    """A heading held across the ±180° seam is a small error, not a 354° one."""
    yaw = start + math.radians(offset_deg) * np.clip(T, 0.0, 1.0)
    states = held(yaw)
    assert np.sign(states[0, 8]) != np.sign(states[-1, 8])  # it did cross the seam
    out = judged(states)
    assert out["mean_heading_error_last_window_deg"] == pytest.approx(abs(offset_deg), rel=1e-9)
    assert out["success"] == success


def test_a_commanded_heading_replaces_the_start_heading():
    states = held(np.full(N, 2.0))
    assert judged(states)["success"]
    assert not judged(states, heading=2.0 + math.radians(12))["success"]
    assert judged(states, heading=2.0 + 2 * math.pi + math.radians(5))["success"]  # any turn count


def test_the_circle_is_judged_on_its_heading_too():
    m = mission.plan_episode("circle", 0, 0)
    n = round(mission.default_duration_s("circle") / m.dt)
    targets = np.array([m.target_at(k)[0] for k in range(n)])
    states = np.zeros((n, 12))
    states[:, 0:3], states[:, 3:6] = targets, np.array([m.target_at(k)[1] for k in range(n)])
    assert mission.judge("circle", states, targets, m.dt)["success"]
    states[:, 11] = 1.0  # flying the circle nose-in, turning at 1 rad/s
    states[:, 8] = mission.wrap_angle(np.arange(n) * m.dt)
    assert not mission.judge("circle", states, targets, m.dt)["success"]


def test_window_success_is_the_rule_the_environment_applies():
    """QuadBatch.success is `window_success` of its window sums: a batch whose accumulated means
    are those of the hand-made trajectories gets the judge's verdicts."""
    cases = [held(np.full(N, 0.7)), held(0.3 * T), held(1.2 + math.radians(10.5) * np.clip(T, 0, 1))]
    batch = QuadBatch(make_config("hover", dtype="float64"), len(cases))
    k = batch.cfg.success_steps
    for i, s in enumerate(cases):
        rate, head = mission.yaw_errors(s[-k:], s[0, 8])
        batch.err_sum[i], batch.yaw_rate_sum[i], batch.heading_err_sum[i] = 0.0, rate.sum(), head.sum()
    ended = np.ones(len(cases), bool)
    got = batch.success(~ended, ended)
    assert got.tolist() == [judged(s)["success"] for s in cases] == [True, False, False]
