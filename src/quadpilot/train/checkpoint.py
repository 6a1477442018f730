"""Checkpoints: everything needed to resume training bit for bit, or to deploy the policy.

A checkpoint is a `torch.save` file holding tensors and JSON-able data only (dict, list, tuple, str,
int, float, bool, None), so `torch.load(path, weights_only=True)` reads it and no pickle of ours is
ever executed (DESIGN "Conventions"). Top-level keys:

    schema          "quadpilot.checkpoint/1"
    ppo_config      PPOConfig.to_json()
    env_config      EnvConfig.to_json() (the vehicle written out in full)
    obs_layout      the observation layout table, ObsLayout.to_json()
    model           ActorCritic state_dict (tensors)
    optimizer       Adam state_dict
    obs_rms         running mean/std of observations: {"mean", "var": float64 tensors, "count", "clip"}
    global_step     environment steps so far; updates: PPO updates so far
    trainer         PPO bookkeeping: non-finite streak, recent episode returns/lengths/successes,
                    the current raw observation
    env             the vector environment mid-episode: state arrays (tensors) and target radius
    rng             numpy Generator state of the environment (a dict of ints), torch.Generator
                    state and torch's default RNG state (uint8 tensors)
    extra           free JSON-able data from the caller; quad-train puts the curriculum state, the
                    last metrics, the elapsed time and the preset name here

`policy.pt` (the deployable file that quad-export reads) has the same format as `checkpoint.pt`.
Snapshots (`save_snapshot`, quad-train --snapshot-every) are `snapshots/policy-<steps>.pt`: the same
format with the weights and normaliser of that moment and no optimizer, trainer or environment
state (`policy_checkpoint_dict`), so each loads, exports and flies like policy.pt.

Writes are atomic: a temporary file in the same directory, flushed and fsync'd, then `os.replace`,
then the directory fsync'd, so a crash or `kill -9` leaves either the old file or the new one,
never half of one. For resuming, `save_for_resume` keeps two generations (`checkpoint.pt` and
`checkpoint.prev.pt`), and `load_for_resume` falls back to the older one if the newer is unreadable.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import tempfile
import time
import types
import typing
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import numpy as np
import torch

from .envs import EnvConfig
from .ppo import PPO, PPOConfig

SCHEMA = "quadpilot.checkpoint/1"
LATEST = "checkpoint.pt"
PREVIOUS = "checkpoint.prev.pt"
POLICY = "policy.pt"
SNAPSHOTS = "snapshots"

REQUIRED = (
    "schema",
    "ppo_config",
    "env_config",
    "obs_layout",
    "model",
    "optimizer",
    "obs_rms",
    "global_step",
    "updates",
    "trainer",
    "env",
    "rng",
    "extra",
)
# A SAC checkpoint (quadpilot.train.sac, "algo": "sac") holds the same environment, RNG and trainer
# entries, its actor under "model", and the critics, temperature and replay count beside them.
SAC_REQUIRED = (
    *(k for k in REQUIRED if k != "ppo_config"),
    "algo",
    "sac_config",
    "critic",
    "critic_target",
    "log_alpha",
    "replay",
)
# QuadBatch arrays that hold an episode in flight; restoring them lets a resumed run continue the
# very episodes the checkpoint interrupted instead of resetting every drone.
_ENV_ARRAYS = ("state", "rotor", "target", "target_vel", "phase", "steps", "ep_return", "err_sum", "obs")
_BIT_GENERATORS = ("PCG64", "PCG64DXSM", "Philox", "SFC64", "MT19937")


class CheckpointError(Exception):
    """A checkpoint file is missing, unreadable, truncated, or not one this version understands."""


# --- plain data -----------------------------------------------------------------------------


def _tensor(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.array(a, copy=True))


def plain(obj: Any) -> Any:
    """`obj` with NumPy scalars made Python numbers and arrays made tensors; raises TypeError on
    anything that `torch.load(weights_only=True)` would refuse."""
    if isinstance(obj, np.generic):  # before the float check: np.float64 is a float subclass
        return obj.item()
    if obj is None or isinstance(obj, (bool, int, float, str, torch.Tensor)):
        return obj
    if isinstance(obj, np.ndarray):
        return _tensor(obj)
    if isinstance(obj, dict):
        bad = [k for k in obj if not isinstance(k, (str, int))]
        if bad:
            raise TypeError(f"checkpoint dict keys must be str or int, got {bad!r}")
        return {k: plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(plain(v) for v in obj)
    raise TypeError(
        f"checkpoints hold tensors and JSON-able data only; got {type(obj).__name__}. Convert it to "
        "a dict/list/str/number first."
    )


def _rms_state(saved: dict) -> dict:
    """A checkpoint's "obs_rms" entry as RunningMeanStd.load_state_dict takes it (arrays, not tensors)."""
    return {k: v.numpy() if isinstance(v, torch.Tensor) else v for k, v in saved.items()}


# --- checking what a file holds ---------------------------------------------------------------
# Every value a checkpoint holds is read through the checks below (DESIGN "Trust boundaries"):
# `check_content` (called by `load_checkpoint`) checks each entry's type and range, and builds the
# configurations it describes; `check_fits` (called where the entries are loaded into a network
# or a trainer) checks that they fit what the configuration built. A file that fails gets one
# CheckpointError naming the file, the entry and what was expected; nothing in it is executed.

