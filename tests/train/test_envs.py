"""The Gymnasium environments: registration, API checks, seeding, terminated vs truncated, options,
and the vector env's same-step autoreset and its equivalence with single drones."""

import subprocess
import sys
import textwrap
import warnings

import gymnasium as gym
import numpy as np
import pytest

from quadpilot.core.dynamics import IDX
from quadpilot.core.frames import euler_to_rotmat
from quadpilot.core.mission import yaw_errors
from quadpilot.core.reward import RewardConfig, hover_reward
from quadpilot.core.vehicle_file import CRAZYFLIE, SEED_VEHICLE
from quadpilot.train.envs import QuadBatch, QuadEnv, QuadVectorEnv, make_config

IDS = {task: f"quadpilot.train:quadpilot/{task.capitalize()}-v0" for task in ("hover", "waypoint", "circle")}
TASKS = list(IDS)
CRASH_PENALTY = RewardConfig().crash_penalty
# hover: Gaussians of weight 0.5 (σ 1 m) and 1.0 (σ 0.1 m) on position, 0.3 (σ 0.5 rad) on heading,
# minus rate penalties
MAX_STEP_REWARD = 1.8
# start exactly at the start point, commanded to hold the start heading
STILL = {"init_pos_radius": 0.0, "init_vel": 0.0, "init_tilt_deg": 0.0, "heading_offset_deg": 0.0}


def make(task="hover", **kwargs):
    return gym.make(IDS[task], **kwargs)


# --- registration -------------------------------------------------------------------------


