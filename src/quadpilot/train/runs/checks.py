"""The checks of the checkpoint format's values: every value a checkpoint file holds is read through
these (docs/architecture.md "Trust boundaries") before it reaches a network, a trainer or an
allocation.

`checkpoint_read.load_checkpoint` reads a file (`load_weights_only`) and checks each entry's type and
range with the functions below, and builds the configurations it describes; `check_fits` (called where the entries
are loaded into a trainer, `trainer.Trainer.load_state_dict`) checks that they fit what the
configuration built. A file that fails gets one CheckpointError naming the file, the entry and what
was expected; nothing in it is executed. `plain` is the other direction: what a trainer saves is made
of tensors and JSON-able data only, so `torch.load(weights_only=True)` reads it.
"""

from __future__ import annotations

import dataclasses
import math
import pickle
import types
import typing
import warnings
from typing import Any

import numpy as np
import torch

from quadpilot.modelfile.model import MAX_LAYERS  # a checkpoint is held to the depth a model file may have

SCHEMA = "quadpilot.checkpoint/1"
BIT_GENERATORS = ("PCG64", "PCG64DXSM", "Philox", "SFC64", "MT19937")


class CheckpointError(Exception):
    """A checkpoint file is missing, unreadable, truncated, or not one this version understands."""


def load_weights_only(path) -> Any:
    """`torch.load(path, weights_only=True)`: tensors and plain data only, so no code in the file
    runs. Whatever goes wrong becomes one CheckpointError reason: torch's own messages span lines,
    its warnings about the pickle protocol go to stderr, and when it meets a pickled object it
    advises loading with weights_only=False, which is the one thing never to do with a file from
    elsewhere."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        text = " ".join(str(e).split())
        if "weights only load failed" in text.lower():  # keep torch's finding, drop its boilerplate
            detail = text.partition("trusted source.")[2].partition("Please file an issue")[0].strip()
            raise CheckpointError(
                f"{path}: unreadable: not tensors and plain data, refused by torch's weights-only reader, "
                f"nothing in it was run{f' ({detail[:150]})' if detail else ''}"
            ) from None
        raise CheckpointError(f"{path}: unreadable (UnpicklingError: {text[:200]})") from None
    except Exception as e:  # torch raises many types for a bad zip, a short read, a bad record
        raise CheckpointError(f"{path}: unreadable ({type(e).__name__}: {' '.join(str(e).split())[:200]})") from None


# --- plain data -----------------------------------------------------------------------------


# QuadBatch arrays that hold the commanded heading of the episodes in flight (`core.mission`'s yaw
# rule), saved with the other episode arrays; absent from checkpoints written before the rule,
# whose episodes in flight then hold the heading they have at the resume.
HEADING_ARRAYS = ("heading", "yaw_rate_sum", "heading_err_sum")


def tensor(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.array(a, copy=True))


def plain(obj: Any) -> Any:
    """`obj` with NumPy scalars made Python numbers and arrays made tensors; raises TypeError on
    anything that `torch.load(weights_only=True)` would refuse."""
    if isinstance(obj, np.generic):  # before the float check: np.float64 is a float subclass
        return obj.item()
    if obj is None or isinstance(obj, (bool, int, float, str, torch.Tensor)):
        return obj
    if isinstance(obj, np.ndarray):
        return tensor(obj)
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


def rms_state(saved: dict) -> dict:
    """A checkpoint's "obs_rms" entry as RunningMeanStd.load_state_dict takes it (arrays, not tensors)."""
    return {k: v.numpy() if isinstance(v, torch.Tensor) else v for k, v in saved.items()}


# --- limits -------------------------------------------------------------------------------