MAX_FILE_BYTES = 1 << 30
"""A checkpoint of the default network is ~0.5 MB (policy.pt ~50 kB); refuse to unpickle a disk image."""
MAX_WIDTH = 4096
"""Widest hidden or LSTM layer a checkpoint may describe (the shipped ones are 64)."""
MAX_LAYERS = 16
MAX_OBS_HISTORY = 64
MAX_BATCH = 1 << 24
"""Most transitions a configuration may hold in memory at once (num_envs × rollout_steps for
PPO, buffer_size for SAC); 2**24 × an 18-float observation is ~1.2 GB, half this machine's share."""
MAX_ENVS = 1 << 16
MAX_THREADS = 256
MAX_STRING = 1000
MAX_LIST = 1 << 20


def _short(v: Any) -> str:
    """`v` for a message: its type, and its value if it is small."""
    if isinstance(v, torch.Tensor):
        return f"a {v.dtype} tensor of shape {tuple(v.shape)}"
    if v is None or isinstance(v, (bool, int, float)):
        text = repr(v)
        return text if len(text) <= 40 else text[:40] + "..."
    if isinstance(v, str):
        return repr(v if len(v) <= 40 else v[:40] + "...")
    return f"a {type(v).__name__}"


def _type_name(tp: Any) -> str:
    if tp is type(None):
        return "None"
    if dataclasses.is_dataclass(tp):
        return f"a {tp.__name__} table"
    args = typing.get_args(tp)
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in args)
    if typing.get_origin(tp) is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_type_name(args[0])}"
        return f"a list of {len(args)} {' and '.join(sorted({_type_name(a) for a in args}))}"
    return {bool: "true/false", int: "an integer", float: "a finite number", str: "a string"}.get(tp, str(tp))


