"""The node's scalar observation (`runtime.observation_one.observe`) is `core.observation.build_observation`
on a batch of one, bit for bit: random states (level to tumbling, yaw across and beyond ±π), targets,
target velocities (the track layout) and headings (the version-2 layouts), signed zeros, values from
tiny to huge, and non-finite inputs (which it hands to `build_observation` itself)."""

import itertools
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from quadpilot.core.observation import build_observation
from quadpilot.runtime import observation_one
from quadpilot.runtime.observation_one import observe

FINITE = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
ANGLE = st.one_of(st.floats(-4 * math.pi, 4 * math.pi), st.sampled_from([0.0, -0.0, math.pi, -math.pi, math.pi / 2]))
ANY = st.floats(allow_nan=True, allow_infinity=True, width=64)


def _reference(state, target, target_vel, heading) -> np.ndarray:
    tv = None if target_vel is None else np.array(target_vel)
    return build_observation(np.array([state]), np.array(target), tv, heading=heading)[0]


def _same_bits(state, target, target_vel, heading) -> None:
    with np.errstate(all="ignore"):  # NumPy's warnings for non-finite angles (the node's own, as before)
        got = observe(list(state), list(target), None if target_vel is None else list(target_vel), heading)
        want = _reference(state, target, target_vel, heading)
    assert got.dtype == want.dtype == np.float32 and got.shape == want.shape
    finite = np.isfinite(want)
    # bit for bit; a NaN (a non-finite input) only as a NaN, its sign and payload being no observation
    assert got.view(np.uint32)[finite].tolist() == want.view(np.uint32)[finite].tolist()
    assert np.array_equal(np.isnan(got), np.isnan(want)) and np.array_equal(got[~finite], want[~finite], equal_nan=True)


STATE = st.tuples(FINITE, FINITE, FINITE, FINITE, FINITE, FINITE, ANGLE, ANGLE, ANGLE, FINITE, FINITE, FINITE)
VEC = st.tuples(FINITE, FINITE, FINITE)


@settings(derandomize=True, database=None, deadline=None, max_examples=400)
@given(state=STATE, target=VEC, target_vel=st.none() | VEC, heading=st.none() | ANGLE)
def test_scalar_observation_is_build_observation_bit_for_bit(state, target, target_vel, heading):
    _same_bits(state, target, target_vel, heading)


@settings(derandomize=True, database=None, deadline=None, max_examples=200)
@given(state=st.tuples(*[ANY] * 12), target=st.tuples(ANY, ANY, ANY), heading=st.none() | ANY)
def test_non_finite_and_extreme_inputs_give_build_observations_values(state, target, heading):
    _same_bits(state, target, None, heading)


def test_hover_states_from_a_seeded_generator():
    """Many ordinary flight states (the node's everyday case), both layouts, with and without a heading."""
    rng = np.random.default_rng(7)
    for k in range(2000):
        s = np.concatenate(
            [rng.normal(0, 3, 3), rng.normal(0, 1, 3), rng.uniform(-np.pi, np.pi, 3), rng.normal(0, 2, 3)]
        )
        target = rng.normal(0, 3, 3)
        tv = rng.normal(0, 2, 3) if k % 2 else None
        heading = float(rng.uniform(-np.pi, np.pi)) if k % 3 else None
        _same_bits(s.tolist(), target.tolist(), None if tv is None else tv.tolist(), heading)


def test_without_agreeing_trigonometry_it_is_build_observation(monkeypatch):
    """Where math's sine is not NumPy's, the batched function itself computes."""
    monkeypatch.setattr(observation_one, "TRIG_AGREES", False)
    monkeypatch.setattr(observation_one.math, "sin", lambda v: 2.0)  # any use of it would show
    s = [0.1, -0.2, 2.0, 0.3, 0.1, -0.5, 0.2, -0.1, 1.0, 0.5, -0.3, 0.2]
    got = observe(s, [0.0, 0.0, 2.0], None, 0.4)
    assert got.tobytes() == _reference(s, [0.0, 0.0, 2.0], None, 0.4).tobytes()


def test_signed_zeros_come_out_as_build_observation_gives_them():
    """Every sign of zero in the position, velocity, target and angles (the einsum's zero start turns
    a sum of negative zeros into +0; a heading of ±0 keeps the signs of its products)."""
    for signs in itertools.product((0.0, -0.0), repeat=9):
        x, y, z, vx, vy, vz, tx, ty, tz = signs
        for angle in (0.0, -0.0):
            s = [x, y, z, vx, vy, vz, angle, angle, angle, -0.0, 0.0, -0.0]
            for heading in (None, 0.0, -0.0):
                _same_bits(s, [tx, ty, tz], None if heading is None else [vx, vy, vz], heading)
