"""The sensor noise model (`core.sensor_noise`) measured like a sensor: white-noise standard
deviation σ = density/√dt, bias random walk growing as σ_b·√t, Gauss-Markov estimator errors with
their stationary std and correlation time; the same seed gives the same noise; and without noise
the environments observe exactly what they did before."""

import dataclasses
import math

import numpy as np
import pytest

from quadpilot.core.observation import build_observation
from quadpilot.core.sensor_noise import (
    ADIS16448,
    BMI088,
    EKF_CM,
    SENSOR_NOISE_PRESETS,
    SensorNoise,
    SensorNoiseState,
    gauss_markov_coefficients,
    get_sensor_noise,
    ou_coefficients,
)

DT = 0.01
N = 4000  # drones: per-axis statistics over 12 000 samples, a few % relative error


def noise(spec, n=N, seed=0):
    s = SensorNoiseState(spec, n, DT, np.random.default_rng(seed))
    s.reset()
    return s


def imu_only(imu, **changes):
    return SensorNoise("test", dataclasses.replace(imu, **changes), None)


def test_gyro_and_accel_white_noise_std_is_density_over_root_dt():
    # no bias: only the white part is left
    s = noise(
        imu_only(ADIS16448, gyro_turn_on_bias=0.0, accel_turn_on_bias=0.0, gyro_bias_walk=0.0, accel_bias_walk=0.0)
    )
    zero = np.zeros((N, 3))
    g, a = s.gyro(zero), s.accel(zero)
    assert np.std(g) == pytest.approx(ADIS16448.gyro_noise_density / math.sqrt(DT), rel=0.03)
    assert np.std(a) == pytest.approx(0.04, rel=0.03)  # 4e-3 m/s²/√Hz at 100 Hz
    assert s.gyro_noise_std == pytest.approx(3.39e-3, rel=1e-2)
    s.step()
    assert np.corrcoef(g[:, 0], s.gyro(zero)[:, 0])[0, 1] == pytest.approx(0.0, abs=0.05)  # white: uncorrelated


def test_turn_on_bias_has_its_std_and_stays_put_within_an_episode():
    s = noise(imu_only(ADIS16448))
    b0 = s.slow[:, 0:3].copy()
    assert np.std(b0) == pytest.approx(0.5 * math.pi / 180, rel=0.03)
    for _ in range(500):  # 5 s: the ADIS random walk moves it by ~1e-4 rad/s, 1 % of the turn-on bias
        s.step()
    assert np.std(s.slow[:, 0:3] - b0) < 0.02 * np.std(b0)


@pytest.mark.parametrize("tau", [None, 1e6])
def test_bias_random_walk_grows_as_root_t(tau):
    walk = 1e-3  # rad/s per √s, large so that the growth is measured well
    s = noise(imu_only(ADIS16448, gyro_turn_on_bias=0.0, gyro_bias_walk=walk, gyro_bias_tau=tau))
    stds = {}
    for k in range(1, 401):
        s.step()
        if k in (25, 100, 400):  # t = 0.25, 1, 4 s
            stds[k] = float(np.std(s.slow[:, 0:3]))
    for k, sd in stds.items():
        assert sd == pytest.approx(walk * math.sqrt(k * DT), rel=0.04), (k, sd)
    assert stds[400] / stds[100] == pytest.approx(2.0, rel=0.05)  # 4× the time, 2× the spread
    assert stds[100] / stds[25] == pytest.approx(2.0, rel=0.05)


def test_ou_discretisation_is_exact_and_tends_to_the_random_walk():
    phi, sigma = ou_coefficients(1.0, 2.0, 0.5)
    # stationary variance of x ← φx + σw is σ²/(1 − φ²) = diffusion²·τ/2
    assert sigma**2 / (1 - phi**2) == pytest.approx(1.0 * 2.0 / 2)
    assert ou_coefficients(3.0, 1e12, DT) == pytest.approx(ou_coefficients(3.0, None, DT))
    phi, sigma = gauss_markov_coefficients(0.02, 1.5, DT)
    assert sigma**2 / (1 - phi**2) == pytest.approx(0.02**2)


def test_estimator_errors_are_stationary_with_their_std_and_correlation_time():
    spec = SensorNoise("test", None, EKF_CM)
    s = noise(spec)
    truth = np.zeros((N, 12))
    first = s.estimate(truth)
    e0 = s.slow[:, 6:9].copy()  # the slowly varying position error
    assert np.std(e0) == pytest.approx(EKF_CM.pos_drift, rel=0.03)
    lag = round(EKF_CM.pos_tau / DT)
    for _ in range(lag):
        s.step()
    e1 = s.slow[:, 6:9]
    assert np.std(e1) == pytest.approx(EKF_CM.pos_drift, rel=0.03)  # stationary
    assert np.corrcoef(e0.ravel(), e1.ravel())[0, 1] == pytest.approx(math.exp(-1), abs=0.03)  # e^(−lag/τ)
    pos_err = first[:, 0:3]  # drift and white together
    assert np.std(pos_err) == pytest.approx(math.hypot(EKF_CM.pos_drift, EKF_CM.pos_white), rel=0.03)
    assert np.std(first[:, 6:8]) == pytest.approx(EKF_CM.tilt_drift, rel=0.03)
    assert np.std(first[:, 8]) == pytest.approx(EKF_CM.yaw_drift, rel=0.05)
    np.testing.assert_array_equal(first[:, 9:12], 0.0)  # no IMU model: exact rates


