"""The SB3 comparison baseline: every PPOConfig field reaches SB3 (or its difference is written down),
the networks and schedules it builds are ours, time-limit ends reach SB3 as truncations, its files
hold no pickle, and `quad-train --algo sb3` writes our run files and is judged by our evaluator."""

import csv
import dataclasses
import json
import math
import subprocess
import sys
import tempfile

import numpy as np
import pytest
import torch

pytest.importorskip("stable_baselines3")

from quadpilot.studies import matched_settings as ms
from quadpilot.train import sb3_baseline as sb
from quadpilot.train.cli import main
from quadpilot.train.envs import EnvConfig, make_config
from quadpilot.train.envs import evaluate as evaluate_module
from quadpilot.train.networks import ActorCritic
from quadpilot.train.ppo import PRESETS, PPOConfig
from quadpilot.train.runs.runlog import HEADER, _json_safe

TINY = ["--num-envs", "64", "--rollout-steps", "16", "--threads", "1", "--eval-episodes", "8"]
ODD = PPOConfig(  # nothing at its default where SB3 has a parameter for it
    num_envs=3,
    rollout_steps=40,
    total_steps=12_345,
    epochs=3,
    minibatch_size=48,
    lr=2e-4,
    lr_schedule="constant",
    gamma=0.97,
    lam=0.9,
    clip_eps=0.15,
    clip_value=True,
    vf_coef=0.8,
    ent_coef=0.01,
    max_grad_norm=0.7,
    target_kl=0.03,
    actor_hidden=(32, 16),
    critic_hidden=(48,),
    activation="relu",
    init_log_std=-0.7,
    reward_scale=0.1,
    normalize_obs=True,
    normalize_adv=False,
    seed=5,
    threads=1,
)


def build(cfg: PPOConfig, env_cfg: EnvConfig | None = None):
    s = sb.sb3_settings(cfg)
    venv, adapter, norm = sb.make_env(s, env_cfg or make_config("hover"))
    return sb.build_model(s, venv), adapter, norm


def linears(module) -> list[torch.nn.Linear]:
    return [m for m in module.modules() if isinstance(m, torch.nn.Linear)]


def test_the_sb3_model_gets_every_matched_setting():
    model, _, norm = build(ODD)
    assert (model.n_envs, model.n_steps, model.batch_size, model.n_epochs) == (3, 40, 48, 3)
    assert (model.gamma, model.gae_lambda, model.ent_coef, model.max_grad_norm) == (0.97, 0.9, 0.01, 0.7)
    assert model.clip_range(1.0) == 0.15 and model.clip_range_vf(0.5) == 0.15
    assert model.vf_coef == 0.4  # SB3's MSE × 0.4 = our ½·MSE × 0.8
    assert model.target_kl == pytest.approx(0.02) and model.normalize_advantage is False
    assert model.seed == 5 and norm is not None and norm.norm_obs and not norm.norm_reward
    assert norm.clip_obs == 10.0
    opt = model.policy.optimizer
    assert isinstance(opt, torch.optim.Adam) and opt.defaults["eps"] == 1e-5 and opt.defaults["lr"] == 2e-4
    pi, vf = linears(model.policy.mlp_extractor.policy_net), linears(model.policy.mlp_extractor.value_net)
    assert [m.out_features for m in pi] == [32, 16] and [m.out_features for m in vf] == [48]
    assert all(isinstance(m, torch.nn.ReLU) for m in model.policy.mlp_extractor.policy_net if not linears(m))
    assert torch.allclose(model.policy.log_std, torch.full((4,), -0.7))
    assert model.policy.share_features_extractor and not list(model.policy.features_extractor.parameters())


def test_every_ppoconfig_field_has_a_mapping_or_a_stated_difference():
    """The matched settings, written down (quadpilot.studies.matched_settings): every PPOConfig field
    has its SB3 parameter or a stated difference, every path it names exists in the settings
    sb3_settings builds, and the report's table has a row per field."""
    fields = {f.name for f in dataclasses.fields(PPOConfig)}
    assert set(ms.FIELD_MAP) == fields, (
        f"add these PPOConfig fields to matched_settings.FIELD_MAP: {sorted(fields - set(ms.FIELD_MAP))}; "
        f"remove these: {sorted(set(ms.FIELD_MAP) - fields)}"
    )
    for name, (path, note) in ms.FIELD_MAP.items():
        assert path is not None or note, f"{name}: no SB3 parameter and no stated difference"
    settings = sb.sb3_settings(ODD)
    for path, _ in ms.FIELD_MAP.values():
        if path is not None:
            ms._get(settings, path)  # every path exists
    assert len(ms.settings_rows(ODD)) == len(fields)
    json.dumps(settings)  # saved in config.json


