"""PPO on tiny configurations: the metrics it reports, how it treats NaN, determinism, presets."""

import math

import pytest
import torch

from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPO, PRESETS, NonFiniteError, PPOConfig
from quadpilot.train.runs.runlog import COLUMNS

TINY = {"num_envs": 16, "rollout_steps": 16, "minibatch_size": 64, "epochs": 2, "threads": 1, "seed": 3}
METRICS = (
    "policy_loss",
    "value_loss",
    "entropy",
    "approx_kl",
    "clip_fraction",
    "explained_variance",
    "grad_norm",
    "lr",
    "nonfinite_skipped",
    "global_step",
    "update",
    "steps_per_s",
    "rollout_s",
    "update_s",
    "ep_return",
    "ep_length",
    "success_rate",
    "episodes",
)


def tiny(**kw) -> PPO:
    # 8-step episodes, so several end inside one 16-step rollout and the episode metrics exist
    return PPO(PPOConfig(**{**TINY, **kw}), make_config("hover", episode_steps=8))


def editable(batch: dict) -> dict:
    """collect() returns inference-mode tensors; clones can be written into."""
    return {k: v.clone() for k, v in batch.items()}


def weights(ppo: PPO) -> list[torch.Tensor]:
    return [p.detach().clone() for p in ppo.model.parameters()]


def test_one_iterate_reports_every_metric_finite():
    ppo = tiny()
    m = ppo.iterate()
    assert set(METRICS) <= set(m), f"missing {set(METRICS) - set(m)}"
    bad = {k: v for k, v in m.items() if not math.isfinite(v)}
    assert not bad, f"non-finite metrics: {bad}"
    assert m["update"] == 1 and m["global_step"] == 16 * 16 and m["episodes"] > 0
    assert m["approx_kl"] >= 0.0 and 0.0 <= m["clip_fraction"] <= 1.0
    assert set(m) <= set(COLUMNS), f"metrics.csv has no column for {set(m) - set(COLUMNS)}"


def test_nan_in_a_batch_is_skipped_and_counted():
    ppo = tiny()
    batch = editable(ppo.collect())
    batch["obs"][5, 0] = float("nan")
    batch["adv"][9] = float("inf")
    m = ppo.update(batch)
    assert m["nonfinite_skipped"] == 2
    assert all(torch.isfinite(p).all() for p in ppo.model.parameters())
    assert math.isfinite(m["policy_loss"])  # the finite rest of the batch still trained


def test_repeated_nan_raises_non_finite_error():
    ppo = tiny(max_nonfinite_updates=3)
    batch = editable(ppo.collect())
    batch["ret"][0] = float("nan")
    for _ in range(2):
        ppo.update(batch)
    with pytest.raises(NonFiniteError, match=r"3 consecutive updates met NaN/Inf.*Lower the learning rate"):
        ppo.update(batch)
    assert all(torch.isfinite(p).all() for p in ppo.model.parameters())


def test_a_clean_update_resets_the_non_finite_streak():
    ppo = tiny(max_nonfinite_updates=2)
    batch = ppo.collect()
    bad = editable(batch)
    bad["obs"][0, 0] = float("nan")
    ppo.update(bad)
    ppo.update(batch)
    ppo.update(bad)  # not two in a row: no error


def test_same_seed_same_weights_after_two_updates():
    a, b = tiny(), tiny()
    for _ in range(2):
        ma, mb = a.iterate(), b.iterate()
    for wa, wb in zip(weights(a), weights(b), strict=True):
        assert torch.equal(wa, wb)
    assert ma["policy_loss"] == mb["policy_loss"]
    c = tiny(seed=4)
    c.iterate()
    c.iterate()
    assert not all(torch.equal(wa, wc) for wa, wc in zip(weights(a), weights(c), strict=True))


def test_seed001_preset_builds_32x32_actor_and_128x128_critic():
    cfg = PPOConfig(**{**PRESETS["seed001"], "threads": 1})
    ppo = PPO(cfg, make_config("hover"))
    obs_dim = ppo.env_cfg.layout.dim
    actor = [tuple(m.weight.shape) for m in ppo.model.actor if isinstance(m, torch.nn.Linear)]
    critic = [tuple(m.weight.shape) for m in ppo.model.critic if isinstance(m, torch.nn.Linear)]
    assert actor == [(32, obs_dim), (32, 32), (4, 32)]
    assert critic == [(128, obs_dim), (128, 128), (1, 128)]
    assert (cfg.num_envs, cfg.rollout_steps, cfg.minibatch_size, cfg.lr) == (1, 350, 64, 1e-4)