def _check_type(tp: Any, v: Any, where: str) -> None:
    """Raise ValueError(where: expected …, found …) unless `v` (JSON-like data) is of type `tp`,
    a dataclass field annotation: bool, int, float (finite; an int is accepted), str, None, a
    union of these, tuple[X, ...] / tuple[X, Y, Z] (a list or tuple), or a dataclass (a dict of its
    fields, each checked the same way)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    ok = False
    if origin in (typing.Union, types.UnionType):
        for option in args:
            try:
                _check_type(option, v, where)
                return
            except ValueError:
                continue
    elif dataclasses.is_dataclass(tp):
        if isinstance(v, dict):
            _check_fields(tp, v, where)
            return
    elif origin is tuple:
        if isinstance(v, (list, tuple)):
            if len(args) == 2 and args[1] is Ellipsis:
                if len(v) > MAX_LAYERS * 4:
                    raise ValueError(f"{where}: {len(v)} items, expected at most {MAX_LAYERS * 4}")
                items = [(args[0], x) for x in v]
            elif len(v) == len(args):
                items = list(zip(args, v, strict=True))
            else:
                raise ValueError(f"{where}: expected {_type_name(tp)}, found {len(v)} items")
            for k, (item_tp, x) in enumerate(items):
                _check_type(item_tp, x, f"{where}[{k}]")
            return
    elif tp is type(None):
        ok = v is None
    elif tp is bool:
        ok = isinstance(v, bool)
    elif tp is int:
        ok = isinstance(v, int) and not isinstance(v, bool) and abs(v) < 2**63
    elif tp is float:
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    elif tp is str:
        ok = isinstance(v, str) and len(v) <= MAX_STRING
    if not ok:
        raise ValueError(f"{where}: expected {_type_name(tp)}, found {_short(v)}")


def _check_fields(cls: type, d: Any, where: str) -> None:
    """`d` is a dict of some of `cls`'s fields (a missing one takes its default, as in files
    written before the field existed), each of its annotated type."""
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected a {cls.__name__} table, found {_short(d)}")
    hints = typing.get_type_hints(cls)
    unknown = [k for k in d if k not in hints]
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {[_short(k) for k in unknown][:5]} for a {cls.__name__}")
    for k, v in d.items():
        _check_type(hints[k], v, f"{where}.{k}")


def _config(cls: type, d: Any, where: str):
    """`cls.from_json(d)` after checking the type of every field; ValueError naming the field."""
    _check_fields(cls, d, where)
    try:
        return cls.from_json(d) if hasattr(cls, "from_json") else cls(**d)
    except (TypeError, ValueError, KeyError) as e:
        raise ValueError(f"{where}: {' '.join(str(e).split())[:300]}") from None


def _check_sizes(cfg: Any, where: str) -> None:
    """The sizes a network or a trainer is built with: refuse before allocating what no run of
    this project has (a crafted file could ask for terabytes)."""
    widths = [*cfg.actor_hidden, *cfg.critic_hidden, getattr(cfg, "lstm_hidden", 1)]
    if len(cfg.actor_hidden) > MAX_LAYERS or len(cfg.critic_hidden) > MAX_LAYERS:
        raise ValueError(f"{where}: more than {MAX_LAYERS} hidden layers")
    if not all(1 <= w <= MAX_WIDTH for w in widths):
        raise ValueError(f"{where}: layer widths {widths} outside 1..{MAX_WIDTH}")
    if not 1 <= getattr(cfg, "obs_history", 1) <= MAX_OBS_HISTORY:
        raise ValueError(f"{where}.obs_history: {cfg.obs_history} outside 1..{MAX_OBS_HISTORY}")
    if not 1 <= cfg.num_envs <= MAX_ENVS or not 1 <= cfg.rollout_steps <= MAX_BATCH:
        raise ValueError(
            f"{where}: num_envs {cfg.num_envs}, rollout_steps {cfg.rollout_steps}: expected 1..{MAX_ENVS} and "
            f"1..{MAX_BATCH}"
        )
    held = cfg.num_envs * cfg.rollout_steps if isinstance(cfg, PPOConfig) else cfg.buffer_size
    if held > MAX_BATCH:
        raise ValueError(f"{where}: holds {held:,} transitions in memory, more than {MAX_BATCH:,}")
    if not 1 <= cfg.threads <= MAX_THREADS:
        raise ValueError(f"{where}.threads: {cfg.threads} outside 1..{MAX_THREADS}")
    for name in ("total_steps", "minibatch_size", "epochs", "updates_per_step"):
        if hasattr(cfg, name) and not 1 <= getattr(cfg, name) < 2**62:
            raise ValueError(f"{where}.{name}: {getattr(cfg, name)}, expected ≥ 1")


def _check_tensor(v: Any, where: str, *, shape: tuple | None = None, kind: str = "float", finite: bool = True):
    """`v` is a tensor of floating (kind "float"), integer or bool (kind "any") dtype, of `shape` if
    given, all finite if asked."""
    if not isinstance(v, torch.Tensor):
        raise ValueError(f"{where}: expected a tensor, found {_short(v)}")
    if kind == "float" and not v.dtype.is_floating_point:
        raise ValueError(f"{where}: expected a floating-point tensor, found {_short(v)}")
    if v.is_complex() or v.is_sparse or v.layout != torch.strided:
        raise ValueError(f"{where}: expected a dense real tensor, found {_short(v)}")
    if shape is not None and tuple(v.shape) != tuple(shape):
        raise ValueError(f"{where}: expected shape {tuple(shape)}, found {tuple(v.shape)}")
    if finite and v.dtype.is_floating_point and not bool(torch.isfinite(v).all()):
        raise ValueError(f"{where}: holds NaN or infinite values")


def _check_weights(d: Any, where: str) -> None:
    """A state_dict: names to finite floating-point tensors."""
    if not isinstance(d, dict) or not d:
        raise ValueError(f"{where}: expected a table of weight tensors, found {_short(d)}")
    for k, v in d.items():
        if not isinstance(k, str):
            raise ValueError(f"{where}: weight names must be strings, found {_short(k)}")
        _check_tensor(v, f"{where}[{k!r}]")


def _check_count(v: Any, where: str) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v < 2**63:
        raise ValueError(f"{where}: expected an integer ≥ 0, found {_short(v)}")
    return v


def _check_number(v: Any, where: str, lo: float = -math.inf, *, above: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < lo or (above and v == lo):
        bound = "" if lo == -math.inf else f" {'>' if above else '≥'} {lo:g}"
        raise ValueError(f"{where}: expected a finite number{bound}, found {_short(v)}")
    return float(v)


def _check_obs_rms(d: Any, where: str) -> None:
    if not isinstance(d, dict) or set(d) != {"mean", "var", "count", "clip"}:
        raise ValueError(f"{where}: expected a table of mean, var, count and clip, found {_short(d)}")
    _check_tensor(d["mean"], f"{where}.mean")
    _check_tensor(d["var"], f"{where}.var", shape=tuple(d["mean"].shape))
    if d["mean"].ndim != 1 or bool((d["var"] < 0).any()):
        raise ValueError(f"{where}: expected one mean and one variance ≥ 0 per observation entry")
    _check_number(d["count"], f"{where}.count", 0.0)
    _check_number(d["clip"], f"{where}.clip", 0.0, above=True)


def _check_extra(extra: Any, where: str) -> None:
    """The caller's free data; the entries quad-train and the montage read back are checked."""
    from .curriculum import CurriculumConfig

    if not isinstance(extra, dict):
        raise ValueError(f"{where}: expected a table, found {_short(extra)}")
    if extra.get("preset") is not None and not isinstance(extra["preset"], str):
        raise ValueError(f"{where}.preset: expected a string, found {_short(extra['preset'])}")
    if "elapsed_s" in extra:
        _check_number(extra["elapsed_s"], f"{where}.elapsed_s", 0.0)
    for name in ("metrics", "first_success"):
        if extra.get(name) is not None and not isinstance(extra[name], dict):
            raise ValueError(f"{where}.{name}: expected a table, found {_short(extra[name])}")
    metrics = extra.get("metrics") or {}
    if "update" in metrics:
        _check_count(metrics["update"], f"{where}.metrics.update")
    cur = extra.get("curriculum")
    if cur is not None:
        if not isinstance(cur, dict):
            raise ValueError(f"{where}.curriculum: expected a table, found {_short(cur)}")
        cfg = _config(CurriculumConfig, cur.get("config"), f"{where}.curriculum.config")
        stage = _check_count(cur.get("stage"), f"{where}.curriculum.stage")
        if stage >= len(cfg.radii):
            raise ValueError(f"{where}.curriculum.stage: {stage}, the curriculum has {len(cfg.radii)} stages")
        for name in ("updates_in_stage", "counted"):
            _check_count(cur.get(name), f"{where}.curriculum.{name}")
        recent = cur.get("recent")
        if not isinstance(recent, list) or len(recent) > MAX_LIST or not all(isinstance(x, bool) for x in recent):
            raise ValueError(f"{where}.curriculum.recent: expected a list of true/false")


