"""The in-place, allocation-free step computes bit for bit what the allocating functions compute.

`dynamics.Stepper` (and `dynamics.step`, which runs it) against the allocating form of the plant step
(tests/core/allocating_dynamics.py), `observation.ObservationBuilder` against
`build_observation`, the row helpers of `frames` and `reward` against `euler_to_rotmat`,
`world_to_body` and np.einsum, `reward.StepTerms` against `crashed`, `mission.yaw_errors`,
`hover_reward` and `circle_reward`, and `SensorNoiseState.estimate_rows` against `estimate`. Unlike
tests/train/test_env_bit_identity.py (digests pinned on one machine) these compare the two codes
on the machine the test runs on, so they hold on any CPU and NumPy. Bits are compared as bytes, so
a −0 for a +0 or another NaN payload is a failure; the states include zeros, signed zeros,
NaN and huge rates so that those paths are compared too.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from allocating_dynamics import allocating_step

from quadpilot.core import dynamics
from quadpilot.core.frames import euler_to_rotmat, euler_to_rotmat_rows, world_to_body, world_to_body_rows
from quadpilot.core.mission import yaw_errors
from quadpilot.core.observation import ObservationBuilder, build_observation
from quadpilot.core.params import ParamBatch, Rotor
from quadpilot.core.reward import (
    RewardConfig,
    StepTerms,
    circle_reward,
    crashed,
    einsum_dot3_rows,
    hover_reward,
)
from quadpilot.core.sensor_noise import SensorNoiseState, get_sensor_noise
from quadpilot.core.state import ATT, PITCH, POS, RATES, ROLL, STATE_DIM, YAW
from quadpilot.core.vehicle_file import CRAZYFLIE, PX4_SIH_QUADX, SEED_VEHICLE

# the awkward states overflow and make NaN on purpose
pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")

DTYPES = (np.float32, np.float64)
VEHICLES = {
    "seed": SEED_VEHICLE,
    "crazyflie": CRAZYFLIE,
    "px4_sih_lag_drag": PX4_SIH_QUADX,
    "idle_speed": dataclasses.replace(SEED_VEHICLE, omega_min=150.0, motor_tau=0.02),
    # RotorPy's Hummingbird parasitic drag per body axis, with PX4 SIH's linear drag on top
    "quadratic_drag": dataclasses.replace(PX4_SIH_QUADX, c_dx=0.005, c_dy=0.005, c_dz=0.01),
    # and RotorPy's rotor aerodynamics (its Hummingbird's k_d, k_z, k_h, with a flapping moment)
    "rotor_aero": dataclasses.replace(
        PX4_SIH_QUADX, c_dx=0.005, c_dy=0.005, c_dz=0.01, k_d=1.19e-4, k_z=2.32e-4, k_h=3.39e-3, k_flap=1e-5
    ),
    "asymmetric": dataclasses.replace(
        SEED_VEHICLE,
        arm=None,
        rotors=(
            Rotor(0.12, 0.10, "ccw"),
            Rotor(-0.10, -0.13, "ccw"),
            Rotor(0.11, -0.12, "cw"),
            Rotor(-0.12, 0.09, "cw"),
        ),
    ),
    # the first rotor's term of a row negative and not ±1 (τx's y = −0.11 against 0.13)
    "asymmetric_negative_first": dataclasses.replace(
        SEED_VEHICLE,
        arm=None,
        rotors=(
            Rotor(0.10, -0.11, "ccw"),
            Rotor(-0.12, 0.13, "ccw"),
            Rotor(0.12, 0.12, "cw"),
            Rotor(-0.09, -0.10, "cw"),
        ),
    ),
}


def same(a, b) -> bool:
    """The same dtype, shape and bytes."""
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and np.ascontiguousarray(a).tobytes() == b.tobytes()


def states(n: int, dtype, seed: int = 0) -> np.ndarray:
    """(n, 12) states around hover, with the awkward ones in the first rows: all zeros, −0.0, a NaN
    attitude, rates large enough to overflow float32 products, an exact ±π yaw."""
    rng = np.random.default_rng(seed)
    s = rng.normal(0.0, 1.0, (n, STATE_DIM))
    s[:, POS] += (0.0, 0.0, 2.0)
    s[:, ATT] *= (0.4, 0.4, 2.0)
    special = [np.zeros(STATE_DIM), np.full(STATE_DIM, -0.0), np.zeros(STATE_DIM), np.zeros(STATE_DIM)]
    special[2][ATT] = (np.nan, 0.1, -0.2)
    special[3][RATES] = (1e20, -3e19, 2e21)
    special[3][ATT.stop - 1] = -np.pi
    k = min(n, len(special))
    s[:k] = special[:k]
    return s.astype(dtype)


# --- dynamics --------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("vehicle", sorted(VEHICLES))
@pytest.mark.parametrize("substeps", [1, 3])
def test_stepper_and_step_give_the_bits_of_the_allocating_step(vehicle, dtype, substeps):
    n = 37  # not a multiple of a SIMD width: the loops' tails are compared too
    params = ParamBatch.from_preset(VEHICLES[vehicle], n, dtype=np.dtype(dtype))
    rng = np.random.default_rng(1)
    s0 = states(n, dtype)
    w0 = rng.random((n, 4)).astype(dtype)
    command = rng.uniform(-0.2, 1.2, (n, 4)).astype(dtype)
    stepper = dynamics.Stepper(n, 4, dtype)
    pushed = (rng.normal(0, 1, (n, 3)), rng.normal(0, 0.01, (n, 3)), rng.normal(0, 4, (n, 3)))
    for force, torque, wind in ((None, None, None), pushed):
        force = None if force is None else force.astype(dtype)
        torque = None if torque is None else torque.astype(dtype)
        for armed in (None, np.arange(n) % 3 != 1):
            args = (s0, w0, command, params, 0.01, substeps)
            kw = dict(force=force, torque=torque, armed=armed, wind=wind)
            want_s, want_w = allocating_step(*args, **kw)
            got_s, got_w = dynamics.step(*args, **kw)
            assert same(got_s, want_s) and same(got_w, want_w)
            s, w, u = np.ascontiguousarray(s0.T), np.ascontiguousarray(w0.T), np.ascontiguousarray(command.T)
            stepper.step(s, w, u, params, 0.01, substeps, **kw)
            assert same(s.T, want_s) and same(w.T, want_w)


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("substeps", [1, 3])
@pytest.mark.parametrize("vehicle", ["seed", "quadratic_drag", "rotor_aero"])
def test_stepper_with_the_observations_trigonometry_gives_the_bits_of_the_allocating_step(dtype, substeps, vehicle):
    """The sines, cosines and thrust axis the observation computed for the state are the ones the
    dynamics computes first (QuadBatch hands them over); the later substeps compute their own."""
    n = 41
    params = ParamBatch.from_preset(VEHICLES[vehicle], n, dtype=np.dtype(dtype))
    s0 = states(n, dtype, seed=2)
    w0 = np.full((n, 4), 0.5, dtype)
    command = np.random.default_rng(3).uniform(0, 1, (n, 4)).astype(dtype)
    want_s, want_w = allocating_step(s0, w0, command, params, 0.01, substeps)
    s, w, u = np.ascontiguousarray(s0.T), np.ascontiguousarray(w0.T), np.ascontiguousarray(command.T)
    ob = ObservationBuilder(n, dtype)
    ob.build(s, np.zeros((n, 3), dtype), np.empty((n, 18), np.float32))
    trig = (ob.last.sin, ob.last.cos, ob.last.rot[:, 2])
    dynamics.Stepper(n, 4, dtype).step(s, w, u, params, 0.01, substeps, trig=trig)
    assert same(s.T, want_s) and same(w.T, want_w)


# --- frames and sums of products -------------------------------------------------------------


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: np.dtype(d).name)
def test_row_rotations_and_sums_give_the_bits_of_euler_to_rotmat_world_to_body_and_einsum(dtype):
    n = 1001
    s = states(n, dtype, seed=4)
    rng = np.random.default_rng(5)
    v = rng.normal(0, 3, (n, 3)).astype(dtype)
    v[:3] = (-0.0, 0.0, -0.0)  # products of −0 where einsum adds them onto +0
    att = np.ascontiguousarray(s[:, ATT].T)
    rot = np.empty((3, 3, n), dtype)
    euler_to_rotmat_rows(np.sin(att), np.cos(att), rot, np.empty(n, dtype))
    want_rot = euler_to_rotmat(s[:, ROLL], s[:, PITCH], s[:, YAW])
    assert same(rot.transpose(2, 0, 1), want_rot)
    out, block, tmp = (np.empty((3, n), dtype) for _ in range(3))
    world_to_body_rows(rot, np.ascontiguousarray(v.T), out, block, tmp)
    assert same(out.T, world_to_body(want_rot, v))
    d = np.empty(n, dtype)
    einsum_dot3_rows(np.ascontiguousarray(v.T), d, block)
    assert same(d, np.einsum("ij,ij->i", v, v))
    einsum_dot3_rows(np.ascontiguousarray(s[:, RATES].T), d, block)
    assert same(d, np.einsum("ij,ij->i", s[:, RATES], s[:, RATES]))


# --- observation -----------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("heading", [False, True])
@pytest.mark.parametrize("track", [False, True])
def test_observation_builder_gives_the_bits_of_build_observation(dtype, heading, track):
    n = 53
    s = states(n, dtype, seed=6)
    rng = np.random.default_rng(7)
    target = rng.normal(0, 1, (n, 3)).astype(dtype)
    target_vel = rng.normal(0, 1, (n, 3)).astype(dtype) if track else None
    psi = rng.uniform(-np.pi, np.pi, n).astype(dtype) if heading else None
    want = build_observation(s, target, target_vel, heading=psi)
    ob = ObservationBuilder(n + 10, dtype)  # built for more states than it is given
    rows = np.ascontiguousarray(s.T)
    got = np.full_like(want, 7.0)
    ob.build(rows, target, got, target_vel, heading=psi)
    assert same(got, want)
    # the same in two parts of the output, after a build of another size
    ob.build(rows[:, :9], target[:9], np.empty((9, want.shape[1]), np.float32), None if not track else target_vel[:9])
    first, second = np.empty((20, want.shape[1]), np.float32), np.empty((n - 20, want.shape[1]), np.float32)
    ob.build(rows, target, (first, second), target_vel, heading=psi)
    assert same(np.concatenate([first, second]), want)
    assert same(ob.last.vec, (s[:, POS] - target).T)


# --- reward and termination ------------------------------------------------------------------


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("pay_heading", [False, True])
@pytest.mark.parametrize("task", ["hover", "circle"])
def test_step_terms_give_the_bits_of_crashed_yaw_errors_and_the_rewards(dtype, pay_heading, task):
    n = 67
    s = states(n, dtype, seed=8)
    s[10:20, POS] += (0.0, 0.0, -5.0)  # under the ground
    s[20:25, ATT.start] = 1.2  # beyond the tilt limit
    rng = np.random.default_rng(9)
    target = (s[:, POS] + rng.normal(0, 2, (n, 3))).astype(dtype)
    heading = rng.uniform(-np.pi, np.pi, n).astype(dtype)
    cfg = RewardConfig(tilt_weight=50.0)
    home = np.array([0.0, 0.5, 2.0], dtype)
    pos_err = s[:, POS] - target
    crash = crashed(s, pos_err, cfg)
    rate, head = yaw_errors(s, heading)
    paid = head if pay_heading else None
    if task == "circle":
        want = circle_reward(s, pos_err, crash, home, 1.0, 1.0, cfg, paid)
    else:
        want = hover_reward(s, pos_err, crash, cfg, paid)
    terms = StepTerms(n, dtype)
    terms.compute(
        np.ascontiguousarray(s.T), target, heading, cfg, pay_heading, (home, 1.0, 1.0) if task == "circle" else None
    )
    assert same(terms.crash, crash) and same(terms.rate, rate) and same(terms.head, head)
    assert same(terms.reward, want)
    assert same(terms.err, np.sqrt(np.einsum("ij,ij->i", pos_err, pos_err)))


# --- sensor noise ----------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: np.dtype(d).name)
def test_noise_steps_and_estimates_as_before(dtype):
    """`step` draws what `standard_normal((N, 27))` draws and updates as the allocating code did;
    `estimate_rows` gives the bits of `estimate`."""
    n = 29
    spec = get_sensor_noise("seed")
    a = SensorNoiseState(spec, n, 0.01, np.random.default_rng(3))
    a.reset()
    slow, white = a.slow.copy(), a.white.copy()
    rng = np.random.Generator(type(a.rng.bit_generator)())
    rng.bit_generator.state = a.rng.bit_generator.state
    for _ in range(3):
        a.step()
        z = rng.standard_normal((n, 27))  # the code before the in-place step, written out
        slow *= a._phi
        slow += a._kick * z[:, :15]
        white = a._white_std * z[:, 15:]
        assert same(a.slow, slow) and same(a.white, white)
    s = states(n, dtype, seed=10)
    rows = np.empty((STATE_DIM, n), dtype)
    a.estimate_rows(np.ascontiguousarray(s.T), rows)
    assert same(rows.T, a.estimate(s))
