"""`quad-train --task hover --contract px4-raptor`: a policy of exactly the shape PX4's mc_raptor is
compiled for (`student.RaptorStudent`: dense 22→16, GRU 16, dense 16→4), distilled from a
trained MLP hover policy of the same vehicle by DAgger (Ross, Gordon and Bagnell 2011, "A Reduction of
Imitation Learning and Structured Prediction to No-Regret Online Learning"), the way RAPTOR's own
foundation policy was made from expert policies (Eschmann et al. 2025, arXiv 2509.11481, Sec. IV).

One iteration: N drones fly an episode of the teacher's hover task at 100 Hz (the contract's training
rate), the first iteration driven by the teacher, later ones by the student; every step is labelled
with the teacher's action on the state the drone is in, written in the contract's convention (the
motor command c in [0, 1] the teacher's action makes, as 2c − 1, in the policy's motor order); the
student sees the contract's 22 inputs (`core.px4_raptor.observation_batch`, with the previous action it
flew), and is trained by backpropagation through time on every episode collected so far, from its
learned initial state, as it runs in flight (the GRU advancing once per 100 Hz step).

The teacher: `--teacher FILE` (a quad-train policy.pt, hover, 100 Hz), else the shipped model trained
for the same vehicle (`runtime.shipped`), else one trained first by our PPO in OUT/teacher (the same
command's --total-steps and options), so that a vehicle file alone is enough.

Output, in the run directory: policy.pt (`torch.load(weights_only=True)`: the weight dict of
`runtime.gru`, the vehicle, the environment, how it was made), eval.json (100 deterministic episodes of
the student alone, the hover rule), metrics.csv (one row per iteration) and config.json.
`quad-export --format px4-raptor OUT/policy.pt` writes the policy.tar mc_raptor loads.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from quadpilot.atomic_files import atomic_write
from quadpilot.console import UsageError
from quadpilot.core import px4_raptor
from quadpilot.core.mission import window_success, yaw_errors
from quadpilot.core.state import POS, YAW

from ..envs import EnvConfig, QuadBatch
from .student import RaptorStudent

SCHEMA = px4_raptor.STUDENT_SCHEMA
CONTRACT = "px4-raptor"


@dataclasses.dataclass(frozen=True)
class DistillConfig:
    """How the student is distilled; every field is in config.json and policy.pt."""

    iterations: int = 10
    """DAgger iterations (an episode of every drone each, then training on all so far)."""
    num_envs: int = 128
    """Drones flown per iteration (each one episode)."""
    teacher_iterations: int = 1
    """The first iterations the teacher flies (the others: the student, labelled by the teacher)."""
    gradient_steps: int = 150
    """Adam steps per iteration, each on `minibatch` whole episodes."""
    minibatch: int = 32
    lr: float = 3e-3
    max_grad_norm: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            low = 0 if f.name in ("seed", "teacher_iterations") else 1 if f.type == "int" else 0.0
            if not (math.isfinite(v) and (v >= low if f.type == "int" else v > low)):
                raise ValueError(
                    f"{f.name} = {v!r}: expected {'an integer >= ' + str(low) if f.type == 'int' else 'a number > 0'}"
                )


def teacher_labels(teacher_action: np.ndarray, u_hover: float, order: np.ndarray) -> np.ndarray:
    """The teacher's actions (N, 4) in our convention (thrust about hover trim, the vehicle's output
    order: command u = u_hover·√(1 + a), `core.dynamics.action_to_command`) as the contract's
    actions (N, 4): 2u − 1 in the policy's (Crazyflie) motor order, output i taking policy output
    order[i]."""
    a = np.clip(np.asarray(teacher_action, np.float64), -1.0, 1.0)
    u = np.clip(u_hover * np.sqrt(1.0 + a), 0.0, 1.0)
    out = np.empty_like(u)
    out[:, order] = 2.0 * u - 1.0
    return out.astype(np.float32)


def contract_commands(action: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Contract actions (N, 4), policy order → motor commands in [0, 1] per vehicle output:
    mc_raptor's (clamp(a) + 1)/2, output i taking policy output order[i]."""
    return (np.clip(action, -1.0, 1.0)[:, order] + 1.0) / 2.0


def torch_policy(student: RaptorStudent):
    """The student as `fly`'s policy: (x (n, 22), state or None) → (raw actions (n, 4), state)."""

    def act(x: np.ndarray, h):
        with torch.no_grad():
            y, h = student(torch.from_numpy(x)[None], h)
        return y[0].numpy(), h

    return act


def numpy_policy(step):
    """A runtime step (`runtime.gru.GruStep`: one vehicle a call) as `fly`'s policy, vehicle by vehicle."""

    def act(x: np.ndarray, h):
        h = [step.initial_state] * len(x) if h is None else h
        out = [step(xi, hi) for xi, hi in zip(x, h, strict=True)]
        return np.stack([a for a, _ in out]), [s for _, s in out]

    return act


