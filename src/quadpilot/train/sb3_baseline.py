"""Stable-Baselines3 PPO on our environment with settings matched to a `PPOConfig`: the comparison
baseline (`quad-train --algo sb3`). Our PPO never imports this module.

What is shared with our PPO is the environment and nothing else: the registered vector env
(`gymnasium.make_vec("quadpilot/<Task>-v0", vectorization_mode="vector_entry_point")`, one NumPy
call per step for all drones, as our PPO steps it) is handed to SB3 through `QuadSB3VecEnv`, an
adapter to SB3's VecEnv API that reports time-limit truncations the way SB3 reads them
(`infos[i]["TimeLimit.truncated"]` and `infos[i]["terminal_observation"]`), so SB3 bootstraps on
truncation as ours does (SB3 ≥ 2.0, `OnPolicyAlgorithm.collect_rollouts`, stable-baselines3 GitHub issue #633).

`sb3_settings(cfg)` maps every `PPOConfig` field to SB3
(`quadpilot.studies.matched_settings.FIELD_MAP` says how, or why it cannot be matched exactly; a
test fails when PPOConfig gains a field that is not in it). SB3's algorithm runs unmodified:
`_TimedPPO` only times `collect_rollouts` and `train` and hands each update's logged values to our
metrics.csv. The trained policy is judged by our `evaluate` (same episodes, same success
definition), through `deterministic_policy`. Files are tensors and NumPy/JSON only:
`sb3_policy.pt` (the policy's state_dict, loads with `weights_only=True`) and `obs_norm.npz`
(VecNormalize's statistics, loads with `allow_pickle=False`); SB3's own `save` and VecNormalize's
`save` pickle, so they are not used.
"""

from __future__ import annotations

import dataclasses
import io
import math
import time
import types
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO as SB3PPO
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecNormalize

from quadpilot.atomic_files import atomic_write

from .envs import EnvConfig, QuadVectorEnv
from .ppo import PPOConfig

POLICY_FILE = "sb3_policy.pt"
OBS_NORM_FILE = "obs_norm.npz"
ENV_IDS = {"hover": "quadpilot/Hover-v0", "waypoint": "quadpilot/Waypoint-v0", "circle": "quadpilot/Circle-v0"}
ACTIVATIONS = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU, "elu": torch.nn.ELU}

# --- the matched settings -------------------------------------------------------------------


class MatchedLR:
    """SB3 learning-rate schedule that reproduces ours exactly: update k (1-based) of K uses
    lr·(1 − (k − 1)/K) (linear) or lr (constant). SB3 calls a schedule with progress_remaining =
    1 − num_timesteps/total_timesteps, evaluated after the k-th rollout (num_timesteps = k·batch)."""

    def __init__(self, lr: float, schedule: str, total_steps: int, batch: int) -> None:
        if schedule not in ("constant", "linear"):
            raise ValueError(f"lr_schedule must be 'constant' or 'linear', got {schedule!r}")
        self.lr, self.schedule, self.total, self.batch = float(lr), schedule, int(total_steps), int(batch)
        self.num_updates = max(1, math.ceil(self.total / self.batch))

    def __call__(self, progress_remaining: float) -> float:
        if self.schedule == "constant":
            return self.lr
        k = round((1.0 - progress_remaining) * self.total / self.batch)  # rollouts collected so far
        return self.lr * min(1.0, max(0.0, 1.0 - (k - 1) / self.num_updates))