def test_make_works_in_a_fresh_interpreter_without_importing_quadpilot():
    code = textwrap.dedent(
        """
        import sys
        import gymnasium as gym
        assert not any(m.startswith("quadpilot") for m in sys.modules), "quadpilot imported too early"
        for name, dim in (("Hover", 18), ("Waypoint", 18), ("Circle", 21)):
            env = gym.make(f"quadpilot.train:quadpilot/{name}-v0")
            obs, info = env.reset(seed=0)
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            assert obs.shape == (dim,), obs.shape
            vec = gym.make_vec(f"quadpilot.train:quadpilot/{name}-v0", num_envs=3,
                               vectorization_mode="vector_entry_point")
            assert vec.reset(seed=0)[0].shape == (3, dim)
            print(name, type(env.unwrapped).__name__, type(vec).__name__)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == [f"{name} QuadEnv QuadVectorEnv" for name in ("Hover", "Waypoint", "Circle")]


# --- API checkers -------------------------------------------------------------------------

# Gymnasium's checker warns about any unbounded Box. The observation really is unbounded (velocity
# and rates have no hard limit); the policy side normalises it. Every other warning fails the test.
UNBOUNDED_BOX = "A Box observation space m"


@pytest.mark.parametrize("task", TASKS)
def test_env_passes_gymnasium_and_sb3_checkers(task):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = make(task)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
        sb3_check_env(env, warn=True)
    others = [str(w.message) for w in caught if UNBOUNDED_BOX not in str(w.message)]
    assert others == []


# --- seeding ------------------------------------------------------------------------------


def roll_out(env, seed, actions):
    obs, _ = env.reset(seed=seed)
    observations, rewards = [obs], []
    for a in actions:
        obs, reward, terminated, truncated, _ = env.step(a)
        observations.append(obs)
        rewards.append(reward)
        if terminated or truncated:
            obs, _ = env.reset()  # unseeded: continues the env's own generator
            observations.append(obs)
    return np.array(observations), np.array(rewards)


@pytest.mark.parametrize("task", TASKS)
def test_same_seed_same_episode(task):
    actions = np.random.default_rng(0).uniform(-0.4, 0.4, (300, 4)).astype(np.float32)
    obs_a, rew_a = roll_out(make(task), 7, actions)
    obs_b, rew_b = roll_out(make(task), 7, actions)
    assert np.array_equal(obs_a, obs_b) and np.array_equal(rew_a, rew_b)
    assert len(obs_a) > len(actions) + 1  # the rollout went through at least one reset
    obs_c, _ = roll_out(make(task), 8, actions)
    assert not np.array_equal(obs_a[0], obs_c[0])  # the seed matters


# --- time limit and crashes ---------------------------------------------------------------


def test_time_limit_truncates_without_terminating():
    env = make("hover", **STILL)
    env.reset(seed=0)
    zero = np.zeros(4, np.float32)  # action 0 is hover trim
    for k in range(1, 500):
        _, _, terminated, truncated, _ = env.step(zero)
        assert not terminated and not truncated, f"episode ended early at step {k}"
    _, reward, terminated, truncated, info = env.step(zero)
    assert truncated and not terminated
    assert info["steps"] == 500
    assert info["success"]  # held the start point within 5 cm
    assert reward == pytest.approx(MAX_STEP_REWARD, abs=1e-3)


def step_until_done(env, action, limit):
    """Step with a constant action until the episode ends: (steps taken, last step's results)."""
    for k in range(1, limit + 1):
        result = env.step(action)
        if result[2] or result[3]:
            return k, result
    raise AssertionError(f"the episode did not end within {limit} steps")


def expected_reward_without_crash(env, obs):
    batch = env.unwrapped.batch
    head = yaw_errors(batch.state, batch.heading)[1]
    return float(hover_reward(batch.state, obs[None, 0:3], np.array([False]), env.unwrapped.cfg.reward, head)[0])


def test_falling_to_the_ground_terminates_with_the_crash_penalty():
    env = make("hover")
    env.reset(seed=1)
    z0 = env.unwrapped.batch.state[0, IDX["z"]]
    full_down = -np.ones(4, np.float32)  # no thrust at all
    k, (obs, reward, terminated, truncated, info) = step_until_done(env, full_down, 200)
    assert terminated and not truncated
    state = env.unwrapped.batch.state[0]
    assert state[IDX["z"]] < 0, "the crash must come from the ground"
    # free fall from z0 reaches the ground after √(2·z0/g), give or take the initial velocity
    assert k == pytest.approx(100 * np.sqrt(2 * z0 / 9.81), abs=15)
    assert reward < MAX_STEP_REWARD - CRASH_PENALTY
    assert reward == pytest.approx(expected_reward_without_crash(env, obs) - CRASH_PENALTY, rel=1e-6)
    assert not info["success"]


def test_crash_on_the_last_step_is_terminated_not_truncated():
    def fall(episode_steps):
        # QuadEnv itself: gymnasium.make consumes a `episode_steps` keyword for its own
        # TimeLimit wrapper, which reports truncated=True even on a crash
        env = QuadEnv("hover", episode_steps=episode_steps)
        env.reset(seed=1)
        k, (_, _, terminated, truncated, _) = step_until_done(env, -np.ones(4, np.float32), episode_steps)
        return k, terminated, truncated

    k, terminated, truncated = fall(500)
    assert terminated and not truncated and k < 500
    # the same fall with the time limit at exactly that step: a crash is still a crash, so the
    # learner must not bootstrap from it
    assert fall(k) == (k, True, False)


def test_large_tilt_terminates():
    env = make("hover", **STILL)
    env.reset(seed=2)
    roll_left_up = np.array([-1, 1, 1, -1], np.float32)  # left rotors at twice hover, right ones off
    k, (obs, reward, terminated, truncated, _) = step_until_done(env, roll_left_up, 100)
    state = env.unwrapped.batch.state[0]
    assert terminated and not truncated
    assert state[IDX["roll"]] > np.radians(60) and state[IDX["z"]] > 1.5  # tilted, not fallen
    assert k < 30
    assert reward == pytest.approx(expected_reward_without_crash(env, obs) - CRASH_PENALTY, rel=1e-6)


def test_step_before_reset_is_refused():
    with pytest.raises(RuntimeError, match="reset"):
        QuadEnv("hover").step(np.zeros(4))


# --- options ------------------------------------------------------------------------------


def test_kwargs_configure_target_and_vehicle():
    env = make("hover", home=(0, 0, 10), vehicle="crazyflie", **STILL)
    obs, _ = env.reset(seed=3)
    cfg = env.unwrapped.cfg
    assert cfg.home == (0, 0, 10) and cfg.params is CRAZYFLIE
    batch = env.unwrapped.batch
    assert np.all(batch.params.mass == np.float32(CRAZYFLIE.mass))
    np.testing.assert_array_equal(batch.state[0, 0:3], [0, 0, 10])
    np.testing.assert_array_equal(obs[0:3], 0.0)  # position error to (0, 0, 10)
    for _ in range(100):  # action 0 is the Crazyflie's hover trim, not the seed vehicle's
        obs, *_ = env.step(np.zeros(4, np.float32))
    assert np.max(np.abs(obs[0:6])) < 1e-3

    default = make("hover")
    default.reset(seed=3)
    assert default.unwrapped.cfg.params is SEED_VEHICLE
    start = default.unwrapped.batch.state[0, 0:3]
    assert np.linalg.norm(start - np.array([0, 0, 2])) <= 1.0 + 1e-6


def test_vehicle_params_object_and_task_defaults():
    heavy = SEED_VEHICLE.scaled(mass=1.2)
    env = QuadEnv("hover", vehicle=heavy)
    assert env.cfg.params is heavy
    assert make_config("waypoint").home == (0.0, 0.0, 3.0)
    assert make_config("waypoint", home=(1.0, 2.0, 3.0)).home == (1.0, 2.0, 3.0)  # explicit wins


def test_unknown_kwargs_raise_a_clear_type_error():
    with pytest.raises(TypeError, match="max_steps") as err:
        make("hover", max_steps=100)
    assert "episode_steps" in str(err.value)  # names the known options
    with pytest.raises(TypeError, match="wind"):
        QuadVectorEnv(2, "hover", wind=3.0)


def test_bad_values_raise_value_errors():
    with pytest.raises(ValueError, match="task"):
        QuadEnv("loop")
    with pytest.raises(ValueError, match="nope"):
        QuadEnv("hover", vehicle="nope")
    with pytest.raises(ValueError, match="home"):
        QuadEnv("hover", home=(0, 2))


# --- vector env ---------------------------------------------------------------------------


def make_vec(task, n, **kwargs):
    return gym.make_vec(IDS[task], num_envs=n, vectorization_mode="vector_entry_point", **kwargs)


@pytest.mark.parametrize(("task", "dim"), [("hover", 18), ("waypoint", 18), ("circle", 21)])
def test_vector_env_shapes_and_dtypes(task, dim):
    vec = make_vec(task, 8)
    assert isinstance(vec, QuadVectorEnv) and vec.cfg.task == task
    assert vec.single_observation_space.shape == (dim,) and vec.observation_space.shape == (8, dim)
    assert vec.action_space.shape == (8, 4) and vec.single_action_space.shape == (4,)
    obs, _ = vec.reset(seed=0)
    assert obs.shape == (8, dim) and obs.dtype == np.float32 and obs in vec.observation_space
    obs, reward, terminated, truncated, _ = vec.step(vec.action_space.sample())
    assert obs.shape == (8, dim) and obs.dtype == np.float32
    assert reward.shape == (8,) and reward.dtype == np.float32
    assert terminated.shape == truncated.shape == (8,)
    assert terminated.dtype == truncated.dtype == np.bool_
    with pytest.raises(ValueError, match="actions must have shape"):
        vec.step(np.zeros((7, 4)))


def test_vector_env_refuses_step_before_reset_and_bad_size():
    with pytest.raises(RuntimeError, match="reset"):
        QuadVectorEnv(2, "hover").step(np.zeros((2, 4)))
    with pytest.raises(ValueError, match="num_envs"):
        QuadVectorEnv(0, "hover")


def single_copies(vec):
    """One single-drone QuadBatch per vector drone, in the same state (target, phase, rotor, …)."""
    singles = []
    for i in range(vec.num_envs):
        one = QuadBatch(vec.cfg, 1)
        for name in ("state", "rotor", "target", "target_vel", "phase", "steps", "obs", "heading"):
            setattr(one, name, getattr(vec.batch, name)[i : i + 1].copy())
        singles.append(one)
    return singles


def test_same_step_autoreset_keeps_the_final_observation():
    vec = make_vec("hover", 4, init_tilt_deg=5.0)
    vec.reset(seed=5)
    singles = single_copies(vec)
    actions = np.zeros((4, 4), np.float32)
    actions[0] = -1.0  # drone 0 cuts its motors and falls; the others hold hover trim
    returns, k = np.zeros(4), 0
    while k < 200:
        obs, reward, terminated, truncated, infos = vec.step(actions)
        expected = [s.step(actions[i : i + 1]) for i, s in enumerate(singles)]
        returns += reward
        k += 1
        if terminated.any() or truncated.any():
            break
        assert infos == {}
        for i in range(4):
            assert np.array_equal(obs[i], expected[i][0][0])
    assert terminated.tolist() == [True, False, False, False] and not truncated.any()
    assert infos["_final_obs"].tolist() == [True, False, False, False]
    assert infos["_episode"].tolist() == [True, False, False, False]
    # the final observation is what the same drone stepped alone saw, and shows it below ground
    final = infos["final_obs"][0]
    assert np.array_equal(final, expected[0][0][0])
    home_z = vec.cfg.home[2]
    assert final[2] + home_z < 0  # pos_error z + target z = altitude
    assert reward[0] == expected[0][1][0] and reward[0] < -CRASH_PENALTY + MAX_STEP_REWARD
    # episode statistics of the ended drone
    assert infos["episode"]["l"][0] == k
    assert infos["episode"]["r"][0] == pytest.approx(returns[0], rel=1e-9)
    assert not infos["episode"]["success"][0]
    # the returned observation of drone 0 is a fresh start, the others are untouched
    assert not np.array_equal(obs[0], final)
    assert np.linalg.norm(obs[0, 0:3]) <= vec.cfg.init_pos_radius + 1e-5
    assert vec.batch.steps.tolist() == [0, k, k, k]
    np.testing.assert_array_equal(vec.batch.rotor[0], vec.batch.u_hover)
    for i in (1, 2, 3):
        assert np.array_equal(obs[i], expected[i][0][0])
        assert np.array_equal(vec.batch.state[i], singles[i].state[0])
    # and the next step carries on from the reset state with a new episode
    obs, reward, terminated, truncated, infos = vec.step(np.zeros((4, 4), np.float32))
    assert vec.batch.steps.tolist() == [1, k + 1, k + 1, k + 1]


def test_time_limit_in_the_vector_env_reports_truncation():
    vec = QuadVectorEnv(3, "hover", episode_steps=20, **STILL)
    vec.reset(seed=0)
    for _ in range(19):
        _, _, terminated, truncated, infos = vec.step(np.zeros((3, 4), np.float32))
        assert not (terminated.any() or truncated.any())
    _, _, terminated, truncated, infos = vec.step(np.zeros((3, 4), np.float32))
    assert truncated.all() and not terminated.any()
    assert infos["episode"]["l"].tolist() == [20, 20, 20]
    assert infos["episode"]["r"] == pytest.approx(np.full(3, 20 * MAX_STEP_REWARD), abs=1e-3)
    assert infos["episode"]["success"].all()


@pytest.mark.parametrize("task", TASKS)
def test_vector_env_equals_single_drones(task):
    """N drones in the vector env and N single-drone engines from the same start give the same
    trajectories bit for bit, up to each drone's first episode end."""
    n = 6
    vec = QuadVectorEnv(n, task)
    vec.reset(seed=11)
    singles = single_copies(vec)
    rng = np.random.default_rng(1)
    running = np.ones(n, bool)
    ended = 0
    for _ in range(150):
        actions = rng.uniform(-0.3, 0.3, (n, 4)).astype(np.float32)
        obs, reward, terminated, truncated, infos = vec.step(actions)
        for i in np.flatnonzero(running):
            s_obs, s_rew, s_term, s_trunc, _ = singles[i].step(actions[i : i + 1])
            seen = infos["final_obs"][i] if (terminated[i] or truncated[i]) else obs[i]
            assert np.array_equal(seen, s_obs[0]), f"drone {i} differs"
            assert reward[i] == s_rew[0] and terminated[i] == s_term[0] and truncated[i] == s_trunc[0]
            if terminated[i] or truncated[i]:
                running[i] = False
                ended += 1
    assert ended >= 1 and running.any()  # compared through episode ends and long runs alike


def test_vector_env_same_seed_same_results():
    def run(seed):
        vec = QuadVectorEnv(8, "waypoint")
        out = [vec.reset(seed=seed)[0]]
        rng = np.random.default_rng(0)
        for _ in range(120):
            obs, reward, terminated, truncated, infos = vec.step(rng.uniform(-0.5, 0.5, (8, 4)))
            out += [obs, reward, terminated, truncated]
            if infos:
                out += [infos["final_obs"], infos["_final_obs"], infos["episode"]["r"], infos["episode"]["l"]]
        return out

    a, b = run(4), run(4)
    assert len(a) == len(b) and len(a) > 1 + 4 * 120  # at least one autoreset happened
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[0], run(5)[0])


def test_waypoint_target_radius_sets_the_target_distribution():
    n = 512
    vec = QuadVectorEnv(n, "waypoint")
    home = np.array(vec.cfg.home)
    obs, _ = vec.reset(seed=0)
    # waypoint drones start exactly at home, so the position error is home − target (in the
    # body frame: R·obs gives it back in the world frame)
    s = vec.batch.state
    rot = euler_to_rotmat(s[:, IDX["roll"]], s[:, IDX["pitch"]], s[:, IDX["yaw"]])
    np.testing.assert_allclose(np.einsum("nij,nj->ni", rot, obs[:, 0:3]), home - vec.batch.target, atol=1e-5)
    dist = np.linalg.norm(vec.batch.target - home, axis=1)
    assert dist.max() <= 0.5 + 1e-6 and dist.max() > 0.45  # the default stage fills its ball
    vec.set_target_radius(3.0)
    obs, _ = vec.reset()
    dist = np.linalg.norm(vec.batch.target - home, axis=1)
    assert dist.max() <= 3.0 + 1e-6 and dist.max() > 2.7
    assert np.mean(dist > 0.5) > 0.9  # uniform in the ball: P(d > 0.5) = 1 − (0.5/3)³ ≈ 0.995
    np.testing.assert_allclose(np.linalg.norm(obs[:, 0:3], axis=1), dist, atol=1e-5)