def _check_trainer(tr: Any, where: str) -> None:
    if not isinstance(tr, dict):
        raise ValueError(f"{where}: expected a table, found {_short(tr)}")
    if not tr:  # a deployable file (policy_checkpoint_dict): nothing to resume
        return
    _check_count(tr.get("nonfinite_streak"), f"{where}.nonfinite_streak")
    for name, kind in (("ep_returns", float), ("ep_lengths", int), ("ep_success", bool)):
        values = tr.get(name)
        if not isinstance(values, list) or len(values) > MAX_LIST:
            raise ValueError(f"{where}.{name}: expected a list, found {_short(values)}")
        for x in values:
            _check_type(kind, x, f"{where}.{name}[]")
    _check_tensor(tr.get("obs"), f"{where}.obs", finite=False)
    if tr.get("extra_state") is not None and not isinstance(tr["extra_state"], dict):
        raise ValueError(f"{where}.extra_state: expected a table, found {_short(tr['extra_state'])}")


def check_content(ckpt: dict, source: str) -> None:
    """Check every entry of a loaded checkpoint whose top-level keys are present (see
    `load_checkpoint`): types, ranges, finite weights, and that the configurations it holds can
    be built and describe networks and batches of a sane size. Raises CheckpointError."""
    from quadpilot.core.observation import get_layout

    algo = ckpt.get("algo", "ppo")
    try:
        if algo == "sac":
            from .sac import SACConfig

            cfg = _config(SACConfig, ckpt["sac_config"], "sac_config")
        else:
            cfg = _config(PPOConfig, ckpt["ppo_config"], "ppo_config")
        _check_sizes(cfg, "sac_config" if algo == "sac" else "ppo_config")
        env_cfg = _config(EnvConfig, ckpt["env_config"], "env_config")
        layout = ckpt["obs_layout"]
        if not isinstance(layout, dict) or not isinstance(layout.get("name"), str):
            raise ValueError(f"obs_layout: expected a table with a name, found {_short(layout)}")
        try:
            known = get_layout(layout["name"])
        except ValueError as e:
            raise ValueError(f"obs_layout: {e}") from None
        if known.name != env_cfg.layout.name:
            raise ValueError(
                f"obs_layout: {known.name!r} does not match its {env_cfg.task} environment, which uses "
                f"{env_cfg.layout.name!r}"
            )
        _check_weights(ckpt["model"], "model")
        if algo == "sac":
            _check_weights(ckpt["critic"], "critic")
            _check_weights(ckpt["critic_target"], "critic_target")
            _check_tensor(ckpt["log_alpha"], "log_alpha", shape=())
            replay = ckpt["replay"]
            if not isinstance(replay, dict) or replay.get("dir") != "replay":
                raise ValueError(f"replay: expected a table naming the replay directory, found {_short(replay)}")
            _check_count(replay.get("stored"), "replay.stored")
            _check_count(ckpt.get("grad_steps"), "grad_steps")
        _check_obs_rms(ckpt["obs_rms"], "obs_rms")
        _check_count(ckpt["global_step"], "global_step")
        _check_count(ckpt["updates"], "updates")
        for name in ("optimizer", "env", "rng"):
            if not isinstance(ckpt[name], dict):
                raise ValueError(f"{name}: expected a table, found {_short(ckpt[name])}")
        _check_trainer(ckpt["trainer"], "trainer")
        _check_extra(ckpt["extra"], "extra")
    except ValueError as e:
        raise CheckpointError(f"{source}: {e}") from None


def _check_like(ref: Any, got: Any, where: str) -> None:
    """`got` (from a file) has the structure of `ref` (the same entry of a trainer built with the
    checkpoint's configuration): the same keys, tensors of the same shape and kind, numbers where
    numbers are. Lists of numbers (episode logs) may differ in length."""
    if isinstance(ref, (torch.Tensor, np.ndarray)):
        if isinstance(got, np.ndarray):
            got = torch.from_numpy(got)
        ref_t = torch.as_tensor(ref)
        _check_tensor(got, where, shape=tuple(ref_t.shape), kind="any", finite=False)
        if ref_t.dtype.is_floating_point != got.dtype.is_floating_point or (ref_t.dtype == torch.bool) != (
            got.dtype == torch.bool
        ):
            raise ValueError(f"{where}: expected a {ref_t.dtype} tensor, found {_short(got)}")
    elif isinstance(ref, dict):
        if not isinstance(got, dict):
            raise ValueError(f"{where}: expected a table, found {_short(got)}")
        missing, unknown = [k for k in ref if k not in got], [k for k in got if k not in ref]
        if missing or unknown:
            raise ValueError(f"{where}: missing {missing[:5]}, unexpected {[_short(k) for k in unknown][:5]}")
        for k in ref:
            _check_like(ref[k], got[k], f"{where}.{k}")
    elif isinstance(ref, (list, tuple)):
        if not isinstance(got, (list, tuple)):
            raise ValueError(f"{where}: expected a list, found {_short(got)}")
        if len(ref) == len(got):
            for k, (a, b) in enumerate(zip(ref, got, strict=True)):
                _check_like(a, b, f"{where}[{k}]")
        elif not all(isinstance(x, (bool, int, float)) for x in got):
            raise ValueError(f"{where}: expected {len(ref)} items, found {len(got)}")
    elif isinstance(ref, bool):
        _check_type(bool, got, where)
    elif isinstance(ref, int):  # unbounded: a PCG64 state is a 128-bit integer
        if isinstance(got, bool) or not isinstance(got, int):
            raise ValueError(f"{where}: expected an integer, found {_short(got)}")
    elif isinstance(ref, float):
        if isinstance(got, bool) or not isinstance(got, (int, float)):
            raise ValueError(f"{where}: expected a number, found {_short(got)}")
    elif isinstance(ref, str):
        _check_type(str, got, where)
    elif ref is None and got is not None:
        raise ValueError(f"{where}: expected nothing (None), found {_short(got)}")


