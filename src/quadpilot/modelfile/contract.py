"""What every part of the runtime shares about a policy file: the error a bad file raises, the
checked description of the file (`ModelInfo`, made by `model.read_model`), the motor count of the
schema, and how text from a file is quoted in a one-line message.

A small module of its own so that the reader (`model`), the graph check (`graph`), the network
description (`network`) and the backends all import it and none of them imports another in a circle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from quadpilot.core.observation import ObsLayout
from quadpilot.core.params import NUM_MOTORS as NUM_MOTORS  # the schema's motor count is the project's one
from quadpilot.core.params import VehicleParams


class ModelContractError(ValueError):
    """The file is not a policy this runtime may fly; the message says why."""


@dataclass(frozen=True)
class ModelInfo:
    """What the file's metadata says about the policy inside it (every value checked)."""

    path: str
    layout: ObsLayout
    """This runtime's own layout of that name (the file's fields were compared with it)."""
    task: str
    """One of `core.mission.TASKS`."""
    control_period_s: float
    vehicle: VehicleParams
    training_steps: int
    source_sha256: str
    """64 lowercase hex digits."""
    action_meaning: str
    """Equal to `model.ACTION_MEANING`."""
    architecture: dict
    """kind (mlp or lstm), layers and their initializer names, normalisation, action mapping:
    checked, numbers as floats, and matched against the graph (`graph.check_graph`)."""
    envelope: dict
    """max_distance_m and max_tilt_deg (floats): the states the policy was trained in (beyond them
    it never learned to act; training episodes ended there)."""
    golden_obs: np.ndarray
    """(K, obs_dim) float32, finite, a sequence from zero recurrent state."""
    golden_action: np.ndarray
    """(K, 4) float32, finite, what the exporting torch module answered."""

    @property
    def obs_dim(self) -> int:
        return self.layout.dim

    @property
    def recurrent(self) -> bool:
        return self.architecture["kind"] == "lstm"

    @property
    def hidden(self) -> int:
        return int(self.architecture.get("hidden", 0))

    def input_names(self) -> tuple[str, ...]:
        return ("obs", "h_in", "c_in") if self.recurrent else ("obs",)

    def output_names(self) -> tuple[str, ...]:
        return ("action", "h_out", "c_out") if self.recurrent else ("action",)


def fail(path, what: str) -> ModelContractError:
    return ModelContractError(f"{path}: {what}")


def quote(text, limit: int = 60) -> str:
    """A file's string for a message: repr (one line, escapes shown), cut to `limit` characters."""
    text = str(text)
    return repr(text if len(text) <= limit else text[:limit] + "...")


def one_line(text, limit: int = 300) -> str:
    """An exception's message for ours: one line, at most `limit` characters."""
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[:limit] + "..."
