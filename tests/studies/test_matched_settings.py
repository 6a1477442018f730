"""The matched settings of the SB3 comparison, written down (quadpilot.studies.matched_settings):
every PPOConfig field has its SB3 parameter or a stated difference, every path it names exists in
the settings sb3_settings builds, and the report's table has a row per field."""

import dataclasses
import json

import pytest

pytest.importorskip("stable_baselines3")

from quadpilot.studies import matched_settings as ms
from quadpilot.train.ppo import PPOConfig
from quadpilot.train.sb3_baseline import sb3_settings

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


def test_every_ppoconfig_field_has_a_mapping_or_a_stated_difference():
    fields = {f.name for f in dataclasses.fields(PPOConfig)}
    assert set(ms.FIELD_MAP) == fields, (
        f"add these PPOConfig fields to matched_settings.FIELD_MAP: {sorted(fields - set(ms.FIELD_MAP))}; "
        f"remove these: {sorted(set(ms.FIELD_MAP) - fields)}"
    )
    for name, (path, note) in ms.FIELD_MAP.items():
        assert path is not None or note, f"{name}: no SB3 parameter and no stated difference"
    settings = sb3_settings(ODD)
    for path, _ in ms.FIELD_MAP.values():
        if path is not None:
            ms._get(settings, path)  # every path exists
    assert len(ms.settings_rows(ODD)) == len(fields)
    json.dumps(settings)  # saved in config.json
