"""Domain randomisation in the training environment: a preset by name, plants redrawn
for exactly the drones that reset and within range, the same plants for the same seed, the
nominal environment bit for bit when it is off, a resumed run that continues bit for bit, and the
quad-train flag."""

import dataclasses
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from quadpilot.core.randomization import PRESETS, RandomizationConfig
from quadpilot.core.vehicle_file import CRAZYFLIE, SEED_VEHICLE
from quadpilot.train.algorithms import load_for_resume, load_policy
from quadpilot.train.cli import main
from quadpilot.train.envs import EnvConfig, QuadBatch, QuadVectorEnv, make_config
from quadpilot.train.envs.evaluate import evaluate
from quadpilot.train.ppo import PPO, PPOConfig
from quadpilot.train.ppo.checkpoint import ppo_from_checkpoint
from quadpilot.train.runs.checkpoint import save_for_resume

HOVER = Path(__file__).parents[2] / "models" / "hover" / "policy.pt"
TINY = PPOConfig(num_envs=16, rollout_steps=16, minibatch_size=64, epochs=2, threads=1, seed=7)


def test_preset_by_name_in_make_config_gym_make_and_json():
    cfg = make_config("hover", randomization="pushes")
    assert cfg.randomization == PRESETS["pushes"]
    back = EnvConfig.from_json(json.loads(json.dumps(cfg.to_json())))
    assert back.randomization == cfg.randomization and back.params == cfg.params
    assert EnvConfig.from_json(make_config("hover").to_json()).randomization is None
    cf = make_config("hover", vehicle="crazyflie", randomization="default")
    assert cf.randomization.drag[1] == pytest.approx(0.3 * CRAZYFLIE.mass / SEED_VEHICLE.mass)
    env = gym.make("quadpilot.train:quadpilot/Hover-v0", randomization="default")
    assert env.unwrapped.cfg.randomization.name == "default"
    with pytest.raises(TypeError, match="randomization must be a RandomizationConfig"):
        EnvConfig(randomization=3)
    with pytest.raises(ValueError, match="unknown randomization preset"):
        make_config("hover", randomization="nope")


def test_off_by_default_and_nominal_plants():
    b = QuadBatch(make_config("hover"), 5)
    b.reset(np.ones(5, bool), np.random.default_rng(0))
    assert b.randomizer is None
    np.testing.assert_array_equal(b.params.mass, np.float32(SEED_VEHICLE.mass))
    np.testing.assert_array_equal(b.params.motor_tau, 0.0)


def test_a_fixed_nominal_plant_steps_bit_for_bit_like_no_randomisation():
    plain = QuadBatch(make_config("hover"), 32)
    fixed = QuadBatch(make_config("hover", randomization=RandomizationConfig.fixed()), 32)
    for b in (plain, fixed):
        b.reset(np.ones(32, bool), np.random.default_rng(5))  # the start states are drawn first
    rng = np.random.default_rng(9)
    for _ in range(100):
        a = rng.uniform(-0.3, 0.3, (32, 4)).astype(np.float32)
        for x, y in zip(plain.step(a), fixed.step(a), strict=True):
            np.testing.assert_array_equal(x, y)


def test_autoreset_redraws_the_plants_of_the_drones_that_ended_only():
    env = QuadVectorEnv(64, "hover", randomization="default", episode_steps=20)
    env.reset(seed=3)
    lo, hi = PRESETS["default"].mass
    rng = np.random.default_rng(0)
    changed_any = False
    for _ in range(60):
        before = env.batch.params.mass.copy()
        _, _, term, trunc, _ = env.step(rng.uniform(-1, 1, (64, 4)).astype(np.float32))
        after = env.batch.params.mass
        done = term | trunc
        np.testing.assert_array_equal(after[~done], before[~done])
        assert np.all(after[done] != before[done])
        changed_any |= done.any()
        ratio = after / np.float32(SEED_VEHICLE.mass)
        assert ratio.min() >= lo - 1e-6 and ratio.max() <= hi + 1e-6
    assert changed_any


def test_same_seed_same_plants_and_flights():
    def run(seed):
        env = QuadVectorEnv(16, "hover", randomization="pushes")
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(1)
        out = [obs]
        for _ in range(200):
            out.append(env.step(rng.uniform(-0.2, 0.2, (16, 4)).astype(np.float32))[0])
        return env.batch.params.mass.copy(), env.batch.randomizer.wind.copy(), np.stack(out)

    a, b, c = run(11), run(11), run(12)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a[0], c[0])


def test_evaluation_on_the_nominal_cell_equals_the_plain_evaluation():
    """Grid cells are `RandomizationConfig.fixed` plants: the all-nominal cell is the plain env."""
    policy = load_policy(HOVER)
    cfg = make_config("hover")
    a = evaluate(policy, cfg, episodes=8)
    b = evaluate(policy, dataclasses.replace(cfg, randomization=RandomizationConfig.fixed()), episodes=8)
    assert a == b and a["success_rate"] == 1.0
    heavy = evaluate(policy, dataclasses.replace(cfg, randomization=RandomizationConfig.fixed(mass=1.3)), episodes=8)
    assert heavy["mean_error_last_window_m"] > a["mean_error_last_window_m"] + 0.02  # sags without integral action


@pytest.mark.parametrize("name", ["pushes", "airframes"])
def test_resumed_randomised_training_continues_bit_for_bit(tmp_path, name):
    """Also for drawn airframes, whose motor maps use each drone's drawn hover command: a resumed run
    that lost them would fly the nominal one and part from the straight run."""
    env_cfg = make_config("hover", episode_steps=24, randomization=name)
    straight = PPO(TINY, env_cfg)
    for _ in range(3):
        straight.iterate()
    first = PPO(TINY, env_cfg)
    first.iterate()
    first.iterate()
    save_for_resume(tmp_path, first)
    ckpt, _, _ = load_for_resume(tmp_path)
    assert ckpt["env_config"]["randomization"]["name"] == name
    resumed = ppo_from_checkpoint(ckpt)
    resumed.iterate()
    for k, v in straight.model.state_dict().items():
        assert np.array_equal(v.numpy(), resumed.model.state_dict()[k].numpy()), k
    np.testing.assert_array_equal(straight.env.batch.state, resumed.env.batch.state)
    np.testing.assert_array_equal(straight.env.batch.params.mass, resumed.env.batch.params.mass)
    np.testing.assert_array_equal(straight.env.batch.randomizer.wind, resumed.env.batch.randomizer.wind)
    np.testing.assert_array_equal(straight.env.batch.randomizer.u_hover, resumed.env.batch.randomizer.u_hover)


CLI_TINY = ["--num-envs", "64", "--rollout-steps", "16", "--threads", "1", "--eval-episodes", "4", "--eval-every", "0"]


def test_quad_train_randomize_flag(tmp_path, capsys):
    out = tmp_path / "dr"
    assert main(["--task", "hover", "--out", str(out), *CLI_TINY, "--total-steps", "1024", "--randomize"]) == 0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["env"]["randomization"]["name"] == "default" and "--randomize" in cfg["command"]
    args = ["--task", "hover", "--out", str(out), *CLI_TINY, "--total-steps", "2048", "--resume"]
    assert main([*args, "--dr", "params"]) == 2
    assert "--randomize params (checkpoint: default)" in capsys.readouterr().err
    assert main(args) == 0  # resumes randomised without repeating the flag
    plain = tmp_path / "plain"
    assert main(["--task", "hover", "--out", str(plain), *CLI_TINY, "--total-steps", "1024"]) == 0
    assert json.loads((plain / "config.json").read_text())["env"]["randomization"] is None