def fly(policy, cfg: EnvConfig, n: int, rng, teacher=None, teacher_drives=False) -> dict:
    """One episode of n drones flown by `policy` (`torch_policy`, `numpy_policy`; or the teacher,
    `teacher_drives`): the contract's observations, the teacher's labels (if a teacher is given), and
    the hover-rule figures of it."""
    order = np.asarray(px4_raptor.policy_order(cfg.params))
    batch = QuadBatch(cfg, n)
    batch.reset(np.ones(n, bool), rng)
    T, window = cfg.episode_steps, cfg.success_steps
    xs = np.zeros((T, n, px4_raptor.OBS_DIM), np.float32)
    labels = np.zeros((T, n, px4_raptor.ACTION_DIM), np.float32)
    alive_at = np.ones((T, n), bool)
    alive = np.ones(n, bool)
    prev = np.full((n, px4_raptor.ACTION_DIM), px4_raptor.RESET_PREVIOUS_ACTION, np.float32)
    err_sum, rate_sum, head_sum = np.zeros(n), np.zeros(n), np.zeros(n)
    h = None
    for t in range(T):
        x = px4_raptor.observation_batch(batch.state, batch.target, batch.heading, prev, out=xs[t])
        if teacher is not None:
            labels[t] = teacher_labels(teacher(batch.obs.copy()), batch.u_hover, order)
        if teacher_drives:  # the student's own answer would not be used
            action = labels[t]
        else:
            action, h = policy(x, h)
        alive_at[t] = alive
        prev = np.clip(action, -1.0, 1.0).astype(np.float32)
        _, _, crashed, _, err = batch.step(contract_commands(prev, order), commands=True)
        alive &= ~crashed
        if not alive.all():  # parked at rest at the target, as `evaluate` does, masked from here on
            s = batch.state
            s[~alive] = 0.0
            s[~alive, POS] = batch.target[~alive]
            s[~alive, YAW] = batch.heading[~alive]
        if t >= T - window:
            err_sum += err
            rate, head = yaw_errors(batch.state, batch.heading)
            rate_sum += rate
            head_sum += head
    mean_err, mean_rate, mean_head = err_sum / window, rate_sum / window, head_sum / window
    success = window_success(alive, mean_err, mean_rate, mean_head, cfg.success_tolerance)
    some = alive.any()
    return {
        "obs": xs,
        "labels": labels,
        "mask": alive_at,
        "figures": {
            "episodes": n,
            "success_rate": float(success.mean()),
            "crash_rate": float((~alive).mean()),
            # None (JSON null) when every drone crashed, as `evaluate` gives them
            "mean_error_last_window_m": float(mean_err[alive].mean()) if some else None,
            "max_error_last_window_m": float(mean_err[alive].max()) if some else None,
            "max_mean_abs_yaw_rate_last_window_rad_s": float(mean_rate[alive].max()) if some else None,
            "max_mean_heading_error_last_window_deg": float(np.degrees(mean_head[alive].max())) if some else None,
            "success_tolerance_m": cfg.success_tolerance,
            "window_s": cfg.success_window,
        },
    }


def train_student(student, optim, data: dict, dc: DistillConfig, gen: torch.Generator) -> float:
    """`dc.gradient_steps` Adam steps of BPTT over whole episodes drawn from `data` (obs (T, S, 22),
    labels (T, S, 4), mask (T, S)); the last step's loss."""
    obs, labels, mask = data["obs"], data["labels"], data["mask"]
    S = obs.shape[1]
    loss = torch.zeros(())
    for _ in range(dc.gradient_steps):
        idx = torch.randperm(S, generator=gen)[: dc.minibatch]
        y, _ = student(obs[:, idx])
        m = mask[:, idx, None]
        loss = (((y - labels[:, idx]) ** 2) * m).sum() / (m.sum() * px4_raptor.ACTION_DIM).clamp(min=1.0)
        optim.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(student.parameters(), dc.max_grad_norm)
        optim.step()
    return float(loss.detach())


def checkpoint(student: RaptorStudent, cfg: EnvConfig, dc: DistillConfig, teacher_source: str, extra: dict) -> dict:
    """What policy.pt holds: tensors and JSON-able data only (`torch.load(weights_only=True)`)."""
    return {
        "schema": SCHEMA,
        "contract": CONTRACT,
        "weights": {k: torch.from_numpy(v) for k, v in student.weights().items()},
        "env_config": cfg.to_json(),
        "distill_config": dataclasses.asdict(dc),
        "teacher": teacher_source,
        **extra,
    }


def fits_contract(cfg: EnvConfig) -> bool:
    """True for the environment the contract's policy is made and flown in: hover at its 100 Hz."""
    return cfg.task == "hover" and abs(cfg.dt - 1.0 / px4_raptor.TRAINING_RATE_HZ) <= 1e-12


class StudentCheckpointError(ValueError):
    """A px4-raptor policy.pt that cannot be used (one line)."""


