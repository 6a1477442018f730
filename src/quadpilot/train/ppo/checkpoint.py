"""PPO's checkpoints: its training state (`ppo_state_dict`, `load_ppo_state`), a PPO trainer
rebuilt from a loaded file (`ppo_from_checkpoint`), and a deployable policy file for a network PPO
did not train (`policy_checkpoint_dict`, `save_untrained_policy`). The layout and its reading are
every algorithm's (`runs.checkpoint`, `runs.checkpoint_read`)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import torch

from quadpilot.atomic_files import atomic_write

from ..envs import EnvConfig
from ..networks import build_actor_critic
from ..runs.checks import SCHEMA, plain
from . import PPO, PPOConfig


def ppo_state_dict(ppo: PPO) -> dict:
    """Everything that changes while `ppo` trains, as tensors and plain data (copies, not views):
    `Trainer.state_dict`, with PPO's entries from `PPO.own_state` (the normaliser's statistics
    among them, whether or not it was used)."""
    return ppo.state_dict()


def load_ppo_state(ppo: PPO, state: dict, source: str = "checkpoint") -> None:
    """Put `state` (from `ppo_state_dict` or a loaded checkpoint) into `ppo`, which must have been
    built with the same configuration. Raises CheckpointError if anything does not fit."""
    ppo.load_state_dict(state, source)


def ppo_from_checkpoint(ckpt: dict, cfg: PPOConfig | None = None, source: str = "checkpoint") -> PPO:
    """A PPO trainer rebuilt from a loaded checkpoint, ready to continue. `cfg` may replace the
    stored PPOConfig (e.g. a longer total_steps); the network and batch shapes must still fit."""
    return PPO.from_checkpoint(ckpt, cfg, source)


def policy_checkpoint_dict(
    model: torch.nn.Module,
    ppo_cfg: PPOConfig,
    env_cfg: EnvConfig,
    global_step: int = 0,
    *,
    obs_rms=None,
    updates: int = 0,
    extra: dict | None = None,
) -> dict:
    """A deployable policy file (policy.pt format) without optimizer, trainer or environment state:
    it loads, exports and flies but cannot be resumed. For a network PPO did not train (e.g. a
    freshly built `RecurrentActorCritic` to test export and runtime on; identity normaliser), or a
    training snapshot (`save_snapshot`: the run's `obs_rms`, `updates` and `extra`)."""
    from quadpilot.core.normalize import RunningMeanStd

    rms = obs_rms if obs_rms is not None else RunningMeanStd((env_cfg.layout.dim,))
    if extra is None:
        extra = {"note": "not trained by PPO: built to test export and runtime"}
    return plain(
        {
            "schema": SCHEMA,
            "algo": "ppo",
            "created_unix": time.time(),
            "ppo_config": ppo_cfg.to_json(),
            "env_config": env_cfg.to_json(),
            "obs_layout": env_cfg.layout.to_json(),
            "model": {k: v.detach().clone() for k, v in model.state_dict().items()},
            "optimizer": {},
            "obs_rms": rms.state_dict(),
            "global_step": int(global_step),
            "updates": int(updates),
            "trainer": {},
            "env": {},
            "rng": {},
            "extra": dict(extra),
        }
    )


def save_untrained_policy(
    path: str | os.PathLike, ppo_cfg: PPOConfig, env_cfg: EnvConfig, seed: int = 0, head_gain: float = 1.0
) -> Path:
    """Write a policy file for a freshly initialised network of `ppo_cfg.arch`, its action head
    re-initialised with `head_gain` (the training init, 0.01, makes every action ≈ 0, which would
    make a parity test blind). For testing and benchmarking export and runtime on architectures
    PPO does not train yet (the LSTM)."""

    torch.manual_seed(seed)
    model = build_actor_critic(env_cfg.layout.dim, 4, ppo_cfg)
    head = model.actor_head if getattr(model, "recurrent", False) else model.actor[-1]
    torch.nn.init.orthogonal_(head.weight, head_gain)
    data = policy_checkpoint_dict(model, ppo_cfg, env_cfg)
    return atomic_write(path, lambda f: torch.save(data, f))