def sb3_settings(cfg: PPOConfig) -> dict[str, Any]:
    """The SB3 configuration matched to `cfg`, JSON-able (saved in config.json as "sb3")."""
    if cfg.arch != "mlp" or cfg.obs_history != 1:
        raise ValueError(
            f"the SB3 baseline matches arch='mlp' with obs_history=1 only, got {cfg.arch!r}, {cfg.obs_history}"
        )
    if cfg.activation not in ACTIVATIONS:
        raise ValueError(f"unknown activation {cfg.activation!r}; expected one of {sorted(ACTIVATIONS)}")
    return {
        "policy": "MlpPolicy",
        "n_envs": cfg.num_envs,
        "total_timesteps": cfg.total_steps,
        "seed": cfg.seed,
        "threads": cfg.threads,
        "reward_scale": cfg.reward_scale,
        "learning_rate": {"initial": cfg.lr, "schedule": cfg.lr_schedule},
        "vec_normalize": {"norm_obs": cfg.normalize_obs, "norm_reward": False, "clip_obs": 10.0, "epsilon": 1e-8},
        "ppo": {
            "n_steps": cfg.rollout_steps,
            "batch_size": cfg.minibatch_size,
            "n_epochs": cfg.epochs,
            "gamma": cfg.gamma,
            "gae_lambda": cfg.lam,
            "clip_range": cfg.clip_eps,
            "clip_range_vf": cfg.clip_eps if cfg.clip_value else None,
            "normalize_advantage": cfg.normalize_adv,
            "ent_coef": cfg.ent_coef,
            "vf_coef": cfg.vf_coef / 2.0,
            "max_grad_norm": cfg.max_grad_norm,
            "target_kl": None if cfg.target_kl is None else cfg.target_kl / 1.5,
        },
        "policy_kwargs": {
            "net_arch": {"pi": list(cfg.actor_hidden), "vf": list(cfg.critic_hidden)},
            "activation_fn": cfg.activation,
            "log_std_init": cfg.init_log_std,
            "ortho_init": True,
        },
    }


def _policy_kwargs(s: dict) -> dict:
    pk = dict(s["policy_kwargs"])
    pk["activation_fn"] = ACTIVATIONS[pk["activation_fn"]]
    pk["net_arch"] = {k: list(v) for k, v in pk["net_arch"].items()}
    return pk


# --- the environment ------------------------------------------------------------------------


class QuadSB3VecEnv(VecEnv):
    """Our registered vector env (`QuadVectorEnv`, one NumPy call per step) behind SB3's VecEnv API.

    SB3 auto-resets too: `step` returns the reset observation of an ended drone, with its last
    observation in `infos[i]["terminal_observation"]`, `infos[i]["TimeLimit.truncated"]` for a
    time-limit end (never set together with a crash), `infos[i]["episode"]` (unscaled return r,
    length l) and `infos[i]["is_success"]` (our success definition). Episodes that ended since
    `take_episodes()` are kept for our metrics, and the time inside the env's own step is summed in
    `env_s`."""

    def __init__(self, env: QuadVectorEnv) -> None:
        self.env = env
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)
        self._actions: np.ndarray | None = None
        self.env_s = 0.0
        self._ended: list[tuple[float, int, bool]] = []

    def reset(self):
        seed = self._seeds[0]
        obs, _ = self.env.reset(seed=seed)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        t = time.perf_counter()
        obs, reward, term, trunc, info = self.env.step(self._actions)
        self.env_s += time.perf_counter() - t
        done = term | trunc
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        if done.any():
            final, ep = info["final_obs"], info["episode"]
            for i in np.flatnonzero(done):
                r, n, ok = float(ep["r"][i]), int(ep["l"][i]), bool(ep["success"][i])
                infos[i] = {
                    "terminal_observation": final[i],
                    "TimeLimit.truncated": bool(trunc[i]),
                    "episode": {"r": r, "l": n},
                    "is_success": ok,
                }
                self._ended.append((r, n, ok))
        return obs, reward, done, infos

    def take_episodes(self) -> list[tuple[float, int, bool]]:
        """(return, length, success) of the episodes ended since the last call."""
        out, self._ended = self._ended, []
        return out

    def close(self) -> None:
        self.env.close()

    # SB3 asks these of every VecEnv; one batched env has no per-env objects to forward them to.
    def get_attr(self, attr_name, indices=None):
        return [getattr(self.env, attr_name)] * len(list(self._get_indices(indices)))

    def set_attr(self, attr_name, value, indices=None):
        setattr(self.env, attr_name, value)

    def env_method(self, method_name, *args, indices=None, **kwargs):
        return [getattr(self.env, method_name)(*args, **kwargs)]

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False] * len(list(self._get_indices(indices)))


class ScaleReward(VecEnvWrapper):
    """Rewards × `scale` before PPO sees them, as our PPO multiplies them before GAE."""

    def __init__(self, venv: VecEnv, scale: float) -> None:
        super().__init__(venv)
        self.scale = float(scale)

    def reset(self):
        return self.venv.reset()

    def step_wait(self):
        obs, reward, done, infos = self.venv.step_wait()
        return obs, reward * self.scale, done, infos


