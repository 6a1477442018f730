"""The rotor start state in the training environments.

`EnvConfig.init_rotor` starts the rotors at hover (the default, unchanged), at rest, or at a random
speed between the two.
"""

import math

import numpy as np
import pytest

from quadpilot.train.envs import QuadBatch, make_config


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