def _check_optimizer(opt: Any, reference: torch.optim.Optimizer, where: str) -> None:
    """An Adam state_dict for `reference`'s parameters: the same groups and parameter indices,
    moment estimates shaped like their parameters and finite, a finite step count."""
    ref = reference.state_dict()
    if not isinstance(opt, dict) or set(opt) != {"state", "param_groups"}:
        raise ValueError(f"{where}: expected a table of state and param_groups, found {_short(opt)}")
    groups = opt["param_groups"]
    if not isinstance(groups, list) or len(groups) != len(ref["param_groups"]):
        raise ValueError(f"{where}.param_groups: expected {len(ref['param_groups'])} groups")
    shapes = {}
    for k, (g, rg, params) in enumerate(zip(groups, ref["param_groups"], reference.param_groups, strict=True)):
        if not isinstance(g, dict) or set(g) != set(rg) or g["params"] != rg["params"]:
            raise ValueError(f"{where}.param_groups[{k}]: not the groups of this network's parameters")
        for name in ("lr", "eps", "weight_decay"):
            if name in g:
                _check_number(g[name], f"{where}.param_groups[{k}].{name}", 0.0)
        shapes.update({i: tuple(p.shape) for i, p in zip(rg["params"], params["params"], strict=True)})
    state = opt["state"]
    if not isinstance(state, dict):
        raise ValueError(f"{where}.state: expected a table, found {_short(state)}")
    for i, s in state.items():
        if i not in shapes or not isinstance(s, dict):
            raise ValueError(f"{where}.state: entry {_short(i)} is not a parameter of this network")
        for name, v in s.items():
            shape = () if name == "step" else shapes[i]
            _check_tensor(v, f"{where}.state[{i}].{name}", shape=shape)


def check_fits(agent: Any, reference: dict, ckpt: dict, source: str, optimizers: dict | None = None) -> None:
    """Before a checkpoint's training state is loaded into `agent` (built with its configuration):
    its trainer, environment and RNG entries have the structure of `reference` (the agent's own
    state as its checkpoint would hold it), its observation normaliser the network's input size, and
    each optimizer's state fits (`optimizers`: entry path → (state_dict from the file, optimizer)).
    Raises CheckpointError."""
    try:
        if not ckpt["trainer"] or not ckpt["env"] or not ckpt["rng"]:
            raise ValueError(
                "holds a deployable policy only (no trainer, environment or RNG state); it cannot be resumed"
            )
        tr_ref = dict(reference["trainer"])
        if "extra_state" not in ckpt["trainer"]:
            tr_ref.pop("extra_state", None)  # files written before it existed: nothing extra to restore
        _check_like(tr_ref, ckpt["trainer"], "trainer")
        _check_like(reference["env"], ckpt["env"], "env")
        _check_like(reference["rng"], ckpt["rng"], "rng")
        kind = ckpt["rng"]["env"].get("bit_generator")
        if kind not in _BIT_GENERATORS:
            raise ValueError(f"rng.env: unknown numpy bit generator {_short(kind)}; expected one of {_BIT_GENERATORS}")
        for where, (state, opt) in (optimizers or {}).items():
            _check_optimizer(state, opt, where)
        rms = getattr(agent, "obs_rms", None)
        if rms is not None:
            _check_obs_rms(ckpt["obs_rms"], "obs_rms")
            if tuple(ckpt["obs_rms"]["mean"].shape) != tuple(rms.mean.shape):
                got = ckpt["obs_rms"]["mean"].shape
                raise ValueError(f"obs_rms: {tuple(got)} entries, the network reads {tuple(rms.mean.shape)}")
    except ValueError as e:
        raise CheckpointError(f"{source}: {e}") from None


# --- PPO state ------------------------------------------------------------------------------


def ppo_state_dict(ppo: PPO) -> dict:
    """Everything that changes while `ppo` trains, as tensors and plain data (copies, not views)."""
    batch = ppo.env.batch
    rms = ppo.obs_rms
    return {
        "model": {k: v.detach().clone() for k, v in ppo.model.state_dict().items()},
        "optimizer": copy.deepcopy(ppo.opt.state_dict()),
        "obs_rms": {"mean": _tensor(rms.mean), "var": _tensor(rms.var), "count": rms.count, "clip": rms.clip},
        "global_step": int(ppo.global_step),
        "updates": int(ppo.updates),
        "trainer": {
            "nonfinite_streak": int(ppo._nonfinite_streak),
            "ep_returns": [float(x) for x in ppo.ep_returns],
            "ep_lengths": [int(x) for x in ppo.ep_lengths],
            "ep_success": [bool(x) for x in ppo.ep_success],
            "obs": _tensor(ppo._obs),
            "extra_state": plain(ppo.extra_state()),  # LSTM states, observation history, sensor noise
        },
        "env": {
            **{name: _tensor(getattr(batch, name)) for name in _ENV_ARRAYS},
            "target_radius": float(batch.target_radius),
            "started": bool(ppo.env._started),
            **_randomization_state(batch),
        },
        "rng": {
            "env": copy.deepcopy(ppo.env._rng.bit_generator.state),
            "torch_gen": ppo.torch_gen.get_state(),
            "torch_default": torch.get_rng_state(),
        },
    }


