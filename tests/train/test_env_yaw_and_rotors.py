"""The yaw rule and the rotor start state in the training environments.

The environments' success (`QuadBatch.success`, what training's episodes report) and `evaluate`'s
(eval.json) are the judge's (`core.mission.judge`, what SITL reports) on the same flight: a
classical controller flies a batch in closed loop, some drones holding their start heading, some
turned 30° away from it, some left free to spin in yaw, and every drone gets the same verdict and the
same window figures from all three. `EnvConfig.init_rotor` starts the rotors at hover (the default,
unchanged), at rest, or at a random speed between the two.
"""

import dataclasses
import math

import numpy as np
import pytest

from quadpilot.core import mission
from quadpilot.core.vehicle_file import SEED_VEHICLE
from quadpilot.runtime.fallback import FallbackController, FallbackGains
from quadpilot.train.envs import QuadBatch, make_config
from quadpilot.train.envs.evaluate import evaluate

# drone: (heading offset latched by the controller in deg, yaw control on)
DRONES = [(0.0, True), (0.0, True), (30.0, True), (-30.0, True), (0.0, False), (0.0, False)]
CFG = make_config(
    "hover", dtype="float64", init_rate=1.0, heading_offset_deg=0.0
)  # ±1 rad/s start rates: a free yaw keeps spinning


class Fallbacks:
    """One fallback controller per drone as a policy (observations → actions in [−1, 1], the
    inverse of `core.dynamics.action_to_command`); drone i holds its start heading turned by
    DRONES[i][0], or has no yaw control at all (its yaw gains zero)."""

    def __init__(self):
        free = FallbackGains.for_vehicle(SEED_VEHICLE)
        free = dataclasses.replace(free, att_p=(*free.att_p[:2], 0.0), rate_d=(*free.rate_d[:2], 0.0))
        self.ctrls = [FallbackController(SEED_VEHICLE, gains=None if yaw else free) for _, yaw in DRONES]
        self.u_hover = SEED_VEHICLE.hover_command

    def __call__(self, obs):
        out = []
        for ctrl, o, (offset, _) in zip(self.ctrls, obs, DRONES, strict=True):
            if ctrl._heading is None:  # first call: latch the start heading turned by the offset
                rot = np.asarray(o[6:15], np.float64).reshape(3, 3)
                psi = math.atan2(rot[1, 0], rot[0, 0]) + math.radians(offset)
                ctrl._heading = (math.cos(psi), math.sin(psi))
            out.append((ctrl.act(o).astype(np.float64) / self.u_hover) ** 2 - 1.0)
        return np.clip(np.array(out), -1.0, 1.0).astype(np.float32)


def fly(seed):
    """The flight evaluate(Fallbacks(), CFG, len(DRONES), seed) makes, stepped here so that every
    state is kept: (batch after the last step, states (T+1, N, 12), targets (N, 3))."""
    policy = Fallbacks()
    batch = QuadBatch(CFG, len(DRONES))
    batch.reset(np.ones(len(DRONES), bool), np.random.default_rng(seed))
    states = [batch.state.copy()]
    for _ in range(CFG.episode_steps):
        _, _, term, trunc, _ = batch.step(policy(batch.obs.copy()))
        states.append(batch.state.copy())
    assert not term.any() and trunc.all()
    return batch, np.array(states), batch.target.copy(), term, trunc