def make_env(s: dict, env_cfg: EnvConfig) -> tuple[VecEnv, QuadSB3VecEnv, VecNormalize | None]:
    """(the VecEnv SB3 trains on, the adapter inside it, the VecNormalize or None)."""
    import quadpilot.train  # noqa: F401  (registers the environments)

    raw = gym.make_vec(
        ENV_IDS[env_cfg.task], num_envs=s["n_envs"], vectorization_mode="vector_entry_point", config=env_cfg
    )
    if not isinstance(raw.unwrapped, QuadVectorEnv):
        raise TypeError(f"expected the registered QuadVectorEnv, got {type(raw.unwrapped).__name__}")
    adapter = QuadSB3VecEnv(raw.unwrapped)
    venv: VecEnv = ScaleReward(adapter, s["reward_scale"])
    vn = s["vec_normalize"]
    norm = None
    if vn["norm_obs"]:
        norm = VecNormalize(
            venv,
            training=True,
            norm_obs=True,
            norm_reward=vn["norm_reward"],
            clip_obs=vn["clip_obs"],
            epsilon=vn["epsilon"],
            gamma=s["ppo"]["gamma"],
        )
        venv = norm
    return venv, adapter, norm


# --- observation statistics without pickle -------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ObsNorm:
    """VecNormalize's observation statistics as plain arrays: (x − mean)/√(var + epsilon),
    clipped to ±clip_obs; the identity when `enabled` is False."""

    mean: np.ndarray
    var: np.ndarray
    count: float
    clip_obs: float
    epsilon: float
    enabled: bool

    @classmethod
    def identity(cls, obs_dim: int) -> ObsNorm:
        return cls(np.zeros(obs_dim), np.ones(obs_dim), 0.0, 10.0, 1e-8, False)

    @classmethod
    def from_vec_normalize(cls, vn: VecNormalize) -> ObsNorm:
        rms = vn.obs_rms
        return cls(rms.mean.copy(), rms.var.copy(), float(rms.count), float(vn.clip_obs), float(vn.epsilon), True)

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        if not self.enabled:
            return np.asarray(obs, np.float32)
        return np.clip((obs - self.mean) / np.sqrt(self.var + self.epsilon), -self.clip_obs, self.clip_obs).astype(
            np.float32
        )

    def save(self, path: str | Path) -> Path:
        buf = io.BytesIO()
        np.savez(
            buf,
            mean=np.asarray(self.mean, np.float64),
            var=np.asarray(self.var, np.float64),
            count=np.float64(self.count),
            clip_obs=np.float64(self.clip_obs),
            epsilon=np.float64(self.epsilon),
            enabled=np.bool_(self.enabled),
        )
        return atomic_write(path, lambda f: f.write(buf.getvalue()))

    @classmethod
    def load(cls, path: str | Path) -> ObsNorm:
        with np.load(path, allow_pickle=False) as z:
            return cls(
                z["mean"].copy(),
                z["var"].copy(),
                float(z["count"]),
                float(z["clip_obs"]),
                float(z["epsilon"]),
                bool(z["enabled"]),
            )


# --- policies -------------------------------------------------------------------------------


def deterministic_policy(policy: ActorCriticPolicy, obs_norm: ObsNorm) -> Callable[[np.ndarray], np.ndarray]:
    """SB3's deterministic action (its `predict`, clipped to the action box) for raw observations
    (N, obs_dim): the callable our `evaluate` takes."""

    def act(raw: np.ndarray) -> np.ndarray:
        action, _ = policy.predict(obs_norm.normalize(raw), deterministic=True)
        return action

    return act


def load_policy(run_dir: str | Path) -> Callable[[np.ndarray], np.ndarray]:
    """The deterministic policy of a finished `quad-train --algo sb3` run, from its config.json,
    sb3_policy.pt (weights_only) and obs_norm.npz (no pickle)."""
    import json

    run_dir = Path(run_dir)
    config = json.loads((run_dir / "config.json").read_text())
    env_cfg = EnvConfig.from_json(config["env"])
    obs_space = gym.spaces.Box(-np.inf, np.inf, (env_cfg.layout.dim,), np.float32)
    act_space = gym.spaces.Box(-1.0, 1.0, (4,), np.float32)
    policy = ActorCriticPolicy(obs_space, act_space, lambda _: 0.0, **_policy_kwargs(config["sb3"]))
    policy.load_state_dict(torch.load(run_dir / POLICY_FILE, weights_only=True))
    return deterministic_policy(policy, ObsNorm.load(run_dir / OBS_NORM_FILE))