MAX_FILE_BYTES = 1 << 30
"""A checkpoint of the default network is ~0.5 MB (policy.pt ~50 kB); refuse to unpickle a disk image."""
MAX_WIDTH = 4096
"""Widest hidden or LSTM layer a checkpoint may describe (the shipped ones are 64)."""
MAX_OBS_HISTORY = 64
MAX_BATCH = 1 << 24
"""Most transitions a configuration may hold in memory at once (num_envs × rollout_steps for
PPO, buffer_size for SAC); 2**24 × an 18-float observation is ~1.2 GB, half this machine's share."""
MAX_ENVS = 1 << 16
MAX_THREADS = 256
MAX_STRING = 1000
MAX_LIST = 1 << 20


def short(v: Any) -> str:
    """`v` for a message: its type, and its value if it is small."""
    if isinstance(v, torch.Tensor):
        return f"a {v.dtype} tensor of shape {tuple(v.shape)}"
    if v is None or isinstance(v, (bool, int, float)):
        text = repr(v)
        return text if len(text) <= 40 else text[:40] + "..."
    if isinstance(v, str):
        return repr(v if len(v) <= 40 else v[:40] + "...")
    return f"a {type(v).__name__}"


def type_name(tp: Any) -> str:
    if tp is type(None):
        return "None"
    if dataclasses.is_dataclass(tp):
        return f"a {tp.__name__} table"
    args = typing.get_args(tp)
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return " or ".join(type_name(a) for a in args)
    if typing.get_origin(tp) is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {type_name(args[0])}"
        return f"a list of {len(args)} {' and '.join(sorted({type_name(a) for a in args}))}"
    return {bool: "true/false", int: "an integer", float: "a finite number", str: "a string"}.get(tp, str(tp))


