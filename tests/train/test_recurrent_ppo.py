"""Recurrent PPO (`recurrent_ppo`) and the observation history (`history`), read like the maths:
sequences are whole stretches of one drone's rollout; the update replays each from its stored
state with resets at episode starts, so before any gradient step it reproduces the rollout's own
log-probabilities and values; minibatches are sets of whole sequences; a resumed run continues bit
for bit; the deterministic policies step with their state."""

import json

import numpy as np
import pytest
import torch

from quadpilot.train.algorithms import load_policy
from quadpilot.train.envs import QuadVectorEnv, make_config
from quadpilot.train.envs.evaluate import evaluate
from quadpilot.train.envs.history import History, HistoryVectorEnv, history_dim
from quadpilot.train.networks import RecurrentActorCritic
from quadpilot.train.ppo import PPO, PPOConfig
from quadpilot.train.ppo import recurrent as recurrent_ppo
from quadpilot.train.ppo.checkpoint import ppo_from_checkpoint
from quadpilot.train.ppo.rollout import minibatches
from quadpilot.train.runs.checkpoint import checkpoint_dict, save_checkpoint


def same(a: dict, b: dict) -> bool:
    """Equal evaluation results (NaN equal to NaN: no episode survived an untrained policy)."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


SMALL = {"num_envs": 16, "rollout_steps": 32, "minibatch_size": 128, "epochs": 2, "threads": 1}


def lstm_ppo(**kw):
    return PPO(PPOConfig(arch="lstm", lstm_hidden=16, **{**SMALL, **kw}), make_config("hover", sensor_noise="seed"))


def test_sequences_are_consecutive_steps_of_one_drone():
    T, N, L = 12, 5, 4
    # entry (t, n) = 100·n + t: a sequence must read 100·n + t0, t0+1, …, t0+L−1
    a = (100 * np.arange(N)[None, :] + np.arange(T)[:, None]).astype(np.float64)
    seq = recurrent_ppo.to_sequences(a, L)
    assert seq.shape == (L, T // L * N)
    for j in range(seq.shape[1]):
        col = seq[:, j]
        assert np.all(np.diff(col) == 1), col  # consecutive time steps
        assert len({int(v) // 100 for v in col}) == 1  # one drone
        assert col[0] % L == 0  # starting on a chunk boundary
    np.testing.assert_array_equal(recurrent_ppo.from_sequences(seq, T), a)
    t = torch.from_numpy(a)
    assert torch.equal(recurrent_ppo.to_sequences(t, L), torch.from_numpy(seq))
    with pytest.raises(ValueError, match="does not split"):
        recurrent_ppo.to_sequences(a, 5)


def test_minibatches_are_whole_sequences_each_used_once_per_epoch():
    g = torch.Generator().manual_seed(0)
    usable = torch.tensor([0, 1, 2, 4, 5, 6, 7, 9])  # 3 and 8 were not finite
    groups = minibatches(usable, 3, g)
    assert [len(x) for x in groups] == [3, 3]  # the remainder of 2 is dropped, as for transitions
    flat = torch.cat(groups).tolist()
    assert len(set(flat)) == 6 and set(flat) <= set(usable.tolist())


def test_lstm_resets_its_state_at_an_episode_start():
    torch.manual_seed(0)
    net = RecurrentActorCritic(6, 4, hidden=8)
    T, B = 10, 3
    obs = torch.randn(T, B, 6)
    starts = torch.zeros(T, B, dtype=torch.bool)
    starts[0] = True
    starts[4, 1] = True  # drone 1 starts a new episode at step 4
    h0 = (torch.randn(B, 8), torch.randn(B, 8))  # state left over from before: must not matter after a start
    mean, _ = net.actor_sequence(obs, h0, starts)
    fresh, _ = net.actor_sequence(obs[4:, 1:2], net.initial_state(1))
    torch.testing.assert_close(mean[4:, 1:2], fresh, rtol=0, atol=1e-6)
    alone, _ = net.actor_sequence(obs[:, 0:1], net.initial_state(1))
    torch.testing.assert_close(mean[:, 0:1], alone, rtol=0, atol=1e-6)  # drone 0 never resets after t=0
    # step by step with the explicit reset gives the same as the segment-fused sequence
    state, outs = h0, []
    for t in range(T):
        keep = (~starts[t]).float().unsqueeze(-1)
        a, state = net.actor_sequence(obs[t : t + 1], (state[0] * keep, state[1] * keep))
        outs.append(a)
    torch.testing.assert_close(torch.cat(outs), mean, rtol=0, atol=1e-6)


@pytest.mark.parametrize("bptt", [0, 8])
def test_replayed_sequences_reproduce_the_rollout(bptt):
    ppo = lstm_ppo(bptt_steps=bptt)
    ppo.iterate()  # the second rollout starts mid-episode, from carried states
    batch = ppo.collect()
    L = bptt or SMALL["rollout_steps"]
    S = SMALL["num_envs"] * SMALL["rollout_steps"] // L
    assert batch["obs"].shape == (L, S, 18) and batch["actor_h"].shape == (S, 16)
    assert batch["starts"].any()  # episodes started inside this rollout (crashes of an untrained policy)
    with torch.no_grad():
        dist, v, mb = recurrent_ppo.forward(ppo.model, batch, torch.arange(S))
    logp = dist.log_prob(mb["act"]).sum(-1)
    torch.testing.assert_close(logp, mb["logp"], rtol=0, atol=1e-4)  # ratio 1 before the first step
    torch.testing.assert_close(v, mb["val"], rtol=0, atol=1e-5)


def test_lstm_iterate_reports_every_metric_finite_and_updates_the_weights():
    """One update runs end to end (that it learns is tests/learning's cue task)."""
    ppo = lstm_ppo()
    before = {k: v.clone() for k, v in ppo.model.state_dict().items()}
    m = ppo.iterate()
    for k in ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction", "explained_variance", "grad_norm"):
        assert np.isfinite(m[k]), k
    assert m["nonfinite_skipped"] == 0
    assert any(not torch.equal(before[k], v) for k, v in ppo.model.state_dict().items())


def test_lstm_nan_sequence_is_skipped_and_counted():
    ppo = lstm_ppo()
    batch = {k: v.clone() for k, v in ppo.collect().items()}
    batch["adv"][3, 5] = float("nan")
    m = ppo.update(batch)
    assert m["nonfinite_skipped"] == SMALL["rollout_steps"]  # one whole sequence
    assert all(torch.isfinite(p).all() for p in ppo.model.parameters())


@pytest.mark.parametrize("kw", [{"arch": "lstm", "lstm_hidden": 16}, {"obs_history": 3}])
def test_resumed_training_continues_bit_for_bit(tmp_path, kw):
    cfg = PPOConfig(**{**SMALL, **kw})
    env_cfg = make_config("hover", sensor_noise="seed")
    straight = PPO(cfg, env_cfg)
    for _ in range(2):
        straight.iterate()
    save_checkpoint(tmp_path / "c.pt", straight)
    from quadpilot.train.algorithms import load_checkpoint

    resumed = ppo_from_checkpoint(load_checkpoint(tmp_path / "c.pt"))
    for _ in range(2):
        straight.iterate()
        resumed.iterate()
    for k, v in straight.model.state_dict().items():
        assert torch.equal(v, resumed.model.state_dict()[k]), k
    np.testing.assert_array_equal(straight._obs, resumed._obs)
    assert checkpoint_dict(straight)["trainer"]["extra_state"].keys() == {"noise"} | (
        {"rollout_state"} if "arch" in kw else {"history"}
    )


def test_loaded_lstm_policy_steps_like_the_trainer(tmp_path):
    ppo = lstm_ppo()
    ppo.iterate()
    save_checkpoint(tmp_path / "p.pt", ppo)
    policy = load_policy(tmp_path / "p.pt")
    assert policy.recurrent and policy.stateful
    obs = np.random.default_rng(0).normal(size=(6, 18)).astype(np.float32)
    trainer = ppo.act_deterministic
    s1, s2 = policy.initial_state(6), trainer.initial_state(6)
    for _ in range(5):
        a1, s1 = policy.step(obs, s1)
        a2, s2 = trainer.step(obs, s2)
        np.testing.assert_array_equal(a1, a2)
    with pytest.raises(TypeError, match="initial_state"):
        policy(obs)
    r = evaluate(policy, policy.env_config, episodes=4)
    assert r["episodes"] == 4 and np.isfinite(r["mean_return"])
    assert same(r, evaluate(ppo.act_deterministic, ppo.env_cfg, episodes=4))


# --- observation history ----------------------------------------------------------------------


def test_history_stacks_observations_and_the_actions_that_led_to_them():
    h = History(2, 3, 3)
    o = lambda v: np.full((2, 3), v, np.float32)  # noqa: E731
    a = lambda v: np.full((2, 4), v, np.float32)  # noqa: E731
    h.reset(np.ones(2, bool), o(1))
    np.testing.assert_array_equal(h.stacked()[0], [1, 1, 1, 0, 0, 0, 0] * 3)  # first obs, zero actions
    h.push(o(2), a(0.5))
    h.push(o(3), a(-0.5))
    row = h.stacked()[0].reshape(3, 7)
    np.testing.assert_array_equal(row[:, 0], [3, 2, 1])  # newest first
    np.testing.assert_array_equal(row[:, 3], [-0.5, 0.5, 0.0])  # the action before each observation
    peek = h.peek(o(4)[[1]], a(0.25)[[1]], np.array([1]))
    np.testing.assert_array_equal(peek.reshape(3, 7)[:, 0], [4, 3, 2])
    np.testing.assert_array_equal(h.stacked()[1].reshape(3, 7)[:, 0], [3, 2, 1])  # peek changed nothing
    h.reset(np.array([False, True]), o(9))
    assert h.stacked()[1].reshape(3, 7)[:, 0].tolist() == [9, 9, 9] and h.stacked()[0][0] == 3


def test_history_env_keeps_the_final_observation_and_resets_at_episode_start():
    cfg = make_config("hover", episode_steps=3)
    env = HistoryVectorEnv(QuadVectorEnv(2, config=cfg), 2)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (2, history_dim(18, 2)) == (2, 44)
    act = np.full((2, 4), 2.0, np.float32)  # clipped to 1 before it enters the history
    for _ in range(2):
        obs, *_ = env.step(act)
    np.testing.assert_array_equal(obs[:, 18:22], 1.0)
    obs, _, _, trunc, infos = env.step(act)
    assert trunc.all()
    final = infos["final_obs"]
    np.testing.assert_array_equal(final[:, 18:22], 1.0)  # the ended episode's history
    np.testing.assert_array_equal(obs[:, 18:22], 0.0)  # the new episode: zero actions
    np.testing.assert_array_equal(obs[:, :18], obs[:, 22:40])  # filled with its first observation


def test_history_policy_trains_evaluates_and_refuses_export(tmp_path):
    ppo = PPO(PPOConfig(obs_history=3, **SMALL), make_config("hover"))
    assert ppo.model.actor[0].in_features == 3 * (18 + 4)
    ppo.iterate()
    save_checkpoint(tmp_path / "h.pt", ppo)
    policy = load_policy(tmp_path / "h.pt")
    assert policy.stateful and not policy.recurrent
    assert same(
        evaluate(policy, policy.env_config, episodes=4), evaluate(ppo.act_deterministic, ppo.env_cfg, episodes=4)
    )
    from quadpilot.export.onnx_export import deployable
    from quadpilot.train.runs.checkpoint import CheckpointError

    with pytest.raises(CheckpointError, match="in-process only"):
        deployable(policy)


def test_bad_recurrent_settings_are_refused():
    with pytest.raises(ValueError, match="divide"):
        PPO(PPOConfig(arch="lstm", bptt_steps=5, **SMALL), make_config("hover"))
    with pytest.raises(ValueError, match="obs_history"):
        PPO(PPOConfig(arch="lstm", obs_history=2, **SMALL), make_config("hover"))