def _randomization_state(batch) -> dict:
    """Domain randomisation in flight: each drone's plant and disturbances, so that a
    resumed run finishes its episodes on the plants they started with. Empty when off."""
    if batch.randomizer is None:
        return {}
    params = {f.name: _tensor(getattr(batch.params, f.name)) for f in dataclasses.fields(batch.params)}
    del params["gravity"]
    r = {k: _tensor(v) for k, v in batch.randomizer.state_dict().items()}
    return {"randomization": {"params": params, **r}}


def _load_randomization_state(batch, env: dict, source: str) -> None:
    if batch.randomizer is None:
        return
    if "randomization" not in env:
        raise CheckpointError(f"{source}: the run randomises its plants but the checkpoint holds none of them")
    saved = env["randomization"]
    try:
        params = {k: v.numpy().astype(batch.dtype) for k, v in saved["params"].items()}
        batch.params = dataclasses.replace(batch.params, **params)
        batch.randomizer.load_state_dict({k: v.numpy() for k, v in saved.items() if k != "params"})
    except (KeyError, TypeError, ValueError) as e:
        raise CheckpointError(f"{source}: randomised plants do not fit this environment ({e})") from e


def _check_env_shapes(batch, env: dict, source: str) -> None:
    """Raise CheckpointError if a checkpoint's environment arrays do not fit `batch`."""
    for name in _ENV_ARRAYS:
        want, got = getattr(batch, name), env[name]
        if tuple(got.shape) != want.shape:
            raise CheckpointError(
                f"{source}: environment array {name!r} has shape {tuple(got.shape)}, this trainer expects "
                f"{want.shape}; was it saved with a different num_envs or task?"
            )


def _load_episode_state(agent, tr: dict) -> None:
    """A checkpoint's "trainer" entries that PPO and SAC share into `agent`."""
    agent._nonfinite_streak = int(tr["nonfinite_streak"])
    agent.ep_returns = [float(x) for x in tr["ep_returns"]]
    agent.ep_lengths = [int(x) for x in tr["ep_lengths"]]
    agent.ep_success = [bool(x) for x in tr["ep_success"]]
    agent._obs = tr["obs"].numpy().copy()


def _load_env_state(agent, env: dict) -> None:
    """A checkpoint's environment arrays, target radius and started flag into `agent.env`."""
    batch = agent.env.batch
    for name in _ENV_ARRAYS:
        setattr(batch, name, env[name].numpy().astype(getattr(batch, name).dtype, copy=True))
    batch.target_radius = float(env["target_radius"])
    agent.env._started = bool(env["started"])


def _load_rng_state(agent, rng: dict, source: str) -> None:
    """A checkpoint's random generators (environment numpy, trainer and default torch) into
    `agent` and torch. Raises CheckpointError on an unknown numpy bit generator."""
    kind = rng["env"].get("bit_generator")
    if kind not in _BIT_GENERATORS:
        raise CheckpointError(f"{source}: unknown numpy bit generator {kind!r}; expected one of {_BIT_GENERATORS}")
    bitgen = getattr(np.random, kind)()
    bitgen.state = rng["env"]
    agent.env._rng = np.random.Generator(bitgen)
    agent.torch_gen.set_state(rng["torch_gen"])
    torch.set_rng_state(rng["torch_default"])


def load_ppo_state(ppo: PPO, state: dict, source: str = "checkpoint") -> None:
    """Put `state` (from `ppo_state_dict` or a loaded checkpoint) into `ppo`, which must have been
    built with the same configuration. Raises CheckpointError if anything does not fit."""
    check_fits(ppo, ppo_state_dict(ppo), state, source, {"optimizer": (state["optimizer"], ppo.opt)})
    batch = ppo.env.batch
    _check_env_shapes(batch, state["env"], source)
    try:
        ppo.model.load_state_dict(state["model"])
        ppo.opt.load_state_dict(state["optimizer"])
    except (RuntimeError, ValueError, KeyError) as e:
        raise CheckpointError(f"{source}: weights do not fit this network ({_one_line(e)})") from None
    try:  # checked above; what is left is what the trainer's own loaders refuse
        rms = ppo.obs_rms
        rms.load_state_dict(_rms_state(state["obs_rms"]))
        ppo.global_step = int(state["global_step"])
        ppo.updates = int(state["updates"])
        tr = state["trainer"]
        _load_episode_state(ppo, tr)
        ppo.load_extra_state(tr.get("extra_state"))
        _load_env_state(ppo, state["env"])
        _load_randomization_state(batch, state["env"], source)
        _load_rng_state(ppo, state["rng"], source)
    except (KeyError, TypeError, ValueError, RuntimeError, IndexError, AttributeError) as e:
        raise CheckpointError(f"{source}: training state does not fit this trainer ({_one_line(e)})") from None


def _one_line(e: BaseException) -> str:
    """An exception as one short line for a message: its type and its first 200 characters."""
    return f"{type(e).__name__}: {' '.join(str(e).split())[:200]}"


def checkpoint_dict(ppo: PPO, extra: dict | None = None) -> dict:
    """The full checkpoint content for `ppo` (see the module docstring)."""
    return plain(
        {
            "schema": SCHEMA,
            "created_unix": time.time(),
            "ppo_config": ppo.cfg.to_json(),
            "env_config": ppo.env_cfg.to_json(),
            "obs_layout": ppo.env_cfg.layout.to_json(),
            **ppo_state_dict(ppo),
            "extra": dict(extra or {}),
        }
    )


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
    from .networks import build_actor_critic

    torch.manual_seed(seed)
    model = build_actor_critic(env_cfg.layout.dim, 4, ppo_cfg)
    head = model.actor_head if getattr(model, "recurrent", False) else model.actor[-1]
    torch.nn.init.orthogonal_(head.weight, head_gain)
    data = policy_checkpoint_dict(model, ppo_cfg, env_cfg)
    return atomic_write(path, lambda f: torch.save(data, f))