def test_sb3_initialises_like_ours():
    """Orthogonal weights (all singular values = the gain): √2 hidden, 0.01 policy output, 1 value
    output; zero biases. The same gains as networks.mlp."""
    model, _, _ = build(dataclasses.replace(PPOConfig(), num_envs=2, threads=1))
    p = model.policy
    layers = [
        *[(m, math.sqrt(2)) for m in linears(p.mlp_extractor)],
        (p.action_net, 0.01),
        (p.value_net, 1.0),
    ]
    for lin, gain in layers:
        sv = torch.linalg.svdvals(lin.weight.detach())
        assert torch.allclose(sv[: min(lin.weight.shape)], torch.full_like(sv, gain), rtol=1e-4), (lin, sv)
        assert not lin.bias.detach().any()


def test_with_our_weights_sb3_computes_our_policy_and_value():
    """Copy an ActorCritic's weights into the SB3 policy built from the same config: the same
    deterministic action, value, log-probability and entropy."""
    cfg = dataclasses.replace(PPOConfig(**PRESETS["seed001"]), threads=1)
    ours = ActorCritic(18, 4, cfg.actor_hidden, cfg.critic_hidden, cfg.activation, cfg.init_log_std)
    model, _, _ = build(cfg)
    p = model.policy
    pairs = [
        *zip(linears(ours.actor)[:-1], linears(p.mlp_extractor.policy_net), strict=True),
        (linears(ours.actor)[-1], p.action_net),
        *zip(linears(ours.critic)[:-1], linears(p.mlp_extractor.value_net), strict=True),
        (linears(ours.critic)[-1], p.value_net),
    ]
    with torch.no_grad():
        for a, b in pairs:
            a.weight.normal_()  # not the init: any weights must give the same function
            a.bias.normal_()
            b.weight.copy_(a.weight)
            b.bias.copy_(a.bias)
        ours.log_std.fill_(-0.4)
        p.log_std.copy_(ours.log_std)
        obs = torch.randn(32, 18)
        act = torch.randn(32, 4)
        values, logp, entropy = p.evaluate_actions(obs, act)
        dist = ours.distribution(obs)
        assert torch.allclose(values.squeeze(-1), ours.value(obs), atol=1e-5)
        assert torch.allclose(logp, dist.log_prob(act).sum(-1), atol=1e-5)
        assert torch.allclose(entropy, dist.entropy().sum(-1), atol=1e-5)
        assert torch.allclose(p._predict(obs, deterministic=True), ours.actor(obs), atol=1e-6)


@pytest.mark.parametrize(
    ("schedule", "total", "batch"), [("linear", 10 * 64, 64), ("linear", 1000, 64), ("constant", 500, 50)]
)
def test_learning_rate_schedule_is_ours_update_by_update(schedule, total, batch):
    cfg = PPOConfig(lr=1e-3, lr_schedule=schedule, total_steps=total, num_envs=1, rollout_steps=batch)
    lr = sb.MatchedLR(cfg.lr, schedule, total, batch)
    for k in range(1, cfg.num_updates + 1):
        ours = cfg.lr * (max(0.0, 1.0 - (k - 1) / cfg.num_updates) if schedule == "linear" else 1.0)
        progress_remaining = 1.0 - k * batch / total  # what SB3 passes before update k
        assert lr(progress_remaining) == pytest.approx(ours, rel=1e-9, abs=1e-15), k
    assert lr(1.0) == cfg.lr  # SB3 builds the optimizer with lr(1)


def test_time_limit_ends_reach_sb3_as_truncations_and_crashes_do_not():
    cfg = make_config("hover", episode_steps=3)
    s = sb.sb3_settings(PPOConfig(num_envs=4, threads=1, seed=1))
    venv, adapter, _ = sb.make_env(s, cfg)
    venv.seed(1)
    venv.reset()
    for _ in range(2):
        _, _, done, infos = venv.step(np.zeros((4, 4), np.float32))
        assert not done.any() and infos == [{}] * 4
    obs, _, done, infos = venv.step(np.zeros((4, 4), np.float32))
    assert done.all()
    for i, info in enumerate(infos):
        assert info["TimeLimit.truncated"] is True and info["terminal_observation"].shape == (18,)
        assert not np.array_equal(info["terminal_observation"], obs[i])  # obs is the reset one
        assert info["episode"]["l"] == 3 and isinstance(info["is_success"], bool)
    assert len(adapter.take_episodes()) == 4 and adapter.take_episodes() == []

    falling = make_config("hover", home=(0.0, 0.0, 0.02), init_pos_radius=0.0, init_vel=0.0, init_tilt_deg=0.0)
    venv, _, _ = sb.make_env(s, falling)
    venv.reset()
    for _ in range(200):  # no thrust from 2 cm: the ground ends it, a termination
        _, _, done, infos = venv.step(-np.ones((4, 4), np.float32))
        if done.any():
            break
    assert done.all() and not any(info["TimeLimit.truncated"] for info in infos)


