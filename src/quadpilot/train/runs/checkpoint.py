"""Checkpoints: everything needed to resume training bit for bit, or to deploy the policy.

A checkpoint is a `torch.save` file holding tensors and JSON-able data only (dict, list, tuple, str,
int, float, bool, None), so `torch.load(path, weights_only=True)` reads it and no pickle of ours is
ever executed (docs/architecture.md "Conventions"). Every algorithm writes the same layout (`trainer`'s docstring
lists the entries: schema, algo, its configuration, environment, model, optimizer, normaliser,
counts, trainer, env and RNG state, extra) plus entries of its own (SAC: critics, temperature,
replay count); a file without "algo" is PPO's, as every file before SAC wrote one.

`policy.pt` (the deployable file that quad-export reads) has the same format as `checkpoint.pt`.
Snapshots (`save_snapshot`, quad-train --snapshot-every) are `snapshots/policy-<steps>.pt`: the same
format with the weights and normaliser of that moment and no optimizer, trainer or environment
state (`trainer.Trainer.policy_dict`), so each loads, exports and flies like policy.pt.

Writes are atomic (`atomic_files.atomic_write`: a temporary file in the same directory, flushed and
fsync'd, then `os.replace`, then the directory fsync'd), so a crash or `kill -9` leaves either the
old file or the new one, never half of one. For resuming, `save_for_resume` keeps two generations
(`checkpoint.pt` and `checkpoint.prev.pt`), and `load_for_resume` falls back to the older one if the
newer is unreadable. Reading a file checks every entry (`checkpoint_read.load_checkpoint`) before
anything is built from it.

No algorithm is named here: the readers take the registry (`train.algorithms.ALGORITHMS`, where
`load_policy` and `load_trainer` are bound to it), and `TrainedPolicy` asks the checkpoint's
Trainer class for its network (`Trainer.policy_settings`, `Trainer.policy_network`). PPO's own
checkpoint helpers are `train.ppo.checkpoint`'s.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from quadpilot.atomic_files import atomic_write

from ..envs import EnvConfig
from ..envs.history import history_dim
from ..networks.actor import DeterministicActor
from .checkpoint_read import algorithm_of, load_checkpoint
from .checks import (
    MAX_BATCH,
    MAX_ENVS,
    MAX_OBS_HISTORY,
    MAX_THREADS,
    CheckpointError,
    one_line,
    rms_state,
    short,
)
from .trainer import LATEST, PREVIOUS, Trainer

__all__ = ["MAX_BATCH", "MAX_ENVS", "MAX_OBS_HISTORY", "MAX_THREADS", "CheckpointError"]

POLICY = "policy.pt"
SNAPSHOTS = "snapshots"


# --- trainers to and from checkpoints ---------------------------------------------------------


def checkpoint_dict(agent: Trainer, extra: dict | None = None) -> dict:
    """The full checkpoint content for `agent` (see `trainer`'s docstring)."""
    return agent.checkpoint_dict(extra)


def trainer_from_checkpoint(
    ckpt: dict, algorithms: dict, cfg=None, source: str = "checkpoint", directory=None
) -> Trainer:
    """The trainer of the checkpoint's algorithm (found in the registry `algorithms`), rebuilt and
    ready to continue (`Trainer.from_checkpoint`)."""
    return algorithm_of(ckpt, algorithms).from_checkpoint(ckpt, cfg, source, directory)


def load_trainer(path: str | os.PathLike, algorithms: dict) -> Trainer:
    """The trainer of a checkpoint file, with what lies beside it (SAC's replay chunks)."""
    path = Path(path)
    return trainer_from_checkpoint(
        load_checkpoint(path, algorithms), algorithms, source=str(path), directory=path.parent
    )


# --- files ----------------------------------------------------------------------------------


def save_checkpoint(
    path: str | os.PathLike, agent: Trainer, extra: dict | None = None, keep_previous: str | None = None
) -> Path:
    """Write `agent` (and the JSON-able `extra`) to `path` atomically; see `atomic_files.atomic_write`."""
    data = agent.checkpoint_dict(extra)
    return atomic_write(path, lambda f: torch.save(data, f), keep_previous)


def save_for_resume(directory: str | os.PathLike, agent: Trainer, extra: dict | None = None) -> Path:
    """Write `directory/checkpoint.pt`, first moving the current one to `checkpoint.prev.pt` (and,
    for SAC, the replay rows added since the last save beside it: `SAC.save_for_resume`)."""
    return agent.save_for_resume(directory, extra)


def has_checkpoint(directory: str | os.PathLike) -> bool:
    d = Path(directory)
    return (d / LATEST).exists() or (d / PREVIOUS).exists()


def load_for_resume(directory: str | os.PathLike, algorithms: dict) -> tuple[dict, Path, str | None]:
    """The newest readable checkpoint in `directory`: (checkpoint, its path, warning or None).

    Tries `checkpoint.pt`, then `checkpoint.prev.pt`; the warning says why the newer one was
    skipped. Raises CheckpointError with both reasons if neither can be read."""
    d = Path(directory)
    try:
        return load_checkpoint(d / LATEST, algorithms), d / LATEST, None
    except CheckpointError as latest_error:
        try:
            ckpt = load_checkpoint(d / PREVIOUS, algorithms)
        except CheckpointError as prev_error:
            raise CheckpointError(f"no usable checkpoint in {d}: {latest_error}; and {prev_error}") from None
        warning = f"{latest_error}; resuming from the previous checkpoint {d / PREVIOUS} instead"
        return ckpt, d / PREVIOUS, warning


def snapshot_path(directory: str | os.PathLike, global_step: int) -> Path:
    """`directory/snapshots/policy-<global_step>.pt`."""
    return Path(directory) / SNAPSHOTS / f"policy-{int(global_step)}.pt"


def save_snapshot(directory: str | os.PathLike, agent: Trainer, extra: dict | None = None) -> Path:
    """Write the policy `agent` has now to `snapshot_path(directory, agent.global_step)` atomically
    (a small deployable file, see `Trainer.policy_dict`); the same step overwrites the same file."""
    path = snapshot_path(directory, agent.global_step)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = agent.policy_dict(extra or {})
    return atomic_write(path, lambda f: torch.save(data, f))


def list_snapshots(directory: str | os.PathLike) -> list[tuple[int, Path]]:
    """The snapshots of a run directory as (training steps, path), oldest first."""
    found = []
    for path in (Path(directory) / SNAPSHOTS).glob("policy-*.pt"):
        steps = path.stem.removeprefix("policy-")
        if steps.isdigit():
            found.append((int(steps), path))
    return sorted(found)


# --- the deployable policy ------------------------------------------------------------------


class TrainedPolicy:
    """The deterministic policy of a checkpoint, without a trainer or an environment: a callable
    from raw observations (N, obs_dim) float32 to actions (N, 4) in [−1, 1], the same mapping as
    `PPO.act_deterministic` (normalisation if the run used it, then the clipped mean action).

    Build with `load_policy(path)`. `env_config` is the environment it was trained on."""

    def __init__(self, ckpt: dict, algorithm: type[Trainer], source: str = "checkpoint") -> None:
        from quadpilot.core.normalize import RunningMeanStd
        from quadpilot.core.observation import get_layout

        self.source = source
        self.algo = algorithm.algo
        try:  # `load_checkpoint` checked the entries; this builds them and checks that they fit
            # the algorithm's `policy_settings` (PPO: its ppo_config; SAC: raw observations, no history)
            self.config, self.normalize_obs, self.obs_history = algorithm.policy_settings(ckpt)
            self.env_config = EnvConfig.from_json(ckpt["env_config"])
            self.layout = get_layout(ckpt["obs_layout"]["name"])
        except (KeyError, TypeError, ValueError) as e:
            raise CheckpointError(f"{source}: {one_line(e)}") from None
        if self.layout.name != self.env_config.layout.name:
            raise CheckpointError(
                f"{source}: observation layout {self.layout.name!r} does not match its {self.env_config.task} "
                f"environment, which uses {self.env_config.layout.name!r}"
            )
        in_dim = history_dim(self.layout.dim, self.obs_history)  # the stacked input of a history policy
        try:
            self.model, self.config = algorithm.policy_network(ckpt, self.layout.dim, self.config)
        except (KeyError, TypeError, ValueError) as e:
            raise CheckpointError(f"{source}: its configuration does not describe a network ({one_line(e)})") from None
        try:
            self.model.load_state_dict(ckpt["model"])
        except (RuntimeError, KeyError, TypeError, ValueError) as e:
            raise CheckpointError(
                f"{source}: weights do not fit the network its config describes ({one_line(e)})"
            ) from None
        rms = ckpt["obs_rms"]
        if tuple(getattr(rms.get("mean"), "shape", ())) != (in_dim,):
            raise CheckpointError(f"{source}: obs_rms.mean is {short(rms.get('mean'))}; the network reads {in_dim}")
        self.obs_rms = RunningMeanStd((in_dim,))
        self.obs_rms.load_state_dict(rms_state(rms))
        self.global_step = int(ckpt["global_step"])
        self.extra = ckpt.get("extra", {})
        normalize = self.obs_rms.normalize if self.normalize_obs else lambda x: np.asarray(x, np.float32)
        self._act = DeterministicActor(self.model, normalize, self.layout.dim, self.obs_history)

    @property
    def recurrent(self) -> bool:
        """An LSTM policy (explicit h, c state; exports with h_in/c_in)."""
        return bool(getattr(self.model, "recurrent", False))

    @property
    def stateful(self) -> bool:
        """Keeps state between steps (an LSTM or an observation history): use initial_state/step."""
        return self.recurrent or self.obs_history > 1

    def _check(self, raw_obs: np.ndarray) -> np.ndarray:
        raw_obs = np.asarray(raw_obs, np.float32)
        if raw_obs.ndim != 2 or raw_obs.shape[1] != self.layout.dim:
            raise ValueError(f"observations must have shape (N, {self.layout.dim}), got {raw_obs.shape}")
        return raw_obs

    def network_input(self, raw_obs: np.ndarray) -> torch.Tensor:
        """The network's input for raw observations (N, obs_dim), normalised if the run normalised."""
        return self._act.network_input(self._check(raw_obs))

    def __call__(self, raw_obs: np.ndarray) -> np.ndarray:
        if self.stateful:
            raise TypeError(f"{self.source} is a recurrent or history policy: use initial_state() and step()")
        return self._act(self._check(raw_obs))

    def initial_state(self, n: int):
        """Start state for n drones (stateful policies): zero (h, c) for an LSTM, an empty history."""
        return self._act.initial_state(n)

    def step(self, raw_obs: np.ndarray, state):
        """One step of a stateful policy: (N, obs_dim) → actions (N, 4) in [−1, 1], new state."""
        return self._act.step(self._check(raw_obs), state)


def load_policy(path: str | os.PathLike, algorithms: dict) -> TrainedPolicy:
    """The deterministic policy in a checkpoint (policy.pt) of one of `algorithms` (the registry);
    CheckpointError if it cannot be used."""
    ckpt = load_checkpoint(path, algorithms)
    return TrainedPolicy(ckpt, algorithm_of(ckpt, algorithms), source=str(path))
