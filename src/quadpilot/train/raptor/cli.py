"""`quad-train --task hover --contract px4-raptor [--vehicle NAME|FILE] [--teacher FILE] --out DIR`:
find or train the teacher, then distill it into the policy PX4's mc_raptor loads
(`distill`). The run directory gets config.json (with the command and the wall time from start
to the student's evaluation), and, when no teacher was given or shipped, the teacher's own run in
DIR/teacher."""

from __future__ import annotations

import copy
import dataclasses
import json
import shlex
import time
from pathlib import Path

from quadpilot.console import UsageError

from ..runs.options import chosen_vehicle
from .distill import CONTRACT, DistillConfig, check_teacher_env, distill

CONTRACTS = (CONTRACT,)
TEACHER_DIR = "teacher"
CHECKS = (
    ("algo", ("ppo",), "--algo: the px4-raptor policy is distilled from our PPO's MLP; use --algo ppo"),
    ("arch", (None, "mlp"), "--arch: the px4-raptor policy's shape is fixed (blob/policy.h); its teacher is an MLP"),
    ("resume", (False,), "--resume: a px4-raptor distillation is not resumable (it takes minutes); run it again"),
)


def check(args) -> None:
    """UsageError (one line) for an option the contract's training cannot honour."""
    if args.task != "hover":
        raise UsageError(f"--contract {CONTRACT} trains hover (mc_raptor holds a setpoint); not --task {args.task}")
    for name, allowed, why in CHECKS:
        if getattr(args, name, allowed[0]) not in allowed:
            raise UsageError(why)
    if getattr(args, "randomize", None) == "airframes":
        raise UsageError(
            f"--randomize airframes: the {CONTRACT} policy is distilled for one vehicle (--vehicle); "
            "use another --randomize preset or none"
        )


def shipped_teacher(vehicle) -> Path | None:
    """The shipped MLP hover policy (policy.pt) trained for this vehicle, if there is one."""
    from quadpilot.core.params import VehicleParams
    from quadpilot.core.vehicle_file import same_vehicle
    from quadpilot.runtime.shipped import models_dir

    root = models_dir()
    for d in sorted(root.iterdir()) if root.is_dir() else ():
        try:
            config = json.loads((d / "config.json").read_text(encoding="utf-8"))
            env = config["env"]
            if env["task"] != "hover" or config["ppo"]["arch"] != "mlp" or env.get("randomization"):
                continue
            if env.get("sensor_noise") or not (d / "policy.pt").is_file():
                continue
            if same_vehicle(VehicleParams(**env["vehicle"]), vehicle):
                return d / "policy.pt"
        except (OSError, ValueError, KeyError, TypeError):
            continue  # a folder that is not a quad-train run
    return None