def test_the_environment_evaluate_and_the_judge_agree_on_each_drone():
    batch, states, targets, term, trunc = fly(seed=5)
    env_success = batch.success(term, trunc)
    verdicts = [
        mission.judge("hover", states[:, i], targets[i], CFG.dt, heading=float(batch.heading[i]))
        for i in range(len(DRONES))
    ]
    assert env_success.tolist() == [v["success"] for v in verdicts]
    k = CFG.success_steps
    for i, v in enumerate(verdicts):
        assert v["mean_abs_yaw_rate_last_window_rad_s"] == pytest.approx(batch.yaw_rate_sum[i] / k, rel=1e-9)
        assert math.radians(v["mean_heading_error_last_window_deg"]) == pytest.approx(
            batch.heading_err_sum[i] / k, rel=1e-9, abs=1e-12
        )
        assert v["mean_error_last_window_m"] == pytest.approx(batch.err_sum[i] / k, rel=1e-9)
        assert v["mean_error_last_window_m"] < 0.05  # every drone holds its position: only yaw decides
    # holding the start heading succeeds; settling 30° off, or spinning, does not
    assert [v["success"] for v in verdicts] == [True, True, False, False, False, False]
    assert min(v["mean_abs_yaw_rate_last_window_rad_s"] for v in verdicts[4:]) > mission.YAW_RATE_TOLERANCE_RAD_S
    assert all(v["mean_heading_error_last_window_deg"] == pytest.approx(30.0, abs=1.0) for v in verdicts[2:4])

    r = evaluate(Fallbacks(), CFG, episodes=len(DRONES), seed=5)
    assert r["success_rate"] == pytest.approx(2 / 6)
    rates = [v["mean_abs_yaw_rate_last_window_rad_s"] for v in verdicts]
    assert r["mean_abs_yaw_rate_last_window_rad_s"] == pytest.approx(np.mean(rates), rel=1e-9)
    assert r["max_mean_abs_yaw_rate_last_window_rad_s"] == pytest.approx(max(rates), rel=1e-9)


def test_init_rotor_starts_the_rotors_at_hover_at_rest_or_in_between():
    n = 64
    default = QuadBatch(make_config("hover"), n)
    default.reset(np.ones(n, bool), np.random.default_rng(0))
    hover = QuadBatch(make_config("hover", init_rotor="hover"), n)
    hover.reset(np.ones(n, bool), np.random.default_rng(0))
    assert np.all(default.rotor == default.u_hover)
    np.testing.assert_array_equal(default.obs, hover.obs)
    np.testing.assert_array_equal(default.state, hover.state)

    rest = QuadBatch(make_config("hover", init_rotor="rest"), n)
    rest.reset(np.ones(n, bool), np.random.default_rng(0))
    assert np.all(rest.rotor == 0.0)
    np.testing.assert_array_equal(rest.state, default.state)  # the same start states are drawn

    rnd = QuadBatch(make_config("hover", init_rotor="random"), n)
    rnd.reset(np.ones(n, bool), np.random.default_rng(0))
    assert np.all((rnd.rotor >= 0) & (rnd.rotor <= rnd.u_hover))
    assert np.all(rnd.rotor == rnd.rotor[:, :1])  # one speed per drone
    assert len(np.unique(rnd.rotor[:, 0])) == n

    with pytest.raises(ValueError, match="init_rotor must be one of"):
        make_config("hover", init_rotor="spinning")


def test_rotors_at_rest_with_the_sih_motor_lag_drop_the_vehicle_first():
    """The RotorPy test's start: rotors at rest, PX4 SIH's 50 ms motor lag. Holding the hover action
    from there, the vehicle sinks while the rotors spin up (a policy for it must learn that), and
    the rotors reach 95 % of hover speed after 3τ = 0.15 s."""
    cfg = make_config(
        "hover",
        vehicle="px4_sih_quadx",
        init_rotor="rest",
        dtype="float64",
        **{
            "init_pos_radius": 0.0,
            "init_vel": 0.0,
            "init_tilt_deg": 0.0,
        },
    )
    batch = QuadBatch(cfg, 1)
    batch.reset(np.ones(1, bool), np.random.default_rng(0))
    z0 = batch.state[0, 2]
    for _ in range(15):
        batch.step(np.zeros((1, 4), np.float32))
    assert batch.rotor[0] == pytest.approx(batch.u_hover * (1 - math.exp(-3.0)), rel=1e-9)
    assert batch.state[0, 5] < -0.5 and batch.state[0, 2] < z0