def test_estimate_leaves_the_truth_alone_and_takes_rates_from_the_gyro():
    s = noise(SENSOR_NOISE_PRESETS["seed"], n=8)
    truth = np.random.default_rng(1).normal(size=(8, 12))
    kept = truth.copy()
    est = s.estimate(truth)
    np.testing.assert_array_equal(truth, kept)
    np.testing.assert_array_equal(est[:, 9:12], s.gyro(truth[:, 9:12]))
    assert not np.array_equal(est[:, 0:9], truth[:, 0:9])


def test_same_seed_same_noise_other_seed_other_noise():
    def run(seed):
        s = noise(SENSOR_NOISE_PRESETS["crazyflie"], n=16, seed=seed)
        out = []
        for _ in range(50):
            s.step()
            out.append(s.estimate(np.zeros((16, 12))))
        return np.stack(out)

    np.testing.assert_array_equal(run(3), run(3))
    assert not np.array_equal(run(3), run(4))


def test_reset_restarts_only_the_selected_drones():
    s = noise(SENSOR_NOISE_PRESETS["seed"], n=6)
    for _ in range(10):
        s.step()
    before = s.slow.copy()
    s.reset(np.array([1, 4]))
    changed = np.any(s.slow != before, axis=1)
    assert changed.tolist() == [False, True, False, False, True, False]


def test_state_dict_round_trip_continues_identically():
    a = noise(SENSOR_NOISE_PRESETS["seed"], n=5)
    a.step()
    b = SensorNoiseState(SENSOR_NOISE_PRESETS["seed"], 5, DT, np.random.default_rng(99))
    b.load_state_dict(a.state_dict())
    a.step()
    b.step()
    np.testing.assert_array_equal(a.estimate(np.zeros((5, 12))), b.estimate(np.zeros((5, 12))))


def test_presets_have_sources_and_units_that_add_up():
    assert get_sensor_noise("seed").imu is ADIS16448 and get_sensor_noise("crazyflie").imu is BMI088
    assert ADIS16448.gyro_noise_density == pytest.approx(3.39e-4, rel=1e-2)  # PX4 Gazebo plugin default
    assert BMI088.gyro_noise_density == pytest.approx(0.014 * math.pi / 180)
    assert SensorNoise.from_json(SENSOR_NOISE_PRESETS["seed"].to_json()) == SENSOR_NOISE_PRESETS["seed"]
    with pytest.raises(ValueError, match="known presets"):
        get_sensor_noise("mpu6000")
    double = get_sensor_noise("seed").scaled(2.0)
    assert double.estimator.pos_drift == 2 * EKF_CM.pos_drift and double.estimator.pos_tau == EKF_CM.pos_tau
    assert double.imu.gyro_turn_on_bias == 2 * ADIS16448.gyro_turn_on_bias and double.imu.gyro_bias_tau == 1e3


# --- in the training environment -------------------------------------------------------------


def test_noise_off_the_environment_observes_the_exact_state():
    from quadpilot.train.envs import QuadVectorEnv, make_config

    env = QuadVectorEnv(16, config=make_config("hover"))
    obs, _ = env.reset(seed=5)
    assert env.batch.noise is None
    np.testing.assert_array_equal(obs, build_observation(env.batch.state, env.batch.target, heading=env.batch.heading))
    rng = np.random.default_rng(0)
    for _ in range(20):
        obs, *_ = env.step(rng.uniform(-0.2, 0.2, (16, 4)).astype(np.float32))
        np.testing.assert_array_equal(
            obs, build_observation(env.batch.state, env.batch.target, heading=env.batch.heading)
        )


def test_noise_on_observes_the_estimate_and_judges_the_truth():
    from quadpilot.train.envs import QuadBatch, make_config

    cfg = make_config("hover", sensor_noise="seed")
    quiet = dataclasses.replace(cfg, sensor_noise=None)
    noisy, exact = QuadBatch(cfg, 64), QuadBatch(quiet, 64)
    noisy.reset(np.ones(64, bool), np.random.default_rng(7))
    exact.reset(np.ones(64, bool), np.random.default_rng(7))
    np.testing.assert_array_equal(noisy.state, exact.state)  # the start draws come first: same starts
    a = np.zeros((64, 4), np.float32)
    _, r1, t1, _, e1 = noisy.step(a)
    _, r2, t2, _, e2 = exact.step(a)
    np.testing.assert_array_equal(noisy.state, exact.state)  # noise never touches the plant
    np.testing.assert_array_equal(r1, r2)
    np.testing.assert_array_equal(t1, t2)
    np.testing.assert_array_equal(e1, e2)
    est = build_observation(noisy.sensed(), noisy.target, heading=noisy.obs_heading)
    np.testing.assert_array_equal(noisy.obs, est)
    d = noisy.obs - exact.obs
    assert 0.002 < np.std(d[:, 0:3]) < 0.05  # cm-level position error
    assert np.abs(d[:, 15:18]).max() < 0.1  # gyro: bias ≲ 0.03 rad/s plus white noise


def test_noisy_environment_same_seed_same_observations():
    from quadpilot.train.envs import QuadVectorEnv, make_config

    def run():
        env = QuadVectorEnv(8, config=make_config("hover", sensor_noise="crazyflie", vehicle="crazyflie"))
        out = [env.reset(seed=11)[0]]
        for _ in range(30):
            out.append(env.step(np.zeros((8, 4), np.float32))[0])
        return np.stack(out)

    np.testing.assert_array_equal(run(), run())