def check_type(tp: Any, v: Any, where: str) -> None:
    """Raise ValueError(where: expected …, found …) unless `v` (JSON-like data) is of type `tp`,
    a dataclass field annotation: bool, int, float (finite; an int is accepted), str, None, a
    union of these, tuple[X, ...] / tuple[X, Y, Z] (a list or tuple), or a dataclass (a dict of its
    fields, each checked the same way)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    ok = False
    if origin in (typing.Union, types.UnionType):
        for option in args:
            try:
                check_type(option, v, where)
                return
            except ValueError:
                continue
    elif dataclasses.is_dataclass(tp):
        if isinstance(v, dict):
            check_fields(tp, v, where)
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
                raise ValueError(f"{where}: expected {type_name(tp)}, found {len(v)} items")
            for k, (item_tp, x) in enumerate(items):
                check_type(item_tp, x, f"{where}[{k}]")
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
        raise ValueError(f"{where}: expected {type_name(tp)}, found {short(v)}")


def check_fields(cls: type, d: Any, where: str) -> None:
    """`d` is a dict of some of `cls`'s fields (a missing one takes its default, as in files
    written before the field existed), each of its annotated type."""
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected a {cls.__name__} table, found {short(d)}")
    hints = typing.get_type_hints(cls)
    unknown = [k for k in d if k not in hints]
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {[short(k) for k in unknown][:5]} for a {cls.__name__}")
    for k, v in d.items():
        check_type(hints[k], v, f"{where}.{k}")


def build_config(cls: type, d: Any, where: str):
    """`cls.from_json(d)` after checking the type of every field; ValueError naming the field."""
    check_fields(cls, d, where)
    try:
        return cls.from_json(d) if hasattr(cls, "from_json") else cls(**d)
    except (TypeError, ValueError, KeyError) as e:
        raise ValueError(f"{where}: {' '.join(str(e).split())[:300]}") from None


def check_sizes(cfg: Any, where: str) -> None:
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
    # what the trainer keeps: PPO's rollout, SAC's replay buffer
    held = getattr(cfg, "buffer_size", cfg.num_envs * cfg.rollout_steps)
    if held > MAX_BATCH:
        raise ValueError(f"{where}: holds {held:,} transitions in memory, more than {MAX_BATCH:,}")
    if not 1 <= cfg.threads <= MAX_THREADS:
        raise ValueError(f"{where}.threads: {cfg.threads} outside 1..{MAX_THREADS}")
    for name in ("total_steps", "minibatch_size", "epochs", "updates_per_step"):
        if hasattr(cfg, name) and not 1 <= getattr(cfg, name) < 2**62:
            raise ValueError(f"{where}.{name}: {getattr(cfg, name)}, expected ≥ 1")


def check_tensor(v: Any, where: str, *, shape: tuple | None = None, kind: str = "float", finite: bool = True):
    """`v` is a tensor of floating (kind "float"), integer or bool (kind "any") dtype, of `shape` if
    given, all finite if asked."""
    if not isinstance(v, torch.Tensor):
        raise ValueError(f"{where}: expected a tensor, found {short(v)}")
    if kind == "float" and not v.dtype.is_floating_point:
        raise ValueError(f"{where}: expected a floating-point tensor, found {short(v)}")
    if v.is_complex() or v.is_sparse or v.layout != torch.strided:
        raise ValueError(f"{where}: expected a dense real tensor, found {short(v)}")
    if shape is not None and tuple(v.shape) != tuple(shape):
        raise ValueError(f"{where}: expected shape {tuple(shape)}, found {tuple(v.shape)}")
    if finite and v.dtype.is_floating_point and not bool(torch.isfinite(v).all()):
        raise ValueError(f"{where}: holds NaN or infinite values")


def check_weights(d: Any, where: str) -> None:
    """A state_dict: names to finite floating-point tensors."""
    if not isinstance(d, dict) or not d:
        raise ValueError(f"{where}: expected a table of weight tensors, found {short(d)}")
    for k, v in d.items():
        if not isinstance(k, str):
            raise ValueError(f"{where}: weight names must be strings, found {short(k)}")
        check_tensor(v, f"{where}[{k!r}]")


def check_count(v: Any, where: str) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v < 2**63:
        raise ValueError(f"{where}: expected an integer ≥ 0, found {short(v)}")
    return v


def check_number(v: Any, where: str, lo: float = -math.inf, *, above: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < lo or (above and v == lo):
        bound = "" if lo == -math.inf else f" {'>' if above else '≥'} {lo:g}"
        raise ValueError(f"{where}: expected a finite number{bound}, found {short(v)}")
    return float(v)


def check_obs_rms(d: Any, where: str) -> None:
    if not isinstance(d, dict) or set(d) != {"mean", "var", "count", "clip"}:
        raise ValueError(f"{where}: expected a table of mean, var, count and clip, found {short(d)}")
    check_tensor(d["mean"], f"{where}.mean")
    check_tensor(d["var"], f"{where}.var", shape=tuple(d["mean"].shape))
    if d["mean"].ndim != 1 or bool((d["var"] < 0).any()):
        raise ValueError(f"{where}: expected one mean and one variance ≥ 0 per observation entry")
    check_number(d["count"], f"{where}.count", 0.0)
    check_number(d["clip"], f"{where}.clip", 0.0, above=True)


def check_extra(extra: Any, where: str) -> None:
    """The caller's free data; the entries quad-train and the montage read back are checked."""
    from ..envs.curriculum import CurriculumConfig

    if not isinstance(extra, dict):
        raise ValueError(f"{where}: expected a table, found {short(extra)}")
    if extra.get("preset") is not None and not isinstance(extra["preset"], str):
        raise ValueError(f"{where}.preset: expected a string, found {short(extra['preset'])}")
    if "elapsed_s" in extra:
        check_number(extra["elapsed_s"], f"{where}.elapsed_s", 0.0)
    for name in ("metrics", "first_success"):
        if extra.get(name) is not None and not isinstance(extra[name], dict):
            raise ValueError(f"{where}.{name}: expected a table, found {short(extra[name])}")
    metrics = extra.get("metrics") or {}
    if "update" in metrics:
        check_count(metrics["update"], f"{where}.metrics.update")
    cur = extra.get("curriculum")
    if cur is not None:
        if not isinstance(cur, dict):
            raise ValueError(f"{where}.curriculum: expected a table, found {short(cur)}")
        cfg = build_config(CurriculumConfig, cur.get("config"), f"{where}.curriculum.config")
        stage = check_count(cur.get("stage"), f"{where}.curriculum.stage")
        if stage >= len(cfg.radii):
            raise ValueError(f"{where}.curriculum.stage: {stage}, the curriculum has {len(cfg.radii)} stages")
        for name in ("updates_in_stage", "counted"):
            check_count(cur.get(name), f"{where}.curriculum.{name}")
        recent = cur.get("recent")
        if not isinstance(recent, list) or len(recent) > MAX_LIST or not all(isinstance(x, bool) for x in recent):
            raise ValueError(f"{where}.curriculum.recent: expected a list of true/false")


