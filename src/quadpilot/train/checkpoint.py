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
import os
import tempfile
import time
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
    """Domain randomisation in flight (issue 7): each drone's plant and disturbances, so that a
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
    built with the same configuration. Raises CheckpointError if the shapes do not fit."""
    batch = ppo.env.batch
    _check_env_shapes(batch, state["env"], source)
    try:
        ppo.model.load_state_dict(state["model"])
        ppo.opt.load_state_dict(state["optimizer"])
    except (RuntimeError, ValueError, KeyError) as e:
        raise CheckpointError(f"{source}: weights do not fit this network ({e})") from e
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
    cfg = cfg or PPOConfig.from_json(ckpt["ppo_config"])
    ppo = PPO(cfg, EnvConfig.from_json(ckpt["env_config"]))
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
    """Read and check a checkpoint with `torch.load(weights_only=True)`.

    Raises CheckpointError naming the file and what was expected if it is missing, truncated,
    not a torch file, not a quadpilot checkpoint, or of another schema version."""
    path = Path(path)
    expected = f"a quadpilot checkpoint (torch.save file, schema {SCHEMA!r})"
    if not path.is_file():
        raise CheckpointError(f"{path}: no such file; expected {expected}")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for a bad zip, a bad pickle, a short read
        reason = " ".join(str(e).split())[:200]
        raise CheckpointError(
            f"{path}: unreadable ({type(e).__name__}: {reason}); the file is truncated or corrupt, or not {expected}"
        ) from e
    if not isinstance(ckpt, dict) or "schema" not in ckpt:
        raise CheckpointError(f"{path}: holds a {type(ckpt).__name__} without a 'schema' key; expected {expected}")
    if ckpt["schema"] != SCHEMA:
        raise CheckpointError(f"{path}: schema {ckpt['schema']!r}; this version of quadpilot reads {SCHEMA!r}")
    algo = ckpt.get("algo", "ppo")
    if algo not in ("ppo", "sac"):
        raise CheckpointError(f"{path}: trained by {algo!r}; this version of quadpilot reads ppo and sac checkpoints")
    missing = [k for k in (SAC_REQUIRED if algo == "sac" else REQUIRED) if k not in ckpt]
    if missing:
        raise CheckpointError(f"{path}: schema {SCHEMA!r} but missing {missing}; the file is damaged")
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
        # PPO: ppo_config; SAC (quadpilot.train.sac): sac_config, raw observations, actor tanh(mean)
        self.ppo_config = PPOConfig.from_json(ckpt["ppo_config"]) if self.algo == "ppo" else None
        self.normalize_obs = bool(self.ppo_config.normalize_obs) if self.ppo_config is not None else False
        self.env_config = EnvConfig.from_json(ckpt["env_config"])
        try:
            self.layout = get_layout(ckpt["obs_layout"]["name"])
        except ValueError as e:
            raise CheckpointError(f"{source}: {e}") from None
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
        except ValueError as e:
            raise CheckpointError(f"{source}: {e}") from None
        try:
            self.model.load_state_dict(ckpt["model"])
        except (RuntimeError, KeyError) as e:
            raise CheckpointError(f"{source}: weights do not fit the network its config describes ({e})") from e
        self.obs_rms = RunningMeanStd((in_dim,))
        self.obs_rms.load_state_dict(_rms_state(ckpt["obs_rms"]))
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
