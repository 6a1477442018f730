"""The reference policies that ship inside the package (models/ of the repository, installed as
package data under `quadpilot/models/`), so that `pip install .` alone can fly one.

    shipped_models()      -> {name: ShippedModel}, every folder that holds a policy.onnx
    shipped_policy("hover_px4_sih")  -> the path of its policy.onnx (policy.tar for a policy of PX4
                                        mc_raptor's contract), or ValueError naming the choices

What each model was trained for is read from its own files: the task, vehicle and architecture from
the ONNX metadata (`model.read_model`, the same checks as every file this runtime flies) and the
success rate from the `eval.json` that quad-train wrote beside it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from quadpilot.modelfile.model import read_model

DEFAULT_MODEL = "hover"


def models_dir() -> Path:
    """Where the shipped models are: inside the installed package (a source checkout's editable
    install reaches the repository's models/ through the same name)."""
    return Path(str(resources.files("quadpilot") / "models")).resolve()


@dataclass(frozen=True)
class ShippedModel:
    name: str
    path: Path
    """Its policy.tar (a policy of PX4 mc_raptor's contract, `runtime.raptor`) if it has one, else its
    policy.onnx."""

    def describe(self) -> str:
        """One line: task, vehicle, architecture and what its own evaluation measured."""
        if self.path.suffix == ".tar":
            from .raptor import load_raptor

            info = load_raptor(self.path).info
            text = f"{info.task} on {info.vehicle.name} ({info.vehicle.mass:g} kg), gru for PX4 mc_raptor (policy.tar)"
        else:
            _, info = read_model(self.path)
            arch = info.architecture["kind"]
            text = (
                f"{info.task} on {info.vehicle.name} ({info.vehicle.mass:g} kg), {arch}, {info.training_steps:,} steps"
            )
        try:
            ev = json.loads((self.path.parent / "eval.json").read_text(encoding="utf-8"))
            text += f"; its evaluation: {100 * float(ev['success_rate']):.0f} % of {int(ev['episodes'])} episodes"
        except (OSError, ValueError, KeyError, TypeError):
            pass  # a folder without its evaluation still flies; the listing just says less
        return text


def shipped_models() -> dict[str, ShippedModel]:
    root = models_dir()
    if not root.is_dir():
        return {}
    models = {}
    for d in sorted(root.iterdir()):
        for name in ("policy.tar", "policy.onnx"):
            if d.is_dir() and (d / name).is_file():
                models[d.name] = ShippedModel(d.name, d / name)
                break
    return models


def shipped_policy(name: str | None = None) -> Path:
    """The policy file of the shipped model `name` (None: the default, hover); ValueError in one line
    when there is none."""
    name = DEFAULT_MODEL if name is None else name
    models = shipped_models()
    if name not in models:
        known = ", ".join(models) or "none (this installation carries no models)"
        raise ValueError(f"--model {name!r}: no shipped model of that name; expected one of {known}")
    return models[name].path


def listing() -> list[str]:
    """quad-sitl --list-models: one line a model (a damaged one says why), then how to fly one."""
    models = shipped_models()
    if not models:
        return ["quad-sitl: this installation carries no shipped models"]
    width = max(map(len, models))
    lines = []
    for name, model in models.items():
        try:
            what = model.describe()
        except ValueError as e:  # a damaged installation (ModelContractError among them): say so and go on
            what = f"unusable: {e}"
        lines.append(f"{name:<{width}}  {what}" + ("  (default)" if name == DEFAULT_MODEL else ""))
    return [*lines, "fly one with: quad-sitl --model NAME"]