def load_student(path) -> tuple[RaptorStudent, dict]:
    """The student and the checkpoint dict of a px4-raptor policy.pt; StudentCheckpointError if not one."""
    from ..runs.checks import CheckpointError, load_weights_only

    try:
        ckpt = load_weights_only(path)  # tensors and plain data only: nothing in the file runs
    except CheckpointError as e:
        raise StudentCheckpointError(f"not a readable checkpoint: {e}") from None
    if not isinstance(ckpt, dict) or ckpt.get("schema") != SCHEMA:
        raise StudentCheckpointError(f"{path}: not a px4-raptor policy (expected schema {SCHEMA!r})")
    try:
        weights = {k: v.numpy() for k, v in ckpt["weights"].items()}
        student = RaptorStudent.from_weights(weights)
        cfg = EnvConfig.from_json(ckpt["env_config"])  # the environment it came from: export flies it
    except (AttributeError, KeyError, TypeError, ValueError) as e:
        what = f"missing entry {e}" if isinstance(e, KeyError) else str(e).splitlines()[0][:200]
        raise StudentCheckpointError(
            f"{path}: damaged px4-raptor policy ({what}); expected the file quad-train --contract px4-raptor writes"
        ) from None
    if not fits_contract(cfg):
        raise StudentCheckpointError(
            f"{path}: its environment says task {cfg.task} at {1 / cfg.dt:g} Hz; a {CONTRACT} policy flies hover at "
            f"{px4_raptor.TRAINING_RATE_HZ} Hz (mc_raptor holds a setpoint), as quad-train --contract {CONTRACT} "
            "writes it"
        )
    return student, ckpt


def is_student_checkpoint(path) -> bool:
    """True if `path` is a px4-raptor policy.pt (read with weights_only; False for anything else)."""
    from ..runs.checks import CheckpointError, load_weights_only

    try:
        ckpt = load_weights_only(path)
    except CheckpointError:
        return False
    return isinstance(ckpt, dict) and ckpt.get("schema") == SCHEMA


def check_teacher_env(cfg: EnvConfig) -> None:
    """UsageError (one line) if a teacher trained in `cfg` cannot be distilled into the contract's policy."""
    if not fits_contract(cfg):
        raise UsageError(
            f"the teacher flies {cfg.task} at {1 / cfg.dt:g} Hz; the px4-raptor contract needs a hover teacher "
            f"at {px4_raptor.TRAINING_RATE_HZ} Hz (--task hover, the default 0.01 s step)"
        )
    try:
        px4_raptor.policy_order(cfg.params)
    except ValueError as e:
        raise UsageError(str(e)) from None


def distill(teacher, cfg: EnvConfig, out: Path, dc: DistillConfig, teacher_source: str, progress=None) -> dict:
    """Run DAgger (module docstring) into the run directory `out`; returns the evaluation."""
    check_teacher_env(cfg)
    torch.manual_seed(dc.seed)
    rng = np.random.default_rng(dc.seed)
    gen = torch.Generator().manual_seed(dc.seed)
    student = RaptorStudent()
    optim = torch.optim.Adam(student.parameters(), lr=dc.lr)
    data: dict | None = None
    rows = []
    start = time.perf_counter()
    T = cfg.episode_steps
    for it in range(dc.iterations):
        ep = fly(torch_policy(student), cfg, dc.num_envs, rng, teacher, teacher_drives=it < dc.teacher_iterations)
        new = {k: torch.from_numpy(ep[k]) for k in ("obs", "labels", "mask")}
        new["mask"] = new["mask"].float()
        data = new if data is None else {k: torch.cat([data[k], new[k]], 1) for k in new}
        loss = train_student(student, optim, data, dc, gen)
        row = {
            "iteration": it + 1,
            "driver": "teacher" if it < dc.teacher_iterations else "student",
            "episodes_so_far": int(data["obs"].shape[1]),
            "loss": loss,
            "success_rate": ep["figures"]["success_rate"],
            "mean_error_last_window_m": ep["figures"]["mean_error_last_window_m"],
            "wall_s": time.perf_counter() - start,
        }
        rows.append(row)
        _write_metrics(out, rows)
        data_now = checkpoint(student, cfg, dc, teacher_source, {"iterations_done": it + 1})
        atomic_write(out / "policy.pt", lambda f, d=data_now: torch.save(d, f))
        if progress is not None:
            progress.update(
                {
                    "global_step": (it + 1) * dc.num_envs * T,
                    "update": it + 1,
                    "steps_per_s": (it + 1) * dc.num_envs * T / max(row["wall_s"], 1e-9),
                    "ep_return": math.nan,  # no return: a distillation has a loss (metrics.csv)
                    "success_rate": ep["figures"]["success_rate"],
                }
            )
    evaluation = fly(torch_policy(student), cfg, 100, np.random.default_rng(12345))["figures"]
    evaluation.update(task="hover", contract=CONTRACT, seed=12345, episode_steps=T, teacher=teacher_source)
    text = json.dumps(evaluation, indent=2, allow_nan=False) + "\n"  # standard JSON: no NaN
    atomic_write(out / "eval.json", lambda f: f.write(text.encode()))
    return evaluation


def _write_metrics(out: Path, rows: list[dict]) -> None:
    def write(f):
        import io

        text = io.StringIO()
        w = csv.DictWriter(text, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
        f.write(text.getvalue().encode())

    atomic_write(out / "metrics.csv", write)