def ppo_from_checkpoint(ckpt: dict, cfg: PPOConfig | None = None, source: str = "checkpoint") -> PPO:
    """A PPO trainer rebuilt from a loaded checkpoint, ready to continue. `cfg` may replace the
    stored PPOConfig (e.g. a longer total_steps); the network and batch shapes must still fit."""
    try:
        cfg = cfg or PPOConfig.from_json(ckpt["ppo_config"])
        ppo = PPO(cfg, EnvConfig.from_json(ckpt["env_config"]))
    except (KeyError, TypeError, ValueError) as e:
        raise CheckpointError(f"{source}: its configuration cannot build a trainer ({_one_line(e)})") from None
    load_ppo_state(ppo, ckpt, source)
    return ppo


# --- files ----------------------------------------------------------------------------------


def _fsync_dir(directory: Path) -> None:
    """Make a rename durable: fsync the directory entry (POSIX; Windows cannot open directories)."""
    if os.name == "nt":
        return
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write(path: str | os.PathLike, write: Callable[[IO[bytes]], None], keep_previous: str | None = None) -> Path:
    """Write `path` atomically: `write(f)` into a temporary file beside it, flush, fsync,
    optionally move the current file to `keep_previous` (a name in the same directory), then
    `os.replace` the temporary file onto `path` and fsync the directory.

    A crash leaves the old `path`, or (between the two renames) only `keep_previous`; never a torn
    file. A leftover `.<name>.*.tmp` is harmless and may be deleted."""
    path = Path(path)
    directory = path.parent
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        if keep_previous is not None and path.exists():
            os.replace(path, directory / keep_previous)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(directory)
    return path


def save_checkpoint(
    path: str | os.PathLike, ppo: PPO, extra: dict | None = None, keep_previous: str | None = None
) -> Path:
    """Write `ppo` (and the JSON-able `extra`) to `path` atomically; see `atomic_write`."""
    data = checkpoint_dict(ppo, extra)
    return atomic_write(path, lambda f: torch.save(data, f), keep_previous)