# --- training -------------------------------------------------------------------------------


class _TimedPPO(SB3PPO):
    """SB3's PPO, its maths untouched: `collect_rollouts` and `train` are timed, and `after_update`
    (set by the caller) sees each update. `stop` ends learning before the next rollout."""

    after_update: Callable[[_TimedPPO], None] | None = None
    stop = False
    rollout_s = 0.0
    update_s = 0.0

    def collect_rollouts(self, *args, **kwargs) -> bool:
        if self.stop:
            return False
        t = time.perf_counter()
        ok = super().collect_rollouts(*args, **kwargs)
        self.rollout_s = time.perf_counter() - t
        return ok

    def train(self) -> None:
        t = time.perf_counter()
        super().train()
        self.update_s = time.perf_counter() - t
        if self.after_update is not None:
            self.after_update(self)


def build_model(s: dict, venv: VecEnv) -> _TimedPPO:
    torch.set_num_threads(s["threads"])
    lr = MatchedLR(
        s["learning_rate"]["initial"],
        s["learning_rate"]["schedule"],
        s["total_timesteps"],
        s["n_envs"] * s["ppo"]["n_steps"],
    )
    with warnings.catch_warnings():  # SB3's note on a last, shorter minibatch (matched_settings.FIELD_MAP)
        warnings.filterwarnings("ignore", message="You have specified a mini-batch size")
        model = _TimedPPO(
            s["policy"],
            venv,
            learning_rate=lr,
            policy_kwargs=_policy_kwargs(s),
            seed=s["seed"],
            device="cpu",
            verbose=0,
            **s["ppo"],
        )
    # SB3's own logger, unless given one, makes an empty folder in the temp directory at every learn();
    # ours keeps its figures in memory (model.logger.name_to_value) and writes nothing
    model.set_logger(Logger(folder=None, output_formats=[]))
    return model


def _versions() -> dict[str, str]:
    import stable_baselines3

    return {
        "stable_baselines3": stable_baselines3.__version__,
        "torch": torch.__version__,
        "gymnasium": gym.__version__,
        "numpy": np.__version__,
    }


