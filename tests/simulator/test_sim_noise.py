"""The simulator's sensor noise is `core.sensor_noise`, the training environments' model: its IMU in
HIL_SENSOR (white noise, turn-on bias) and, with `estimator_noise`, a state estimate in ODOMETRY
that the node flies on while HIL_STATE_QUATERNION stays the exact ground truth. Same seed, same
noise; noise off, no ODOMETRY and an exact gyro."""

import numpy as np
import pytest
from test_sim import LEVEL, by_type, config, connect, finish, on_the_wire, read_step, send, serving

from quadpilot.core.sensor_noise import SensorNoiseState, get_sensor_noise
from quadpilot.link import wire
from quadpilot.simulator import build_sim_parser, config_from_args

STEPS = 30


def fly(cfg, steps=STEPS):
    """Hover commands for `steps` steps; the messages of each step by type."""
    hover = on_the_wire(cfg.vehicle_params.hover_command)
    out = []
    with serving(cfg) as (_, port, result):
        c = connect(port)
        for _ in range(steps):
            out.append(by_type(read_step(c)))
            send(c, [hover] * 4)
        c.close()
        finish(result)
    return out


def test_estimator_noise_sends_odometry_before_the_sensor_and_keeps_the_truth_exact():
    cfg = config(initial_state=LEVEL, estimator_noise=True, seed=3)
    steps = fly(cfg)
    err = []
    for m in steps:
        assert list(m)[-1] == "HIL_SENSOR" and "ODOMETRY" in m
        odo, truth = m["ODOMETRY"], m["HIL_STATE_QUATERNION"]
        assert odo.time_usec == truth.time_usec
        est = wire.state_from_odometry(odo)
        true = wire.state_from_hil_state_quaternion(truth, cfg.home)
        err.append(est[0:3] - true[0:3])
        np.testing.assert_array_equal(wire.gyro_from_hil_sensor(m["HIL_SENSOR"]), true[9:12])  # IMU exact
        assert np.isfinite(odo.pose_covariance[0]) and odo.estimator_type == wire.ODOMETRY_ESTIMATOR
    err = np.array(err)
    assert 0.001 < np.abs(err).max() < 0.1  # cm-level, and really there
    # the same seed reproduces the estimate; the stream is the core model's
    again = fly(cfg)
    assert [m["ODOMETRY"].x for m in again] == [m["ODOMETRY"].x for m in steps]


def test_imu_noise_is_the_core_model_with_a_turn_on_bias():
    cfg = config(initial_state=LEVEL, imu_noise=True, seed=1)
    gyro = np.array([wire.gyro_from_hil_sensor(m["HIL_SENSOR"]) for m in fly(cfg, 60)])
    assert all("ODOMETRY" not in m for m in fly(cfg, 2))
    spec = get_sensor_noise("seed")
    # per axis: a constant offset (the turn-on bias) plus white noise
    white = np.std(gyro, axis=0).mean()
    assert white == pytest.approx(spec.imu.gyro_noise_density / np.sqrt(cfg.dt), rel=0.3)
    assert np.abs(gyro.mean(axis=0)).max() > 3 * white / np.sqrt(60)  # a bias, not zero-mean noise
    assert np.abs(gyro.mean(axis=0)).max() < 5 * spec.imu.gyro_turn_on_bias


def test_noise_flags_reach_the_configuration():
    args = build_sim_parser().parse_args(["--imu-noise", "--estimator-noise", "--motor-tau", "0.03"])
    cfg = config_from_args(args)
    assert cfg.sensor_noise == get_sensor_noise("seed")
    assert cfg.vehicle_params.motor_tau == 0.03
    only_imu = config(imu_noise=True).sensor_noise
    assert only_imu.estimator is None and only_imu.imu is not None
    assert config().sensor_noise is None
    state = SensorNoiseState(cfg.sensor_noise, 1, cfg.dt, np.random.default_rng(0))
    state.reset()
    assert state.gyro_noise_std == pytest.approx(cfg.gyro_noise_std)