def check_trainer(tr: Any, where: str) -> None:
    if not isinstance(tr, dict):
        raise ValueError(f"{where}: expected a table, found {short(tr)}")
    if not tr:  # a deployable file (`ppo.checkpoint.policy_checkpoint_dict`, a snapshot): nothing to resume
        return
    check_count(tr.get("nonfinite_streak"), f"{where}.nonfinite_streak")
    for name, kind in (("ep_returns", float), ("ep_lengths", int), ("ep_success", bool)):
        values = tr.get(name)
        if not isinstance(values, list) or len(values) > MAX_LIST:
            raise ValueError(f"{where}.{name}: expected a list, found {short(values)}")
        for x in values:
            check_type(kind, x, f"{where}.{name}[]")
    check_tensor(tr.get("obs"), f"{where}.obs", finite=False)
    if tr.get("extra_state") is not None and not isinstance(tr["extra_state"], dict):
        raise ValueError(f"{where}.extra_state: expected a table, found {short(tr['extra_state'])}")


def check_like(ref: Any, got: Any, where: str) -> None:
    """`got` (from a file) has the structure of `ref` (the same entry of a trainer built with the
    checkpoint's configuration): the same keys, tensors of the same shape and kind, numbers where
    numbers are. Lists of numbers (episode logs) may differ in length."""
    if isinstance(ref, (torch.Tensor, np.ndarray)):
        if isinstance(got, np.ndarray):
            got = torch.from_numpy(got)
        ref_t = torch.as_tensor(ref)
        check_tensor(got, where, shape=tuple(ref_t.shape), kind="any", finite=False)
        if ref_t.dtype.is_floating_point != got.dtype.is_floating_point or (ref_t.dtype == torch.bool) != (
            got.dtype == torch.bool
        ):
            raise ValueError(f"{where}: expected a {ref_t.dtype} tensor, found {short(got)}")
    elif isinstance(ref, dict):
        if not isinstance(got, dict):
            raise ValueError(f"{where}: expected a table, found {short(got)}")
        missing, unknown = [k for k in ref if k not in got], [k for k in got if k not in ref]
        if missing or unknown:
            raise ValueError(f"{where}: missing {missing[:5]}, unexpected {[short(k) for k in unknown][:5]}")
        for k in ref:
            check_like(ref[k], got[k], f"{where}.{k}")
    elif isinstance(ref, (list, tuple)):
        if not isinstance(got, (list, tuple)):
            raise ValueError(f"{where}: expected a list, found {short(got)}")
        if len(ref) == len(got):
            for k, (a, b) in enumerate(zip(ref, got, strict=True)):
                check_like(a, b, f"{where}[{k}]")
        elif not all(isinstance(x, (bool, int, float)) for x in got):
            raise ValueError(f"{where}: expected {len(ref)} items, found {len(got)}")
    elif isinstance(ref, bool):
        check_type(bool, got, where)
    elif isinstance(ref, int):  # unbounded: a PCG64 state is a 128-bit integer
        if isinstance(got, bool) or not isinstance(got, int):
            raise ValueError(f"{where}: expected an integer, found {short(got)}")
    elif isinstance(ref, float):
        if isinstance(got, bool) or not isinstance(got, (int, float)):
            raise ValueError(f"{where}: expected a number, found {short(got)}")
    elif isinstance(ref, str):
        check_type(str, got, where)
    elif ref is None and got is not None:
        raise ValueError(f"{where}: expected nothing (None), found {short(got)}")