def test_observation_statistics_round_trip_without_pickle(tmp_path):
    model, adapter, norm = build(dataclasses.replace(ODD, num_envs=8))
    model.env.reset()
    for _ in range(20):
        model.env.step(np.random.default_rng(0).uniform(-1, 1, (8, 4)).astype(np.float32))
    stats = sb.ObsNorm.from_vec_normalize(norm)
    path = stats.save(tmp_path / sb.OBS_NORM_FILE)
    with np.load(path, allow_pickle=False) as z:  # plain arrays only
        assert set(z.files) == {"mean", "var", "count", "clip_obs", "epsilon", "enabled"}
    back = sb.ObsNorm.load(path)
    assert np.array_equal(back.mean, stats.mean) and np.array_equal(back.var, stats.var)
    assert back.count == stats.count > 20 * 8 and back.enabled
    raw = adapter.env.batch.obs.copy() * 3
    assert np.allclose(back.normalize(raw), norm.normalize_obs(raw), atol=1e-6)
    ident = sb.ObsNorm.load(sb.ObsNorm.identity(18).save(tmp_path / "id.npz"))
    assert np.array_equal(ident.normalize(raw), raw.astype(np.float32))


def test_quad_train_algo_sb3_writes_our_run_files_and_is_judged_by_our_evaluator(tmp_path, monkeypatch, capsys):
    calls = []
    real = evaluate_module.evaluate

    def spy(policy, env_cfg, episodes=100, seed=12345):
        calls.append((policy, env_cfg, episodes))
        return real(policy, env_cfg, episodes=episodes, seed=seed)

    monkeypatch.setattr(evaluate_module, "evaluate", spy)
    temp = tmp_path / "temp"  # the temp directory: SB3's logger writes there unless given one
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    monkeypatch.delenv("SB3_LOGDIR", raising=False)  # else SB3 would write there
    out = tmp_path / "sb3"
    assert (
        main(
            ["--algo", "sb3", "--task", "hover", "--out", str(out), *TINY, "--total-steps", "3072", "--eval-every", "1"]
        )
        == 0
    )
    assert "done (sb3), 3,072 steps in 3 updates" in capsys.readouterr().out
    assert not [p.name for p in temp.iterdir() if p.name.startswith("SB3-")]  # nothing left behind
    names = {p.name for p in out.iterdir()}
    assert {"config.json", "metrics.csv", "eval.json", "curves.png", sb.POLICY_FILE, sb.OBS_NORM_FILE} <= names
    assert (out / "metrics.csv").read_text().splitlines()[0] == HEADER
    with open(out / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["global_step"]) for r in rows] == [1024, 2048, 3072]
    assert [float(r["lr"]) for r in rows] == pytest.approx([1e-3, 1e-3 * 2 / 3, 1e-3 / 3])  # ours, update by update
    for key in ("time_s", "policy_loss", "value_loss", "entropy", "approx_kl", "steps_per_s", "update_s"):
        assert all(math.isfinite(float(r[key])) for r in rows), key
    assert all(r["eval_success_rate"] != "" for r in rows)
    config = json.loads((out / "config.json").read_text())
    assert config["algo"] == "sb3" and config["ppo"]["num_envs"] == 64 and config["sb3"]["ppo"]["n_steps"] == 16
    assert config["sb3"]["ppo"]["vf_coef"] == 0.25 and config["versions"]["stable_baselines3"]
    ev = json.loads((out / "eval.json").read_text())
    assert ev["algo"] == "sb3" and ev["episodes"] == 8 and ev["global_step"] == 3072
    assert "first_success" in ev and set(ev["time_breakdown_s"]) >= {"env_s", "inference_s", "update_s"}
    # our evaluator judged it (periodic evaluations and the final one), on the training environment, and
    # then, trained through quad-train's default timing, without delay and at a fixed 20 ms ± 10 ms
    trained = calls[: len(rows) + 1]
    assert all(json.loads(json.dumps(c[1].to_json())) == config["env"] for c in trained)
    assert [c[1].timing and c[1].timing.name for c in calls[len(rows) + 1 :]] == [None, "20ms±10"]
    assert set(ev["timings"]) == {"no_delay", "delay_20ms_jitter_10ms"}
    # the saved files give back the same policy: the same evaluation
    again = _json_safe(real(sb.load_policy(out), EnvConfig.from_json(config["env"]), episodes=8))
    assert again == {k: ev[k] for k in again}


def test_algo_sb3_refuses_what_it_cannot_do(tmp_path, capsys):
    out = tmp_path / "x"
    for args, message in [
        (["--task", "waypoint"], "waypoint's curriculum is not wired to SB3"),
        (["--task", "hover", "--resume"], "--resume is not available with --algo sb3"),
        (["--task", "hover", "--checkpoint-every", "3"], "--checkpoint-every does not apply"),
    ]:
        assert main(["--algo", "sb3", *args, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
        assert not out.exists()


def test_our_ppo_never_imports_sb3():
    code = (
        "import sys; from quadpilot.train.cli import main; "
        "import quadpilot.train.ppo, quadpilot.train.runs.checkpoint; "
        "main(['--help']); print('stable_baselines3' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "False"