def distill_config(args, episode_steps: int, sizes: bool = True) -> DistillConfig:
    """--seed, --num-envs (drones per iteration), --total-steps (simulated steps in all: iterations of
    num_envs episodes) and --set NAME=VALUE (a DistillConfig field) as the distillation's settings.
    sizes=False: --num-envs and --total-steps were the teacher's PPO run's, not the distillation's."""
    from ..runs.options import parse_overrides

    values = parse_overrides(args.set, DistillConfig, CONTRACT) if sizes else {}
    for flag, name in (("seed", "seed"), ("num_envs", "num_envs")):
        if getattr(args, flag, None) is not None and (sizes or flag == "seed"):
            values.setdefault(name, getattr(args, flag))
    if args.total_steps is not None and sizes:
        per_iteration = values.get("num_envs", DistillConfig.num_envs) * episode_steps
        values.setdefault("iterations", max(1, -(-args.total_steps // per_iteration)))
    try:
        return DistillConfig(**values)
    except ValueError as e:
        raise UsageError(f"--contract {CONTRACT}: {e}") from None


def _teacher(teacher, path: Path, vehicle):
    """The loaded teacher, if it is one the contract can distil for `vehicle` (UsageError, one line)."""
    from quadpilot.core.vehicle_file import differences, same_vehicle

    if not same_vehicle(teacher.env_config.params, vehicle):
        flown = teacher.env_config.params
        apart = differences(flown, vehicle)
        which = f"{flown.name}, not {vehicle.name}" if flown.name != vehicle.name else f"another {vehicle.name}"
        raise UsageError(
            f"--teacher {path} flies {which} ({', '.join(apart[:4])}"
            f"{f' and {len(apart) - 4} more' if len(apart) > 4 else ''}: teacher vs --vehicle); "
            "give the teacher of the same vehicle"
        )
    check_teacher_env(teacher.env_config)
    return teacher


def _first_missing(out: Path) -> Path | None:
    """The outermost directory of `out` (itself included) that does not exist yet: what mkdir will make."""
    top = None
    for d in (out, *out.parents):
        if d.exists():
            break
        top = d
    return top


def _remove_if_empty(out: Path, top: Path | None) -> None:
    """Remove what mkdir made of `out` up to `top` (`_first_missing`), as long as nothing is in it
    but, perhaps, an empty teacher directory (a refused teacher's training)."""
    if top is None:
        return
    if (out / TEACHER_DIR).is_dir():
        try:
            (out / TEACHER_DIR).rmdir()
        except OSError:
            return
    for d in (out, *out.parents):
        try:
            d.rmdir()  # only ever removes an empty directory
        except OSError:
            return
        if d == top:
            return


def train_from_cli(args, argv: list[str], algorithms: dict) -> int:
    """quad-train --algo raptor: a PPO teacher (shipped, given or trained here with `algorithms`, the
    registry `train.cli` hands down), then its distilled student."""
    from ..runs.checkpoint import load_policy
    from ..runs.loop import Progress, train

    check(args)
    start = time.perf_counter()
    try:  # the frame first: a teacher trained for a frame the contract cannot fly is time lost
        from quadpilot.core.px4_raptor import policy_order

        policy_order(chosen_vehicle(args))
    except ValueError as e:
        raise UsageError(f"--vehicle: {e}") from None
    import torch

    # one thread unless told: the GRU's small products gain nothing from more, and lose much to a busy CPU
    torch.set_num_threads(args.threads or 1)
    vehicle = chosen_vehicle(args)
    out = Path(args.out or f"runs/hover-px4-raptor-{vehicle.name}")
    # every refusal of the command comes before the run directory is made: none is left empty behind
    if args.teacher is not None:
        teacher_path, how = Path(args.teacher), "given"
        shown = str(teacher_path)
    elif (found := shipped_teacher(vehicle)) is not None:
        teacher_path, how = found, "shipped"
        shown = f"models/{found.parent.name}/{found.name}"  # the shipped model's name, not this machine's path
    else:
        teacher_path, how = out / TEACHER_DIR / "policy.pt", "trained"
        shown = str(teacher_path)
    if how != "trained":
        teacher = _teacher(load_policy(teacher_path, algorithms), teacher_path, vehicle)
        dc = distill_config(args, teacher.env_config.episode_steps)
        out.mkdir(parents=True, exist_ok=True)
    else:
        distill_config(args, 1, sizes=False)  # the seed, checked before the teacher's training
        made = _first_missing(out)
        out.mkdir(parents=True, exist_ok=True)
        teacher_args = copy.copy(args)
        teacher_args.out, teacher_args.contract = str(out / TEACHER_DIR), None
        print(f"quad-train: no shipped teacher flies {vehicle.name}: training one first in {teacher_args.out}")
        status = None
        try:
            status = train(teacher_args, argv, algorithms)
        finally:
            if status != 0:  # refused (or failed) before the teacher's run wrote anything: no empty folder
                _remove_if_empty(out, made)
        if status != 0:
            return status
        teacher = _teacher(load_policy(teacher_path, algorithms), teacher_path, vehicle)
        dc = distill_config(args, teacher.env_config.episode_steps, sizes=False)  # the sizes were the teacher's
    cfg = teacher.env_config
    label = f"quad-train hover ({CONTRACT})"
    progress = Progress(label, 0, dc.iterations * dc.num_envs * cfg.episode_steps)
    try:
        evaluation = distill(teacher, cfg, out, dc, teacher_source=f"{how}: {shown}", progress=progress)
    finally:
        progress.close()
    wall = time.perf_counter() - start
    config = {
        "schema": "quadpilot.run/1",
        "algo": "distill",  # not a PPO run: the teacher's is (DIR/teacher, or the shipped one named here)
        "contract": CONTRACT,
        "command": shlex.join(["quad-train", *argv]),
        "teacher": {"how": how, "path": shown},
        "distill": dataclasses.asdict(dc),
        "env": cfg.to_json(),
        "wall_s": wall,
    }
    (out / "config.json").write_text(json.dumps(config, indent=2) + "\n", encoding="utf-8")
    error = evaluation["mean_error_last_window_m"]  # None: every episode crashed
    print(
        f"quad-train: {out}/policy.pt: success {evaluation['success_rate']:.0%} of {evaluation['episodes']} episodes, "
        + ("every one crashed" if error is None else f"mean error over the last 2 s {100 * error:.2f} cm")
        + f" ({wall:.0f} s); next: quad-export --format px4-raptor {out}/policy.pt"
    )
    return 0
