"""The trainer every algorithm is: what the run loop (`loop`) drives and what a checkpoint holds.

An algorithm (PPO and its recurrent variant in `train.ppo`, SAC in `train.sac`) is a
`Trainer` subclass. It builds its networks and optimisers in `__init__` (then `_start`), runs one
iteration in `iterate` (one metrics.csv row: collect, then update) and names its own checkpoint
entries in `own_state` / `load_own_state` / `own_optimizers`. The rest is here, once for every
algorithm: the vector environment and its random generators, the episode log and its summary, the
non-finite streak, and the training state in one layout, so that a checkpoint of any algorithm
holds the same entries (docs/architecture.md "Conventions": tensors and JSON-able data only):

    schema, algo    "quadpilot.checkpoint/1"; "ppo" or "sac" (a file without "algo" is PPO's)
    <algo>_config   the algorithm's configuration (PPOConfig, SACConfig), to_json()
    env_config      EnvConfig.to_json() (vehicle, randomisation and sensor noise written out)
    obs_layout      the observation layout, ObsLayout.to_json()
    model           the policy network's state_dict (PPO: the actor-critic; SAC: the actor)
    optimizer       the optimisers' states
    obs_rms         the observation normaliser (the identity where the algorithm has none)
    global_step, updates   environment steps and iterations so far
    trainer         the non-finite streak, recent episode returns/lengths/successes, the current raw
                    observation, and `extra_state`: the sensor-noise processes and what the
                    algorithm carries between iterations (LSTM states, the observation history)
    env             the vector environment mid-episode: its arrays, target radius, started flag and,
                    with domain randomisation, each drone's plant and disturbances
    rng             the environment's numpy generator, the trainer's torch.Generator, torch's default
    extra           the caller's JSON-able data (quad-train: curriculum, last metrics, elapsed time,
                    first_success, preset, command)

plus the algorithm's own entries (SAC: critic, critic_target, log_alpha, grad_steps, replay).
"""

from __future__ import annotations

import copy
import dataclasses
import os
import time
from pathlib import Path

import numpy as np
import torch

from quadpilot.atomic_files import atomic_write
from quadpilot.core.state import YAW

from ..envs import EnvConfig
from .checks import (
    BIT_GENERATORS,
    HEADING_ARRAYS,
    SCHEMA,
    CheckpointError,
    check_fits,
    one_line,
    plain,
    tensor,
)

LATEST = "checkpoint.pt"
PREVIOUS = "checkpoint.prev.pt"
# QuadBatch arrays that hold an episode in flight; restoring them lets a resumed run continue the
# very episodes the checkpoint interrupted instead of resetting every drone.
ENV_ARRAYS = ("state", "rotor", "target", "target_vel", "phase", "steps", "ep_return", "err_sum", "obs")


class NonFiniteError(RuntimeError):
    """Training met NaN/Inf too often to go on without poisoning the weights."""


