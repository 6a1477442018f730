"""The algorithms quad-train trains and a checkpoint may hold, by name (quad-train --algo, a
checkpoint's "algo" entry; a file without one is PPO's), and the checkpoint readers that need to
know them all.

`runs` knows no algorithm: its readers take this registry as an argument. These are the same
readers with the registry given, for everything above `train` (export, studies, benchmarks,
tests) and the command line."""

from __future__ import annotations

import os
from pathlib import Path

from .ppo import PPO
from .runs import checkpoint, checkpoint_read
from .runs.checks import CheckpointError
from .runs.trainer import Trainer
from .sac import SAC

__all__ = [
    "ALGORITHMS",
    "CheckpointError",
    "load_checkpoint",
    "load_for_resume",
    "load_policy",
    "load_trainer",
    "trained_policy",
]

ALGORITHMS: dict[str, type[Trainer]] = {"ppo": PPO, "sac": SAC}


def load_checkpoint(path: str | os.PathLike) -> dict:
    """A checkpoint file read and every entry checked (`runs.checkpoint_read.load_checkpoint`)."""
    return checkpoint_read.load_checkpoint(path, ALGORITHMS)


def load_policy(path: str | os.PathLike) -> checkpoint.TrainedPolicy:
    """The deterministic policy in a checkpoint (policy.pt); CheckpointError if it cannot be used."""
    return checkpoint.load_policy(path, ALGORITHMS)


def trained_policy(ckpt: dict, source: str = "checkpoint") -> checkpoint.TrainedPolicy:
    """The deterministic policy of a loaded, checked checkpoint (`load_checkpoint`)."""
    return checkpoint.TrainedPolicy(ckpt, checkpoint_read.algorithm_of(ckpt, ALGORITHMS), source)


def load_trainer(path: str | os.PathLike) -> Trainer:
    """The trainer of a checkpoint file, ready to continue, with what lies beside it (SAC's replay)."""
    return checkpoint.load_trainer(path, ALGORITHMS)


def load_for_resume(directory: str | os.PathLike) -> tuple[dict, Path, str | None]:
    """The newest readable checkpoint of a run directory (`runs.checkpoint.load_for_resume`)."""
    return checkpoint.load_for_resume(directory, ALGORITHMS)