def train_from_cli(args, argv: list[str]) -> int:
    """`quad-train --algo sb3 ...`: the same options, run directory files and evaluation as our
    PPO, with SB3 doing the learning. No resume (SB3 checkpoints pickle)."""
    from quadpilot.console import UsageError

    from .envs import make_config
    from .ppo import PPO
    from .runs import options, plotting, runlog
    from .runs.loop import Progress, Stop, command, evaluate_and_advance, final_evaluation, now, time_breakdown

    if args.resume:
        raise UsageError("--resume is not available with --algo sb3 (its runs write no resumable checkpoint)")
    if any(a == "--checkpoint-every" or a.startswith("--checkpoint-every=") for a in argv):
        raise UsageError("--checkpoint-every does not apply to --algo sb3 (its runs write no resumable checkpoint)")
    if args.task == "waypoint":
        raise UsageError("--algo sb3 trains hover and circle; waypoint's curriculum is not wired to SB3")
    preset = args.preset or "fast"
    cfg = options.make_config(PPO, options.explicit_options(args, PPO), preset)
    out = Path(args.out or f"runs/{args.task}-sb3-seed{cfg.seed}")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UsageError(f"{out} exists and is not empty; choose another --out")
    env_cfg = make_config(args.task, **options.env_kwargs(args))
    try:
        s = sb3_settings(cfg)
    except ValueError as e:
        raise UsageError(str(e)) from None
    venv, adapter, norm = make_env(s, env_cfg)
    model = build_model(s, venv)
    obs_dim = env_cfg.layout.dim

    def obs_norm() -> ObsNorm:
        return ObsNorm.from_vec_normalize(norm) if norm is not None else ObsNorm.identity(obs_dim)

    out.mkdir(parents=True, exist_ok=True)
    runlog.write_json(
        out / "config.json",
        {
            "schema": "quadpilot.run/1",
            "algo": "sb3",
            "task": args.task,
            "preset": preset,
            "ppo": cfg.to_json(),
            "sb3": s,
            "env": env_cfg.to_json(),
            "eval_episodes": args.eval_episodes,
            "eval_every": args.eval_every,
            "command": command(argv),
            "started": now(),
            "versions": _versions(),
        },
    )
    batch = cfg.batch_size
    num_updates = cfg.num_updates
    state: dict[str, Any] = {"updates": 0, "eval_s": 0.0, "first_success": None, "last": None, "episodes": []}
    t0 = time.perf_counter()

    def train_time() -> float:
        return time.perf_counter() - t0 - state["eval_s"]

    log = runlog.MetricsLog(out / "metrics.csv")
    progress = Progress(f"quad-train {args.task} (sb3)", 0, num_updates * batch)
    stop = Stop()
    view = types.SimpleNamespace(env_cfg=env_cfg)  # what the run loop's evaluation reads of a trainer

    def after_update(model: _TimedPPO) -> None:
        state["updates"] += 1
        v = model.logger.name_to_value
        ended = adapter.take_episodes()
        recent = ended[-4 * cfg.num_envs :]
        elapsed = model.rollout_s + model.update_s
        env_s, adapter.env_s = adapter.env_s, 0.0
        m = {
            "global_step": model.num_timesteps,
            "update": state["updates"],
            "time_s": train_time(),
            "policy_loss": v.get("train/policy_gradient_loss"),
            "value_loss": 0.5 * v["train/value_loss"] if "train/value_loss" in v else None,
            "entropy": -v["train/entropy_loss"] if "train/entropy_loss" in v else None,
            "approx_kl": v.get("train/approx_kl"),
            "clip_fraction": v.get("train/clip_fraction"),
            "explained_variance": v.get("train/explained_variance"),
            "lr": v.get("train/learning_rate"),
            "steps_per_s": batch / elapsed if elapsed > 0 else float("nan"),
            "rollout_s": model.rollout_s,
            "env_s": env_s,
            "inference_s": model.rollout_s - env_s,
            "update_s": model.update_s,
            "ep_return": float(np.mean([e[0] for e in recent])) if recent else float("nan"),
            "ep_length": float(np.mean([e[1] for e in recent])) if recent else float("nan"),
            "success_rate": float(np.mean([e[2] for e in recent])) if recent else float("nan"),
            "episodes": len(recent),
        }
        view.updates, view.global_step = state["updates"], model.num_timesteps
        view.act_deterministic = deterministic_policy(model.policy, obs_norm())
        state["first_success"], dt = evaluate_and_advance(view, args, None, m, state["first_success"])
        state["eval_s"] += dt
        log.write(m)
        state["last"] = m
        progress.update(m)
        if stop.signal is not None:
            model.stop = True

    model.after_update = after_update
    try:
        with stop:
            model.learn(total_timesteps=cfg.total_steps)
    except KeyboardInterrupt:
        print(f"\nquad-train: aborted; {out} holds the metrics so far and no policy.", flush=True)
        return 130
    finally:
        progress.close()
        log.close()
    train_s = train_time()
    atomic_write(out / POLICY_FILE, lambda f: torch.save(model.policy.state_dict(), f))
    obs_norm().save(out / OBS_NORM_FILE)
    plotting.plot_curves(out / "metrics.csv", out / "curves.png", f"{args.task} (SB3 PPO), {out.name}")
    if stop.signal is not None and state["updates"] < num_updates:
        print(f"quad-train: stopped by {stop.signal} after update {state['updates']}/{num_updates}", flush=True)
        return 130
    summary = f"quad-train: done (sb3), {model.num_timesteps:,} steps in {state['updates']} updates; policy in {out}"
    if args.eval_episodes:
        meta = {
            "algo": "sb3",
            "policy": POLICY_FILE,
            "obs_norm": OBS_NORM_FILE,
            "global_step": model.num_timesteps,
            "updates": state["updates"],
            "train_time_s": train_s,
            "first_success": state["first_success"],
            "time_breakdown_s": time_breakdown(out / "metrics.csv", runlog.COLUMNS),
        }
        view.act_deterministic = deterministic_policy(model.policy, obs_norm())
        summary += final_evaluation(view, args, None, out, lambda: meta)
    print(summary, flush=True)
    return 0