class Trainer:
    """The part of a trainer every algorithm shares; see the module docstring."""

    algo = "ppo"
    """The name on the command line (--algo) and in the checkpoint ("algo")."""
    unit = "update"
    """What one iteration is called in messages (PPO: update; SAC: iteration)."""
    tag: str | None = None
    """Added to the run's labels and default directory (SAC: "sac"); None for our PPO."""
    default_preset: str | None = None
    """The --preset a fresh run takes without one (PPO: "fast"); None: the algorithm has no presets."""
    columns: tuple[str, ...] = ()
    """metrics.csv's header."""
    run_keys: tuple[str, ...] = ()
    """config.json's entries, in order (`loop.start_fresh` has their values)."""
    eval_keys: tuple[str, ...] = ()
    """eval.json's entries before the evaluation's own, in order (`loop.train`)."""
    required: tuple[str, ...] = ()
    """Checkpoint entries of this algorithm beyond the common ones (`checkpoint.load_checkpoint`)."""
    Config: type = object

    cfg: object
    env_cfg: EnvConfig

    @classmethod
    def config_key(cls) -> str:
        return f"{cls.algo}_config"

    def _start(self, env) -> None:
        """The common state of a fresh trainer; the environment is reset by `reseed`."""
        self.env = env
        self.global_step = 0
        self.updates = 0
        self._nonfinite_streak = 0
        self.ep_returns: list[float] = []
        self.ep_lengths: list[int] = []
        self.ep_success: list[bool] = []

    def reseed(self, seed: int) -> None:
        raw, _ = self.env.reset(seed=seed)
        self._obs = raw

    # --- what an algorithm provides ----------------------------------------------------------
    def iterate(self) -> dict[str, float]:
        """One iteration (a metrics row): collect, update; every metric under its fixed name."""
        raise NotImplementedError

    def own_state(self) -> dict:
        """The algorithm's checkpoint entries: model, optimizer, obs_rms and its own."""
        raise NotImplementedError

    def own_optimizers(self, ckpt: dict, source: str) -> dict:
        """Entry path → (optimizer state from `ckpt`, the optimizer it must fit), for `check_fits`."""
        raise NotImplementedError

    def load_own_state(self, ckpt: dict) -> None:
        """Put the algorithm's entries of `ckpt` back (weights and optimisers first, then numbers)."""
        raise NotImplementedError

    def plot_curves(self, metrics_path: Path, out_path: Path, title: str, radii: tuple[float, ...]) -> Path:
        raise NotImplementedError

    def run_entries(self) -> dict:
        """config.json's entries of the algorithm (its configuration under its name)."""
        return {self.algo: self.cfg.to_json()}

    # --- episodes and health -----------------------------------------------------------------
    def _record_episodes(self, infos: dict) -> None:
        """Returns, lengths and successes of the episodes that ended in this step."""
        ended = infos["_final_obs"]
        ep = infos["episode"]
        self.ep_returns.extend(ep["r"][ended].tolist())
        self.ep_lengths.extend(ep["l"][ended].tolist())
        self.ep_success.extend(ep["success"][ended].tolist())

    def _episode_metrics(self, n_before: int) -> dict[str, float]:
        """Mean return, length and success of the episodes this iteration ended (at most the last
        4·num_envs; NaN when none ended), and their count; then the log is cut to what the next
        report may need."""
        n = self.cfg.num_envs
        recent = slice(max(n_before, len(self.ep_returns) - 4 * n), None)
        ended_r, ended_l, ended_s = self.ep_returns[recent], self.ep_lengths[recent], self.ep_success[recent]
        out = {
            "ep_return": float(np.mean(ended_r)) if ended_r else float("nan"),
            "ep_length": float(np.mean(ended_l)) if ended_l else float("nan"),
            "success_rate": float(np.mean(ended_s)) if ended_s else float("nan"),
            "episodes": len(ended_r),
        }
        keep = 8 * n
        del self.ep_returns[:-keep], self.ep_lengths[:-keep], self.ep_success[:-keep]
        return out

    def _count_nonfinite(self, met: bool, what: str) -> None:
        """Track consecutive iterations that `met` NaN/Inf; at cfg.max_nonfinite_updates of them,
        NonFiniteError with `what` (the rest of the sentence after "N consecutive ")."""
        if not met:
            self._nonfinite_streak = 0
            return
        self._nonfinite_streak += 1
        if self._nonfinite_streak >= self.cfg.max_nonfinite_updates:
            raise NonFiniteError(f"{self._nonfinite_streak} consecutive {what}")

    # --- state between iterations ------------------------------------------------------------
    def extra_state(self) -> dict:
        """Trainer state beyond the networks', as arrays and plain data: the sensor-noise
        processes and the delay line (algorithms add what they carry between iterations)."""
        batch = self.env.batch
        out = {"noise": batch.noise.state_dict()} if batch.noise is not None else {}
        if batch.delay is not None:  # the commands and states on their way (core.timing)
            out["timing"] = batch.delay.state_dict()
        return out

    def load_extra_state(self, d: dict | None) -> None:
        """Put back what `extra_state` saved (a checkpoint without it leaves things as they are)."""
        d = d or {}
        if "timing" in d and self.env.batch.delay is not None:
            self.env.batch.delay.load_state_dict(d["timing"])
        if "noise" in d:
            from quadpilot.core.sensor_noise import SensorNoiseState

            batch = self.env.batch
            if batch.noise is None:
                batch.noise = SensorNoiseState(batch.noise_spec, batch.n, self.env_cfg.dt, np.random.default_rng(0))
            nd = d["noise"]
            batch.noise.load_state_dict(
                {"slow": np.asarray(nd["slow"]), "white": np.asarray(nd["white"]), "rng": nd["rng"]}
            )

    # --- checkpoints -------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Everything that changes while training, as tensors and plain data (copies, not views)."""
        batch = self.env.batch
        return {
            **self.own_state(),
            "global_step": int(self.global_step),
            "updates": int(self.updates),
            "trainer": {
                "nonfinite_streak": int(self._nonfinite_streak),
                "ep_returns": [float(x) for x in self.ep_returns],
                "ep_lengths": [int(x) for x in self.ep_lengths],
                "ep_success": [bool(x) for x in self.ep_success],
                "obs": tensor(self._obs),
                "extra_state": plain(self.extra_state()),
            },
            "env": {
                **{name: tensor(getattr(batch, name)) for name in ENV_ARRAYS + HEADING_ARRAYS},
                "target_radius": float(batch.target_radius),
                "started": bool(self.env.started),
                **_randomization_state(batch),
            },
            "rng": {
                "env": copy.deepcopy(self.env.rng.bit_generator.state),
                "torch_gen": self.torch_gen.get_state(),
                "torch_default": torch.get_rng_state(),
            },
        }

    def checkpoint_dict(self, extra: dict | None = None) -> dict:
        """The whole checkpoint (checkpoint.pt, policy.pt): see the module docstring."""
        return plain(
            {
                "schema": SCHEMA,
                "algo": self.algo,
                "created_unix": time.time(),
                self.config_key(): self.cfg.to_json(),
                "env_config": self.env_cfg.to_json(),
                "obs_layout": self.env_cfg.layout.to_json(),
                **self.state_dict(),
                "extra": dict(extra or {}),
            }
        )

    def policy_dict(self, extra: dict | None = None) -> dict:
        """A deployable file (a snapshot): the checkpoint without optimizer, trainer, environment or
        RNG state; it loads, exports and flies but cannot be resumed."""
        return {**self.checkpoint_dict(extra), "optimizer": {}, "trainer": {}, "env": {}, "rng": {}}

    def load_state_dict(self, ckpt: dict, source: str = "checkpoint") -> None:
        """Put a loaded checkpoint's state into this trainer, which must have been built with the
        same configuration. Raises CheckpointError if anything does not fit."""
        if not ckpt["trainer"] or not ckpt["env"] or not ckpt["rng"]:
            raise CheckpointError(
                f"{source}: holds a deployable policy only (no trainer, environment or RNG state); it cannot be resumed"
            )
        optimizers = self.own_optimizers(ckpt, source)
        reference = self.state_dict()
        env = ckpt["env"]
        mine = reference["env"].get("randomization")
        theirs = env.get("randomization") if isinstance(env, dict) else None
        if mine is not None and isinstance(theirs, dict) and isinstance(theirs.get("params"), dict):
            # plant fields the environment gained after the file was written stay nominal
            mine["params"] = {k: v for k, v in mine["params"].items() if k in theirs["params"]}
        check_fits(self, reference, ckpt, source, optimizers)  # shapes too
        batch = self.env.batch
        try:
            self.load_own_state(ckpt)
        except (RuntimeError, ValueError, KeyError) as e:
            raise CheckpointError(f"{source}: weights do not fit this trainer's networks ({one_line(e)})") from None
        try:  # checked above; what is left is what the trainer's own loaders refuse
            self.load_own_numbers(ckpt)
            self.global_step = int(ckpt["global_step"])
            self.updates = int(ckpt["updates"])
            tr = ckpt["trainer"]
            self._nonfinite_streak = int(tr["nonfinite_streak"])
            self.ep_returns = [float(x) for x in tr["ep_returns"]]
            self.ep_lengths = [int(x) for x in tr["ep_lengths"]]
            self.ep_success = [bool(x) for x in tr["ep_success"]]
            self._obs = tr["obs"].numpy().copy()
            self.load_extra_state(tr.get("extra_state"))
            for name in ENV_ARRAYS:
                setattr(batch, name, env[name].numpy().astype(getattr(batch, name).dtype, copy=True))
            if all(name in env for name in HEADING_ARRAYS):
                for name in HEADING_ARRAYS:
                    setattr(batch, name, env[name].numpy().astype(getattr(batch, name).dtype, copy=True))
            else:
                batch.heading[:] = batch.state[:, YAW]
            batch.target_radius = float(env["target_radius"])
            self.env.started = bool(env["started"])
            _load_randomization_state(batch, env, source)
            self._load_rng_state(ckpt["rng"], source)
        except (KeyError, TypeError, ValueError, RuntimeError, IndexError, AttributeError) as e:
            raise CheckpointError(f"{source}: training state does not fit this trainer ({one_line(e)})") from None

    def load_own_numbers(self, ckpt: dict) -> None:
        """The algorithm's checkpoint entries other than weights and optimisers (obs_rms, α, …)."""

    def _load_rng_state(self, rng: dict, source: str) -> None:
        kind = rng["env"].get("bit_generator")
        if kind not in BIT_GENERATORS:
            raise CheckpointError(f"{source}: unknown numpy bit generator {kind!r}; expected one of {BIT_GENERATORS}")
        bitgen = getattr(np.random, kind)()
        bitgen.state = rng["env"]
        self.env.rng = np.random.Generator(bitgen)
        self.torch_gen.set_state(rng["torch_gen"])
        torch.set_rng_state(rng["torch_default"])

    @classmethod
    def from_checkpoint(cls, ckpt: dict, cfg=None, source: str = "checkpoint", directory: Path | None = None):
        """A trainer rebuilt from a loaded checkpoint, ready to continue. `cfg` may replace the
        stored configuration (e.g. a longer total_steps); the network and batch shapes must still
        fit. `directory` holds the files beside the checkpoint (SAC's replay chunks)."""
        try:
            cfg = cfg or cls.Config.from_json(ckpt[cls.config_key()])
            agent = cls(cfg, EnvConfig.from_json(ckpt["env_config"]))
        except (KeyError, TypeError, ValueError) as e:
            raise CheckpointError(f"{source}: its configuration cannot build a trainer ({one_line(e)})") from None
        agent.load_state_dict(ckpt, source)
        agent.load_files(Path(directory) if directory is not None else None)
        return agent

    # --- files -------------------------------------------------------------------------------
    def save_for_resume(self, directory: str | os.PathLike, extra: dict | None = None) -> Path:
        """Write directory/checkpoint.pt atomically, first moving the current one to checkpoint.prev.pt."""
        data = self.checkpoint_dict(extra)
        return atomic_write(Path(directory) / LATEST, lambda f: torch.save(data, f), keep_previous=PREVIOUS)

    def load_files(self, directory: Path | None) -> None:
        """Read what the algorithm keeps beside its checkpoint (nothing but for SAC)."""

    @classmethod
    def clean_stale_files(cls, directory: Path) -> None:
        """Remove temporary files of the algorithm's own that a kill interrupted."""

    # --- what the run loop and the policy reader ask the algorithm -----------------------------
    @classmethod
    def preset_values(cls, preset: str | None) -> dict:
        """A fresh run's configuration values before its flags (`options.make_config`): `preset`'s."""
        return {}

    @classmethod
    def init_from(cls, path: str, explicit: dict, algorithms: dict) -> tuple[dict, dict]:
        """quad-train --init-from PATH: the checked policy file (read with the registry `algorithms`)
        and `explicit` with the file's network options. PPO's only (the CLI refuses it for the others)."""
        raise NotImplementedError

    def start_from(self, ckpt: dict, source: str) -> dict:
        """Put --init-from's policy (`init_from`) into this fresh trainer; what config.json records."""
        raise NotImplementedError

    @classmethod
    def policy_settings(cls, ckpt: dict) -> tuple[object, bool, int]:
        """How a checked policy file's network reads observations (`checkpoint.TrainedPolicy`): its
        configuration (None where `policy_network` reads it), whether observations are normalised,
        the observation history's length."""
        return None, False, 1

    @classmethod
    def policy_network(cls, ckpt: dict, obs_dim: int, cfg) -> tuple[torch.nn.Module, object]:
        """The deterministic policy's network of a checked policy file (eval mode, its weights not
        loaded yet) and its configuration; `cfg` is `policy_settings`'s."""
        raise NotImplementedError


def _randomization_state(batch) -> dict:
    """Domain randomisation in flight: each drone's plant and disturbances, so that a
    resumed run finishes its episodes on the plants they started with. Empty when off."""
    if batch.randomizer is None:
        return {}
    fields = {f.name: getattr(batch.params, f.name) for f in dataclasses.fields(batch.params)}
    params = {k: tensor(v) for k, v in fields.items() if isinstance(v, np.ndarray)}  # the per-drone ones
    r = {k: tensor(v) for k, v in batch.randomizer.state_dict().items()}
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