def load_checkpoint(path: str | os.PathLike) -> dict:
    """Read and check a checkpoint with `torch.load(weights_only=True)` (no code in the file runs).

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
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for a bad zip, a bad pickle, a short read
        reason = " ".join(str(e).split())[:200]
        raise CheckpointError(
            f"{path}: unreadable ({type(e).__name__}: {reason}); the file is truncated or corrupt, or not {expected}"
        ) from None
    if not isinstance(ckpt, dict) or "schema" not in ckpt:
        raise CheckpointError(f"{path}: holds a {type(ckpt).__name__} without a 'schema' key; expected {expected}")
    if not isinstance(ckpt["schema"], str) or ckpt["schema"] != SCHEMA:
        raise CheckpointError(f"{path}: schema {_short(ckpt['schema'])}; this version of quadpilot reads {SCHEMA!r}")
    algo = ckpt.get("algo", "ppo")
    if not isinstance(algo, str) or algo not in ("ppo", "sac"):
        raise CheckpointError(
            f"{path}: trained by {_short(algo)}; this version of quadpilot reads ppo and sac checkpoints"
        )
    missing = [k for k in (SAC_REQUIRED if algo == "sac" else REQUIRED) if k not in ckpt]
    if missing:
        raise CheckpointError(f"{path}: schema {SCHEMA!r} but missing {missing}; the file is damaged")
    check_content(ckpt, str(path))
    return ckpt


def save_for_resume(directory: str | os.PathLike, ppo: PPO, extra: dict | None = None) -> Path:
    """Write `directory/checkpoint.pt`, first moving the current one to `checkpoint.prev.pt`."""
    return save_checkpoint(Path(directory) / LATEST, ppo, extra, keep_previous=PREVIOUS)


def has_checkpoint(directory: str | os.PathLike) -> bool:
    d = Path(directory)
    return (d / LATEST).exists() or (d / PREVIOUS).exists()


def load_for_resume(directory: str | os.PathLike) -> tuple[dict, Path, str | None]:
    """The newest readable checkpoint in `directory`: (checkpoint, its path, warning or None).

    Tries `checkpoint.pt`, then `checkpoint.prev.pt`; the warning says why the newer one was
    skipped. Raises CheckpointError with both reasons if neither can be read."""
    d = Path(directory)
    try:
        return load_checkpoint(d / LATEST), d / LATEST, None
    except CheckpointError as latest_error:
        try:
            ckpt = load_checkpoint(d / PREVIOUS)
        except CheckpointError as prev_error:
            raise CheckpointError(f"no usable checkpoint in {d}: {latest_error}; and {prev_error}") from None
        warning = f"{latest_error}; resuming from the previous checkpoint {d / PREVIOUS} instead"
        return ckpt, d / PREVIOUS, warning


def snapshot_path(directory: str | os.PathLike, global_step: int) -> Path:
    """`directory/snapshots/policy-<global_step>.pt`."""
    return Path(directory) / SNAPSHOTS / f"policy-{int(global_step)}.pt"


def save_snapshot(directory: str | os.PathLike, ppo: PPO, extra: dict | None = None) -> Path:
    """Write the policy `ppo` has now to `snapshot_path(directory, ppo.global_step)` atomically
    (a small deployable file, see `policy_checkpoint_dict`); the same step overwrites the same file."""
    path = snapshot_path(directory, ppo.global_step)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = policy_checkpoint_dict(
        ppo.model, ppo.cfg, ppo.env_cfg, ppo.global_step, obs_rms=ppo.obs_rms, updates=ppo.updates, extra=extra or {}
    )
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

    def __init__(self, ckpt: dict, source: str = "checkpoint") -> None:
        from quadpilot.core.normalize import RunningMeanStd
        from quadpilot.core.observation import get_layout

        from .history import network_input_dim
        from .networks import build_actor_critic

        self.source = source
        self.algo = ckpt.get("algo", "ppo")
        try:  # `load_checkpoint` checked the entries; this builds them and checks that they fit
            # PPO: ppo_config; SAC (quadpilot.train.sac): sac_config, raw observations, actor tanh(mean)
            self.ppo_config = PPOConfig.from_json(ckpt["ppo_config"]) if self.algo == "ppo" else None
            self.normalize_obs = bool(self.ppo_config.normalize_obs) if self.ppo_config is not None else False
            self.env_config = EnvConfig.from_json(ckpt["env_config"])
            self.layout = get_layout(ckpt["obs_layout"]["name"])
        except (KeyError, TypeError, ValueError) as e:
            raise CheckpointError(f"{source}: {_one_line(e)}") from None
        if self.layout.name != self.env_config.layout.name:
            raise CheckpointError(
                f"{source}: observation layout {self.layout.name!r} does not match its {self.env_config.task} "
                f"environment, which uses {self.env_config.layout.name!r}"
            )
        c = self.ppo_config
        self.obs_history = int(c.obs_history) if c is not None else 1
        in_dim = network_input_dim(self.layout.dim, c)  # the stacked input of a history policy
        try:
            self.model = build_actor_critic(in_dim, 4, c).eval() if c is not None else self._sac_actor(ckpt)
        except (KeyError, TypeError, ValueError) as e:
            raise CheckpointError(f"{source}: its configuration does not describe a network ({_one_line(e)})") from None
        try:
            self.model.load_state_dict(ckpt["model"])
        except (RuntimeError, KeyError, TypeError, ValueError) as e:
            raise CheckpointError(
                f"{source}: weights do not fit the network its config describes ({_one_line(e)})"
            ) from None
        rms = ckpt["obs_rms"]
        if tuple(getattr(rms.get("mean"), "shape", ())) != (in_dim,):
            raise CheckpointError(f"{source}: obs_rms.mean is {_short(rms.get('mean'))}; the network reads {in_dim}")
        self.obs_rms = RunningMeanStd((in_dim,))
        self.obs_rms.load_state_dict(_rms_state(rms))
        self.global_step = int(ckpt["global_step"])
        self.extra = ckpt.get("extra", {})

    def _sac_actor(self, ckpt: dict):
        from .sac import SACConfig, build_actor

        self.sac_config = SACConfig.from_json(ckpt["sac_config"])
        return build_actor(self.layout.dim, self.sac_config).eval()

    @property
    def recurrent(self) -> bool:
        """An LSTM policy (explicit h, c state; exports with h_in/c_in)."""
        return bool(getattr(self.model, "recurrent", False))

    @property
    def stateful(self) -> bool:
        """Keeps state between steps (an LSTM or an observation history): use initial_state/step."""
        return self.recurrent or self.obs_history > 1

    def _actor(self):
        from .recurrent_ppo import DeterministicActor

        normalize = self.obs_rms.normalize if self.normalize_obs else lambda x: np.asarray(x, np.float32)
        return DeterministicActor(self.model, normalize, self.layout.dim, self.obs_history)

    def _check(self, raw_obs: np.ndarray) -> None:
        if raw_obs.ndim != 2 or raw_obs.shape[1] != self.layout.dim:
            raise ValueError(f"observations must have shape (N, {self.layout.dim}), got {raw_obs.shape}")

    def _input(self, raw_obs: np.ndarray) -> torch.Tensor:
        raw_obs = np.asarray(raw_obs, np.float32)
        self._check(raw_obs)
        x = self.obs_rms.normalize(raw_obs) if self.normalize_obs else raw_obs
        return torch.from_numpy(np.ascontiguousarray(x, np.float32))

    @torch.inference_mode()
    def __call__(self, raw_obs: np.ndarray) -> np.ndarray:
        if self.stateful:
            raise TypeError(f"{self.source} is a recurrent or history policy: use initial_state() and step()")
        return self.model.mean_action(self._input(raw_obs)).numpy()

    def initial_state(self, n: int):
        """Start state for n drones (stateful policies): zero (h, c) for an LSTM, an empty history."""
        if self.recurrent:
            return self.model.initial_state(n)
        return self._actor().initial_state(n)

    @torch.inference_mode()
    def step(self, raw_obs: np.ndarray, state):
        """One step of a stateful policy: (N, obs_dim) → actions (N, 4) in [−1, 1], new state."""
        if self.recurrent:
            action, state = self.model.mean_action_step(self._input(raw_obs), state)
            return action.numpy(), state
        self._check(raw_obs)
        return self._actor().step(np.asarray(raw_obs, np.float32), state)


def load_policy(path: str | os.PathLike) -> TrainedPolicy:
    """The deterministic policy in a checkpoint (policy.pt); CheckpointError if it cannot be used."""
    return TrainedPolicy(load_checkpoint(path), source=str(path))
