"""The environments' step allocates no array, and the batch's state reads and writes as an array.

At N = 4096 (the benchmark's batch) a float32 row is 16 KiB and a bool row 4 KiB, so a step that
allocated any array of one value per drone would raise tracemalloc's peak (NumPy reports its data
allocations to tracemalloc, its iterator buffers included) by at least 4 KiB. What a step may
allocate: a few Python objects (views, tuples), and what it returns: `QuadVectorEnv.step` hands
out new arrays (a learner keeps them), and the drones that reset draw their new episodes.

The state (N, 12) and rotor speeds (N, M) live as rows inside the batch (`QuadBatch.state` and
`rotor` are properties): what is written through them before a step is what the step starts from,
and an array taken before a step keeps that step's inputs, as when the step made new arrays.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from quadpilot.core import dynamics
from quadpilot.core.observation import build_observation
from quadpilot.core.state import POS, Z
from quadpilot.train.envs import QuadBatch, QuadVectorEnv, make_config

N = 4096
SMALL = 4096  # bytes: less than any array of one float32 per drone, and than two bool rows
CONFIGS = {
    "hover": {"task": "hover"},
    "circle": {"task": "circle"},
    "waypoint_v1": {"task": "waypoint", "obs_version": 1},
    "float64": {"task": "hover", "dtype": "float64"},
    "motor_lag_drag": {"task": "hover", "vehicle": "px4_sih_quadx"},
}


def peak_bytes(fn, *args):
    """(how far tracemalloc's traced memory rose above where it was while fn(*args) ran, its result)."""
    start = tracemalloc.get_traced_memory()[0]
    tracemalloc.reset_peak()
    out = fn(*args)
    return tracemalloc.get_traced_memory()[1] - start, out


@pytest.fixture
def traced():
    tracemalloc.start()
    yield
    tracemalloc.stop()


def calm(n: int, seed: int = 0) -> list[np.ndarray]:
    """Actions near hover: no drone crashes in a few steps."""
    return list((0.02 * np.random.default_rng(seed).standard_normal((8, n, 4))).astype(np.float32))


def hovering(kw: dict) -> QuadVectorEnv:
    env = QuadVectorEnv(N, init_pos_radius=0.2, init_vel=0.0, init_tilt_deg=2.0, **kw)
    env.reset(seed=0)
    return env


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_a_batch_step_allocates_no_array(traced, name):
    env = hovering(CONFIGS[name])
    batch, actions = env.batch, calm(N)
    for a in actions:  # warm-up: the buffers' views are made at the first steps
        batch.step(a)
    peaks = [peak_bytes(batch.step, a)[0] for a in actions]
    assert max(peaks) < SMALL, f"QuadBatch.step allocated {max(peaks)} bytes at its peak"


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_a_vector_step_without_resets_allocates_only_the_arrays_it_returns(traced, name):
    env = hovering(CONFIGS[name])
    actions = calm(N, seed=1)
    for a in actions:
        env.step(a)
    for a in actions:
        peak, (obs, reward, terminated, truncated, infos) = peak_bytes(env.step, a)
        assert not infos, "an episode ended: this test needs a step without resets"
        returned = obs.nbytes + reward.nbytes + terminated.nbytes + truncated.nbytes
        assert peak - returned < SMALL, f"QuadVectorEnv.step allocated {peak - returned} bytes beyond its results"
        # inside the step itself: nothing
        peak = peak_bytes(env.batch.step_autoreset, a, env.rng)[0]
        assert peak < SMALL, f"QuadBatch.step_autoreset allocated {peak} bytes"


def test_a_vector_step_with_resets_allocates_only_its_results_and_does_not_grow(traced):
    """Three drones crash every step (put under the ground through `state`): their reset draws and
    last observations are all the step allocates beyond what it returns, and nothing stays."""
    env = hovering(CONFIGS["hover"])
    actions = calm(N, seed=2)

    def step(a):
        env.batch.state[:3, Z] = -1.0
        return env.step(a)

    for a in actions:
        step(a)
    start = tracemalloc.get_traced_memory()[0]
    for a in actions * 3:
        peak, (obs, reward, terminated, truncated, infos) = peak_bytes(step, a)
        assert terminated.sum() == 3
        ep = infos["episode"]
        returned = sum(x.nbytes for x in (obs, reward, terminated, truncated, infos["final_obs"], infos["_final_obs"]))
        returned += sum(x.nbytes for x in ep.values())
        assert peak - returned < 2 * SMALL, f"QuadVectorEnv.step allocated {peak - returned} bytes beyond its results"
        del obs, reward, terminated, truncated, infos, ep
    assert tracemalloc.get_traced_memory()[0] - start < 1024, "memory grew from step to step"


# --- the state and rotor speeds read and write as arrays ------------------------------------


def test_what_is_written_through_state_and_rotor_is_what_the_step_starts_from():
    cfg = make_config("hover")
    a = QuadBatch(cfg, 64)
    b = QuadBatch(cfg, 64)
    for batch in (a, b):
        batch.reset(np.ones(64, bool), np.random.default_rng(3))
        batch.step(np.zeros((64, 4), np.float32))  # the observation's trigonometry is now the state's
    new_state = a.state + np.float32(0.05)
    new_rotor = np.full((64, 4), 0.3, np.float32)
    a.state[:] = new_state  # in place, through the array handed out
    a.rotor[:] = new_rotor
    b.state = new_state.copy()  # or by assignment
    b.rotor = new_rotor.copy()
    action = np.random.default_rng(4).uniform(-1, 1, (64, 4)).astype(np.float32)
    want_state, want_rotor = dynamics.step(
        new_state, new_rotor, dynamics.action_to_command(action, a.u_hover), a.params, cfg.dt
    )
    want_obs = build_observation(want_state, a.target, heading=a.heading)
    for batch in (a, b):
        obs = batch.step(action)[0]
        assert np.array_equal(batch.state, want_state) and np.array_equal(batch.rotor, want_rotor)
        assert obs.tobytes() == want_obs.tobytes()


def test_an_array_taken_before_a_step_keeps_that_steps_inputs():
    batch = QuadBatch(make_config("hover"), 8)
    batch.reset(np.ones(8, bool), np.random.default_rng(5))
    before = batch.state
    kept = before.copy()
    batch.step(np.ones((8, 4), np.float32))
    after = batch.state
    assert not np.array_equal(after, kept) and np.array_equal(before, kept)
    assert after.flags.c_contiguous and after.shape == (8, 12)
    # a reset writes into the array it has, as it did when the state was a plain array
    now = batch.state
    batch.reset(np.arange(8) < 2, np.random.default_rng(6))
    assert np.array_equal(now[2:], batch.state[2:]) and not np.array_equal(now[:2, POS], kept[:2, POS])
    assert now is batch.state
