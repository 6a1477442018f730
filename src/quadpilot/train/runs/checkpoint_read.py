"""Reading a checkpoint file: loaded with torch's weights-only reader and every entry checked, in
this one module (`load_checkpoint`, `check_content`), with the value checks of `checks`, before
anything is built from it (`checkpoint.trainer_from_checkpoint`, `checkpoint.load_policy`).

It knows no algorithm: the caller hands it the registry (`train.algorithms.ALGORITHMS`, name →
`Trainer` class), whose classes name their configuration and entries and check their own."""

from __future__ import annotations

import os
from pathlib import Path

from ..envs import EnvConfig
from .checks import (
    MAX_FILE_BYTES,
    SCHEMA,
    CheckpointError,
    build_config,
    check_count,
    check_extra,
    check_obs_rms,
    check_sizes,
    check_trainer,
    check_weights,
    load_weights_only,
    short,
)

REQUIRED = (
    *("schema", "env_config", "obs_layout", "model", "optimizer", "obs_rms", "global_step", "updates"),
    *("trainer", "env", "rng", "extra"),
)
"""The entries of every checkpoint, with the algorithm's configuration and `Trainer.required`."""


DEFAULT_ALGO = "ppo"
"""The algorithm of a checkpoint without an "algo" entry (written before SAC existed)."""


def algorithm_of(ckpt: dict, algorithms: dict):
    """The trainer class, in the registry `algorithms`, of a checkpoint `load_checkpoint` checked."""
    return algorithms[ckpt.get("algo", DEFAULT_ALGO)]


def load_checkpoint(path: str | os.PathLike, algorithms: dict) -> dict:
    """Read and check a checkpoint of one of `algorithms` (the registry) with
    `torch.load(weights_only=True)` (no code in the file runs).

    Raises CheckpointError naming the file and what was wrong if it is missing, too large,
    truncated, not a torch file, not a quadpilot checkpoint, of another schema version, or if any
    entry fails `check_content`."""
    path = Path(path)
    expected = f"a quadpilot checkpoint (torch.save file, schema {SCHEMA!r})"
    if not path.is_file():
        raise CheckpointError(f"{path}: no such file; expected {expected}")
    try:
        size = path.stat().st_size
    except OSError as e:
        raise CheckpointError(f"{path}: cannot read it ({e.strerror or e})") from None
    if size > MAX_FILE_BYTES:
        raise CheckpointError(f"{path}: {size:,} bytes; a checkpoint is at most {MAX_FILE_BYTES:,}")
    try:
        ckpt = load_weights_only(path)
    except CheckpointError as e:
        raise CheckpointError(f"{e}; expected {expected}") from None
    if not isinstance(ckpt, dict) or "schema" not in ckpt:
        raise CheckpointError(f"{path}: holds a {type(ckpt).__name__} without a 'schema' key; expected {expected}")
    if not isinstance(ckpt["schema"], str) or ckpt["schema"] != SCHEMA:
        raise CheckpointError(f"{path}: schema {short(ckpt['schema'])}; this version of quadpilot reads {SCHEMA!r}")
    algo = ckpt.get("algo", DEFAULT_ALGO)
    if not isinstance(algo, str) or algo not in algorithms:
        raise CheckpointError(
            f"{path}: trained by {short(algo)}; this version of quadpilot reads {' and '.join(algorithms)} checkpoints"
        )
    cls = algorithm_of(ckpt, algorithms)
    missing = [k for k in (*REQUIRED, cls.config_key(), *cls.required) if k not in ckpt]
    if missing:
        raise CheckpointError(f"{path}: schema {SCHEMA!r} but missing {missing}; the file is damaged")
    check_content(ckpt, str(path), cls)
    return ckpt


def check_content(ckpt: dict, source: str, algo: type) -> None:
    """Check every entry of a loaded checkpoint whose top-level keys are present (see
    `load_checkpoint`; `algo` is its algorithm's Trainer class): types, ranges, finite weights,
    and that the configurations it holds can be built and describe networks and batches of a sane
    size. Raises CheckpointError."""
    from quadpilot.core.observation import get_layout

    key = algo.config_key()
    try:
        cfg = build_config(algo.Config, ckpt[key], key)
        check_sizes(cfg, key)
        env_cfg = build_config(EnvConfig, ckpt["env_config"], "env_config")
        layout = ckpt["obs_layout"]
        if not isinstance(layout, dict) or not isinstance(layout.get("name"), str):
            raise ValueError(f"obs_layout: expected a table with a name, found {short(layout)}")
        try:
            known = get_layout(layout["name"])
        except ValueError as e:
            raise ValueError(f"obs_layout: {e}") from None
        if known.name != env_cfg.layout.name:
            raise ValueError(
                f"obs_layout: {known.name!r} does not match its {env_cfg.task} environment, which uses "
                f"{env_cfg.layout.name!r}"
            )
        check_weights(ckpt["model"], "model")
        if hasattr(algo, "check_entries"):
            algo.check_entries(ckpt)
        check_obs_rms(ckpt["obs_rms"], "obs_rms")
        check_count(ckpt["global_step"], "global_step")
        check_count(ckpt["updates"], "updates")
        for name in ("optimizer", "env", "rng"):
            if not isinstance(ckpt[name], dict):
                raise ValueError(f"{name}: expected a table, found {short(ckpt[name])}")
        check_trainer(ckpt["trainer"], "trainer")
        check_extra(ckpt["extra"], "extra")
    except ValueError as e:
        raise CheckpointError(f"{source}: {e}") from None
