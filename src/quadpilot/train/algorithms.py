"""The algorithms quad-train trains and a checkpoint may hold, by name (quad-train --algo, a
checkpoint's "algo" entry; a file without one is PPO's)."""

from __future__ import annotations

from .ppo import PPO
from .runs.trainer import Trainer
from .sac import SAC

ALGORITHMS: dict[str, type[Trainer]] = {"ppo": PPO, "sac": SAC}