def check_optimizer(opt: Any, reference: torch.optim.Optimizer, where: str) -> None:
    """An Adam state_dict for `reference`'s parameters: the same groups and parameter indices,
    moment estimates shaped like their parameters and finite, a finite step count."""
    ref = reference.state_dict()
    if not isinstance(opt, dict) or set(opt) != {"state", "param_groups"}:
        raise ValueError(f"{where}: expected a table of state and param_groups, found {short(opt)}")
    groups = opt["param_groups"]
    if not isinstance(groups, list) or len(groups) != len(ref["param_groups"]):
        raise ValueError(f"{where}.param_groups: expected {len(ref['param_groups'])} groups")
    shapes = {}
    for k, (g, rg, params) in enumerate(zip(groups, ref["param_groups"], reference.param_groups, strict=True)):
        if not isinstance(g, dict) or set(g) != set(rg) or g["params"] != rg["params"]:
            raise ValueError(f"{where}.param_groups[{k}]: not the groups of this network's parameters")
        for name in ("lr", "eps", "weight_decay"):
            if name in g:
                check_number(g[name], f"{where}.param_groups[{k}].{name}", 0.0)
        shapes.update({i: tuple(p.shape) for i, p in zip(rg["params"], params["params"], strict=True)})
    state = opt["state"]
    if not isinstance(state, dict):
        raise ValueError(f"{where}.state: expected a table, found {short(state)}")
    for i, s in state.items():
        if i not in shapes or not isinstance(s, dict):
            raise ValueError(f"{where}.state: entry {short(i)} is not a parameter of this network")
        for name, v in s.items():
            shape = () if name == "step" else shapes[i]
            check_tensor(v, f"{where}.state[{i}].{name}", shape=shape)


def check_fits(agent: Any, reference: dict, ckpt: dict, source: str, optimizers: dict | None = None) -> None:
    """Before a checkpoint's training state is loaded into `agent` (built with its configuration):
    its trainer, environment and RNG entries have the structure of `reference` (the agent's own
    state as its checkpoint would hold it), its observation normaliser the network's input size, and
    each optimizer's state fits (`optimizers`: entry path → (state_dict from the file, optimizer)).
    Raises CheckpointError."""
    try:
        tr_ref = dict(reference["trainer"])
        if "extra_state" not in ckpt["trainer"]:
            tr_ref.pop("extra_state", None)  # files written before it existed: nothing extra to restore
        check_like(tr_ref, ckpt["trainer"], "trainer")
        env_ref = dict(reference["env"])
        if isinstance(ckpt["env"], dict) and not any(k in ckpt["env"] for k in HEADING_ARRAYS):
            for k in HEADING_ARRAYS:  # files written before the yaw rule: the heading is the one at the resume
                env_ref.pop(k, None)
        check_like(env_ref, ckpt["env"], "env")
        check_like(reference["rng"], ckpt["rng"], "rng")
        kind = ckpt["rng"]["env"].get("bit_generator")
        if kind not in BIT_GENERATORS:
            raise ValueError(f"rng.env: unknown numpy bit generator {short(kind)}; expected one of {BIT_GENERATORS}")
        for where, (state, opt) in (optimizers or {}).items():
            check_optimizer(state, opt, where)
        rms = getattr(agent, "obs_rms", None)
        if rms is not None:
            check_obs_rms(ckpt["obs_rms"], "obs_rms")
            if tuple(ckpt["obs_rms"]["mean"].shape) != tuple(rms.mean.shape):
                got = ckpt["obs_rms"]["mean"].shape
                raise ValueError(f"obs_rms: {tuple(got)} entries, the network reads {tuple(rms.mean.shape)}")
    except ValueError as e:
        raise CheckpointError(f"{source}: {e}") from None


def one_line(e: BaseException) -> str:
    """An exception as one short line for a message: its type and its first 200 characters."""
    return f"{type(e).__name__}: {' '.join(str(e).split())[:200]}"
