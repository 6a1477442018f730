"""quad-train: train a quadrotor policy with PPO, with checkpoints that survive Ctrl-C and kill -9.

Writes into the run directory (default runs/<task>-seed<S>):
  config.json         PPO, environment and curriculum configuration, preset, command line(s)
  metrics.csv         one row per PPO update (fixed header), flushed as each update ends
  checkpoint.pt       latest resumable state (checkpoint.prev.pt: the one before it)
  policy.pt           final deployable checkpoint (what quad-export reads)
  eval.json           deterministic evaluation of the final policy
  curves.png          episode return, length, success rate (and curriculum stage) against steps
  snapshots/          with --snapshot-every N: policy-<steps>.pt, the deployable policy at 0 steps,
                      every N updates and at the end (python -m quadpilot.studies.montage draws them)

Resume an interrupted or finished run with the same command plus --resume; a larger --total-steps
extends a finished run. A run holds its directory's lock (.lock) while it writes there: a second
run in the same directory, fresh or --resume, is refused.

Exit codes: 0 done; 1 a file that cannot be used (a malformed or foreign checkpoint, a run
directory another run holds, a write that failed); 2 a bad flag or a request the run directory
does not fit (one line on stderr each); 130 stopped by Ctrl-C or SIGTERM (resumable).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import itertools
import math
import shlex
import signal
import sys
import textwrap
import threading
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from quadpilot.console import Parser, UsageError

SIGNALS = ("SIGINT", "SIGTERM")
RUN_FILES = (
    "config.json",
    "metrics.csv",
    "checkpoint.pt",
    "checkpoint.prev.pt",
    "policy.pt",
    "eval.json",
    "curves.png",
)


_Parser = Parser  # the shared scaffold (quadpilot.console); the name the studies import


def field_docs(cls) -> dict[str, str]:
    """The docstring under each field of a dataclass (DESIGN style 1: it becomes --help)."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError):
        return {}
    body = tree.body[0].body
    docs = {}
    for a, b in itertools.pairwise(body):
        if (
            isinstance(a, ast.AnnAssign)
            and isinstance(a.target, ast.Name)
            and isinstance(b, ast.Expr)
            and isinstance(b.value, ast.Constant)
            and isinstance(b.value.value, str)
        ):
            docs[a.target.id] = " ".join(b.value.value.split())
    return docs


def _int_at_least(lo: int, hi: int = 2**62):
    """An argparse type: an integer in lo..hi (the upper bound keeps a typo like 10**12 drones from
    reaching an allocation)."""

    def parse(s: str) -> int:
        try:
            v = int(s.replace("_", ""))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {s!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"must be ≥ {lo}, got {v}")
        if v > hi:
            raise argparse.ArgumentTypeError(f"must be ≤ {hi:,}, got {v:,}")
        return v

    parse.__name__ = f"integer ≥ {lo}"
    return parse


# PPOConfig fields that have a command-line option; given explicitly, they override the preset.
PPO_OPTIONS = {
    "total_steps": ("N", 1),
    "num_envs": ("K", 1),
    "seed": ("S", 0),
    "rollout_steps": ("T", 1),
    "minibatch_size": ("M", 1),
    "threads": ("N", 1),
    "obs_history": ("K", 1),
    "bptt_steps": ("L", 0),
}


def _upper_bounds() -> dict[str, int]:
    """The largest value of each PPO_OPTIONS flag: the sizes a checkpoint may describe
    (checkpoint.py), so that a run's own file is never refused, and 64 bits for the seed
    (torch.manual_seed)."""
    from .checkpoint import MAX_BATCH, MAX_ENVS, MAX_OBS_HISTORY, MAX_THREADS

    sizes = {"num_envs": MAX_ENVS, "rollout_steps": MAX_BATCH, "minibatch_size": MAX_BATCH, "bptt_steps": MAX_BATCH}
    return {**sizes, "threads": MAX_THREADS, "obs_history": MAX_OBS_HISTORY, "seed": 2**63 - 1, "total_steps": 2**62}


# Options a resumed run may change; everything else must match the checkpoint.
RESUME_MAY_CHANGE = ("total_steps", "threads")
# --algo: our PPO, a comparison baseline from another library trained on the same environment
# with settings matched to the PPO preset, or our SAC; each other than ppo is a module of
# this package with train_from_cli(args, argv).
ALGOS = {"ppo": None, "sb3": "sb3_baseline", "sac": "sac"}


def build_parser() -> argparse.ArgumentParser:
    from quadpilot.core.vehicle_file import shipped_names

    from .envs import TASKS
    from .ppo import PRESETS, PPOConfig

    docs = field_docs(PPOConfig)
    defaults = PPOConfig()
    p = _Parser(
        prog="quad-train",
        description=__doc__.split("\n\n")[0],
        epilog="\n\n".join(__doc__.split("\n\n")[1:]),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        allow_abbrev=False,
    )
    p.add_argument(
        "--task", required=True, choices=TASKS, help="What to learn: hover, waypoint (with curriculum), circle."
    )
    upper = _upper_bounds()
    for name, (metavar, lo) in PPO_OPTIONS.items():
        doc = docs.get(name, "").replace("%", "%%")
        p.add_argument(
            "--" + name.replace("_", "-"),
            type=_int_at_least(lo, upper[name]),
            metavar=metavar,
            help=f"{doc} Default: the preset's, else {getattr(defaults, name)}.",
        )
    p.add_argument(
        "--algo",
        choices=tuple(ALGOS),
        default="ppo",
        help="Who learns: ppo (ours), sb3 (Stable-Baselines3 PPO with settings matched to the preset, "
        "for comparison; needs the dev extra) or sac (our Soft Actor-Critic, quadpilot.train.sac; "
        "--rollout-steps is then vector steps per iteration, a metrics row, and --minibatch-size the "
        "transitions per gradient step). Default: ppo.",
    )
    p.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        help="PPO hyper-parameter preset: fast (batched PPO tuned here), seed001 (seed 001's recipe) or "
        "sb3_defaults (Stable-Baselines3 PPO's defaults). "
        "Options given explicitly override it. Default: fast.",
    )
    p.add_argument(
        "--vehicle",
        metavar="NAME|FILE.toml",
        help=f"Airframe: a shipped vehicle ({', '.join(shipped_names())}; quadpilot/vehicles/*.toml) or a vehicle "
        "file of the same schema (quadpilot.core.vehicle_file). It travels with the policy (checkpoint, ONNX "
        "metadata). Default: seed.",
    )
    _add_randomize_option(p)
    _add_sensor_options(p)
    p.add_argument("--out", metavar="DIR", help="Run directory. Default: runs/<task>-seed<S>.")
    p.add_argument(
        "--resume",
        action="store_true",
        help="Continue the run in DIR from checkpoint.pt (or checkpoint.prev.pt if that is unreadable). "
        "Only --total-steps and --threads may differ from the original run.",
    )
    p.add_argument(
        "--eval-episodes",
        type=_int_at_least(0, upper["num_envs"]),  # evaluated as one batch of drones
        default=100,
        metavar="N",
        help="Deterministic evaluation episodes of the final policy written to eval.json (0: skip). Default: 100.",
    )
    p.add_argument(
        "--eval-every",
        type=_int_at_least(0),
        default=10,
        metavar="N",
        help="Also evaluate the deterministic policy every N updates (--eval-episodes episodes, 100 if that is 0; "
        "logged as eval_success_rate in metrics.csv; its time is not counted as training time) and record in "
        "eval.json the steps and training seconds at which success first reached 95 %%. 0: never. Default: 10.",
    )
    p.add_argument(
        "--checkpoint-every",
        type=_int_at_least(1),
        default=1,
        metavar="N",
        help="Save checkpoint.pt every N updates (and always at the end and on Ctrl-C); a kill loses at most "
        "N updates. Default: 1 (a save costs milliseconds).",
    )
    p.add_argument(
        "--snapshot-every",
        type=_int_at_least(0),
        default=0,
        metavar="N",
        help="Keep the policy every N updates (and at 0 steps and at the end) as snapshots/policy-<steps>.pt, "
        "a small deployable file like policy.pt (~50 kB for the default network), for "
        "python -m quadpilot.studies.montage. 0: none. Default: 0.",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="NAME=VALUE",
        help="--algo sac only: set a SAC hyper-parameter (a field of quadpilot.train.sac.SACConfig, e.g. "
        "updates_per_step=4, critic_hidden=128,128, autotune_alpha=false); repeatable.",
    )
    return p


# --- domain randomisation ------------------------------------------------------------------


def _add_randomize_option(p: argparse.ArgumentParser) -> None:
    from quadpilot.core.randomization import PRESETS as RANDOMIZATIONS

    p.add_argument(
        "--randomize",
        "--dr",
        nargs="?",
        const="default",
        choices=sorted(RANDOMIZATIONS),
        metavar="PRESET",
        help="Randomise the plant per episode (domain randomisation, quadpilot.core.randomization): "
        "default (mass and inertia ±20 %%, k_f and k_m ±10 %%, motor lag 0-30 ms, wind up to 1.5 m/s), "
        "params (the same without wind) or pushes (default plus random pushes). The policy observes nothing "
        "new and keeps the nominal hover command. Without PRESET: default. Default: off.",
    )


def _randomize_clash(args, env_config: dict) -> list[str]:
    """A resumed run keeps its randomisation: --randomize on resume must name the stored one."""
    if not getattr(args, "randomize", None):
        return []
    stored = (env_config.get("randomization") or {}).get("name")
    return [] if stored == args.randomize else [f"--randomize {args.randomize} (checkpoint: {stored or 'off'})"]


# --- network and sensors ------------------------------------------------------------------


def _add_sensor_options(p: argparse.ArgumentParser) -> None:
    from quadpilot.core.sensor_noise import SENSOR_NOISE_PRESETS

    p.add_argument(
        "--arch",
        choices=("mlp", "lstm"),
        help="Network: mlp (two tanh layers each for actor and critic) or lstm (one LSTM layer each, trained "
        "on sequences with the hidden state reset at episode starts; quadpilot.train.recurrent_ppo). Default: "
        "the preset's, else mlp.",
    )
    p.add_argument(
        "--sensor-noise",
        nargs="?",
        const="vehicle",
        choices=("vehicle", *sorted(SENSOR_NOISE_PRESETS)),
        metavar="PRESET",
        help="Observe through noisy sensors (quadpilot.core.sensor_noise): gyro white noise and bias random walk, "
        "and a cm-level position/velocity/attitude estimate; seed: ADIS16448 IMU, crazyflie: BMI088. Without "
        "PRESET: the vehicle's own. Default: exact states.",
    )
    p.add_argument(
        "--motor-tau",
        type=float,
        metavar="S",
        help="First-order motor time constant in seconds (e.g. 0.03), replacing the vehicle preset's (0). "
        "Default: the preset's.",
    )


def _resolve_vehicle(args) -> None:
    """--vehicle NAME|FILE.toml: a shipped name stays a name (`core.params.get_preset`, equal to its
    file), a file becomes its VehicleParams. UnknownVehicleError (exit 2) or VehicleFileError (exit 1)."""
    from quadpilot.core.vehicle_file import is_vehicle_path, resolve_vehicle

    if args.vehicle is None:
        return
    params = resolve_vehicle(args.vehicle)  # checks a name against the shipped files, reads a file
    if is_vehicle_path(args.vehicle):
        args.vehicle = params


def _vehicle(args):
    """The VehicleParams --vehicle names (seed without it)."""
    from quadpilot.core.params import VehicleParams, get_preset

    v = args.vehicle or "seed"
    return v if isinstance(v, VehicleParams) else get_preset(v)


def _sensor_preset(args) -> str:
    """The sensor-noise preset --sensor-noise names; without a PRESET, the vehicle's own, which a
    vehicle file has only if its name is a sensor-noise preset's."""
    from quadpilot.core.sensor_noise import SENSOR_NOISE_PRESETS

    if args.sensor_noise != "vehicle":
        return args.sensor_noise
    name = _vehicle(args).name
    if name not in SENSOR_NOISE_PRESETS:
        raise UsageError(
            f"--sensor-noise: no sensor model for vehicle {name!r}; name one: --sensor-noise "
            f"{'|'.join(sorted(SENSOR_NOISE_PRESETS))}"
        )
    return name


def _sensor_env_kw(args) -> dict:
    """make_config keywords for --sensor-noise and --motor-tau."""
    import dataclasses as dc

    kw: dict = {}
    if args.sensor_noise:
        kw["sensor_noise"] = _sensor_preset(args)
    if args.motor_tau is not None:
        if not (math.isfinite(args.motor_tau) and args.motor_tau >= 0):
            raise UsageError(f"--motor-tau must be a finite number of seconds ≥ 0, got {args.motor_tau}")
        kw["vehicle"] = dc.replace(_vehicle(args), motor_tau=args.motor_tau)
    return kw


def _vehicle_clash(args, env_config: dict) -> list[str]:
    """A resumed run keeps its vehicle: --vehicle, if given, must name the stored one (a name: the
    same name; a file: the same parameters, with --motor-tau's time constant if that is given)."""
    import dataclasses as dc

    from quadpilot.core.params import VehicleParams

    if not args.vehicle:
        return []
    stored = env_config["vehicle"]
    if isinstance(args.vehicle, str):
        return [] if args.vehicle == stored["name"] else [f"--vehicle {args.vehicle} (checkpoint: {stored['name']})"]
    want = args.vehicle if args.motor_tau is None else dc.replace(args.vehicle, motor_tau=args.motor_tau)
    if want == VehicleParams(**stored):
        return []
    return [f"--vehicle {want.name} from a file whose parameters differ (checkpoint: {stored['name']})"]


def _sensor_clash(args, env_config: dict) -> list[str]:
    """A resumed run keeps its sensors and motors: the flags, if given, must match the checkpoint."""
    out = []
    if args.sensor_noise:
        want = _sensor_preset(args)
        stored = (env_config.get("sensor_noise") or {}).get("name")
        if stored != want:
            out.append(f"--sensor-noise {want} (checkpoint: {stored or 'off'})")
    if args.motor_tau is not None and args.motor_tau != env_config["vehicle"].get("motor_tau"):
        out.append(f"--motor-tau {args.motor_tau} (checkpoint: {env_config['vehicle'].get('motor_tau')})")
    return out


# --- progress -------------------------------------------------------------------------------


def _info(m: dict) -> str:
    ret, succ = m["ep_return"], m["success_rate"]
    ret_s = f"{ret:.1f}" if math.isfinite(ret) else "–"  # no episode ended in this update
    succ_s = f"{succ:.0%}" if math.isfinite(succ) else "–"
    s = f"{m['steps_per_s']:,.0f} steps/s · return {ret_s} · success {succ_s}"
    if m.get("curriculum_stage") is not None:
        s += f" · stage {m['curriculum_stage']} ({m['target_radius']:g} m)"
    return s


class _Progress:
    """A rich progress bar on a terminal; a plain line every ~10 % otherwise (CI logs)."""

    def __init__(self, label: str, start: int, total: int) -> None:
        from rich.console import Console

        self.label, self.total = label, total
        console = Console()
        self.fancy = console.is_terminal
        self.next_mark = math.floor(10 * start / total + 1e-9) / 10 + 0.1 if total else 1.0
        if self.fancy:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
            from rich.table import Column

            self.bar = Progress(
                TextColumn("[bold]{task.description}"),
                BarColumn(bar_width=24),
                # on a narrow terminal the counters keep their width and the metrics get cut
                MofNCompleteColumn(table_column=Column(min_width=2 * len(f"{total}") + 1)),
                TimeRemainingColumn(table_column=Column(min_width=7)),
                TextColumn("{task.fields[info]}", table_column=Column(no_wrap=True, overflow="ellipsis")),
                console=console,
            )
            self.task = self.bar.add_task(label.removeprefix("quad-train "), total=total, completed=start, info="")
            self.bar.start()
        else:
            print(f"{label}: {start:,}/{total:,} steps", flush=True)

    def update(self, m: dict) -> None:
        step = int(m["global_step"])
        if self.fancy:
            self.bar.update(self.task, completed=step, info=_info(m))
            return
        frac = step / self.total if self.total else 1.0
        if frac + 1e-9 >= self.next_mark or step >= self.total:
            print(
                f"{self.label}: {step:,}/{self.total:,} steps ({frac:.0%}), update {m['update']} · {_info(m)}",
                flush=True,
            )
            self.next_mark = math.floor(10 * frac + 1e-9) / 10 + 0.1

    def close(self) -> None:
        if self.fancy:
            self.bar.stop()
            self.fancy = False


class _Stop:
    """First SIGINT/SIGTERM: finish the update, save, exit. Second: abort at once."""

    def __init__(self) -> None:
        self.signal: str | None = None
        self._old: dict = {}

    def __call__(self, signum, frame) -> None:
        if self.signal is not None:
            raise KeyboardInterrupt
        self.signal = signal.Signals(signum).name

    def __enter__(self) -> _Stop:
        if threading.current_thread() is threading.main_thread():
            for name in SIGNALS:
                sig = getattr(signal, name, None)
                if sig is not None:
                    self._old[sig] = signal.signal(sig, self)
        return self

    def __exit__(self, *exc) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


# --- the run --------------------------------------------------------------------------------


def _clean_stale_temps(out: Path) -> None:
    """Temporary files of a write that a kill interrupted (see checkpoint.atomic_write)."""
    for f in out.glob(".*.tmp"):
        if any(f.name.startswith(f".{name}.") for name in RUN_FILES):
            f.unlink(missing_ok=True)
    for f in (out / "snapshots").glob(".policy-*.tmp"):
        f.unlink(missing_ok=True)


def _command(argv: list[str]) -> str:
    return shlex.join(["quad-train", *argv])


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def check_out_dir(out: Path, flag: str = "--out") -> None:
    """UsageError unless `out` is a directory this process could create or write in (checked before
    any work: a path through a file, under /proc, or in a read-only place is refused up front)."""
    from quadpilot.console import check_output_path  # the one place outputs are probed

    if not str(out):
        raise UsageError(f"{flag}: empty path")
    if out.exists() and not out.is_dir():
        raise UsageError(f"{flag} {out}: exists and is not a directory")
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    try:
        check_output_path(existing, flag, directory=True)
    except ValueError as e:
        raise UsageError(f"{flag} {out}: cannot be created: {str(e).removeprefix(f'{flag} ')}") from None


def _check_fresh_dir(out: Path) -> None:
    """A fresh run needs --out to be new or empty, and not in use by another run."""
    from .runlog import check_run_dir_free, holds_run_files

    if out.is_dir():
        check_run_dir_free(out)  # RunDirBusy: exit 1, before anything else is looked at
        if holds_run_files(out):
            raise UsageError(
                f"{out} exists and is not empty; add --resume to continue that run or choose another --out"
            )
    elif out.exists() or out.is_symlink():
        raise UsageError(f"{out} exists and is not a directory; choose another --out")
    check_out_dir(out)


def _claim_fresh_dir(out: Path) -> None:
    """Create --out and take its lock; then check again that it is empty (another fresh run may
    have started in it between `_check_fresh_dir` and here)."""
    from .runlog import holds_run_files

    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(f"--out {out}: cannot create the run directory ({e.strerror or e})") from None
    _claim(out)
    if holds_run_files(out):
        raise UsageError(f"{out} exists and is not empty; add --resume to continue that run or choose another --out")


def _claim(out: Path) -> None:
    """Take the run directory's lock for the rest of this process (runlog.lock_run_dir)."""
    from .runlog import lock_run_dir

    try:
        lock_run_dir(out)
    except PermissionError as e:
        raise UsageError(f"--out {out}: cannot write there ({e.strerror or e})") from None


def _check_sizes(cfg) -> None:
    """The same bounds on sizes as a checkpoint's (checkpoint._check_sizes), for the flags and
    presets together: e.g. --num-envs times --rollout-steps."""
    from .checkpoint import _check_sizes as check

    try:
        check(cfg, "the configuration")
    except ValueError as e:
        raise UsageError(str(e)) from None


def _start_fresh(args, explicit: dict, out: Path, argv: list[str]):
    from .curriculum import CurriculumConfig, WaypointCurriculum
    from .envs import make_config
    from .ppo import PPO, PRESETS, PPOConfig
    from .runlog import MetricsLog, write_json

    _check_fresh_dir(out)
    preset = args.preset or "fast"
    cfg = PPOConfig(**{**PRESETS[preset], **explicit})
    _check_sizes(cfg)
    env_kw = {"vehicle": args.vehicle} if args.vehicle else {}
    if getattr(args, "randomize", None):
        env_kw["randomization"] = args.randomize  # a preset name; make_config scales it to the vehicle
    env_kw.update(_sensor_env_kw(args))
    cur_cfg = CurriculumConfig() if args.task == "waypoint" else None
    if cur_cfg is not None:
        env_kw["target_radius"] = cur_cfg.radii[0]
    env_cfg = make_config(args.task, **env_kw)
    ppo = PPO(cfg, env_cfg)  # before any file is written: a failure here leaves no half-made run
    _claim_fresh_dir(out)
    write_json(
        out / "config.json",
        {
            "schema": "quadpilot.run/1",
            "task": args.task,
            "preset": preset,
            "ppo": cfg.to_json(),
            "env": env_cfg.to_json(),
            "curriculum": cur_cfg.to_json() if cur_cfg else None,
            "checkpoint_every": args.checkpoint_every,
            "snapshot_every": args.snapshot_every,
            "eval_episodes": args.eval_episodes,
            "command": _command(argv),
            "started": _now(),
            "resumes": [],
        },
    )
    MetricsLog(out / "metrics.csv").close()  # the header, so the file exists from the start
    cur = WaypointCurriculum(cur_cfg, cfg.num_envs, cfg.rollout_steps, env_cfg.episode_steps) if cur_cfg else None
    return ppo, cur, preset, 0.0, None


def _restore_curriculum(agent, extra: dict):
    """The waypoint curriculum a checkpoint's `extra` holds (None if the run has none), with the
    agent's environment set to the radius it had reached."""
    from .curriculum import CurriculumConfig, WaypointCurriculum

    if extra.get("curriculum") is None:
        return None
    state = extra["curriculum"]
    cfg = agent.cfg
    cur = WaypointCurriculum(
        CurriculumConfig.from_json(state["config"]), cfg.num_envs, cfg.rollout_steps, agent.env_cfg.episode_steps
    )
    cur.load_state_dict(state)
    agent.env.set_target_radius(cur.radius)
    return cur


def _record_resume(
    out: Path,
    argv: list[str],
    used: Path,
    updates: int,
    key: str,
    cfg_json: dict,
    columns: tuple[str, ...] | None = None,
) -> None:
    """A resume's bookkeeping: metrics.csv cut back to the checkpoint's `updates` (header
    `columns`, by default runlog.COLUMNS), and config.json's `key` configuration replaced and the
    resume appended to its "resumes". Raises UsageError if metrics.csv is not a file of this kind."""
    import json

    from .runlog import COLUMNS, truncate_metrics, write_json

    try:
        dropped = truncate_metrics(out / "metrics.csv", updates, columns or COLUMNS)
    except ValueError as e:
        raise UsageError(str(e)) from None
    config_path = out / "config.json"
    config = json.loads(config_path.read_text()) if config_path.exists() else {}
    config[key] = cfg_json
    config.setdefault("resumes", []).append(
        {
            "command": _command(argv),
            "from": used.name,
            "update": updates,
            "at": _now(),
            "metrics_rows_dropped": dropped,
        }
    )
    write_json(config_path, config)


def _check_resume_dir(out: Path) -> None:
    """--resume needs a run directory with a checkpoint that no other run holds; takes its lock."""
    from .checkpoint import has_checkpoint
    from .runlog import holds_run_files

    if out.exists() and not out.is_dir():
        raise UsageError(f"--resume: {out} is not a directory; --out names the run directory")
    if not out.is_dir() or not has_checkpoint(out):
        if out.is_dir() and holds_run_files(out):  # e.g. killed before its first update ended
            raise UsageError(f"--resume: {out} holds no checkpoint.pt; remove it or pick another --out to start afresh")
        raise UsageError(f"--resume: no checkpoint.pt in {out}; start the run without --resume")
    _claim(out)  # before reading: the checkpoint read is the one this run continues from


def _resume(args, explicit: dict, out: Path, argv: list[str]):
    from .checkpoint import load_for_resume, ppo_from_checkpoint
    from .ppo import PPOConfig

    _check_resume_dir(out)
    ckpt, used, warning = load_for_resume(out)  # CheckpointError: a bad file, exit 1 (main)
    if ckpt.get("algo", "ppo") != "ppo":
        raise UsageError(f"{out} holds a {ckpt['algo']} run; resume it with --algo {ckpt['algo']}")
    if warning:
        print(f"quad-train: warning: {warning}", file=sys.stderr)
    stored = PPOConfig.from_json(ckpt["ppo_config"])
    extra = ckpt["extra"]
    task = ckpt["env_config"]["task"]
    if args.task != task:
        raise UsageError(f"{out} holds a {task} run; --task {args.task} does not match it")
    clashes = [
        f"--{k.replace('_', '-')} {v} (checkpoint: {getattr(stored, k)})"
        for k, v in explicit.items()
        if k not in RESUME_MAY_CHANGE and v != getattr(stored, k)
    ]
    if args.preset and args.preset != extra.get("preset"):
        clashes.append(f"--preset {args.preset} (checkpoint: {extra.get('preset')})")
    clashes += _vehicle_clash(args, ckpt["env_config"])
    clashes += _randomize_clash(args, ckpt["env_config"])
    clashes += _sensor_clash(args, ckpt["env_config"])
    if clashes:
        raise UsageError(
            f"a resumed run keeps its configuration; only --total-steps and --threads may change: {', '.join(clashes)}"
        )
    cfg = dataclasses.replace(stored, **{k: v for k, v in explicit.items() if k in RESUME_MAY_CHANGE})
    if cfg.lr_schedule != "constant" and cfg.total_steps != stored.total_steps:
        print(
            f"quad-train: note: the {cfg.lr_schedule} learning-rate schedule runs over total_steps; from here on it "
            f"follows the new {cfg.total_steps:,} instead of {stored.total_steps:,}",
            file=sys.stderr,
        )
    ppo = ppo_from_checkpoint(ckpt, cfg, source=str(used))
    cur = _restore_curriculum(ppo, extra)
    _clean_stale_temps(out)
    _record_resume(out, argv, used, ppo.updates, "ppo", cfg.to_json())
    print(
        f"quad-train: resuming {out} from {used.name} at update {ppo.updates} ({ppo.global_step:,} steps)", flush=True
    )
    return ppo, cur, extra.get("preset"), float(extra.get("elapsed_s", 0.0)), extra.get("first_success")


def _train(args, argv: list[str]) -> int:
    from .checkpoint import POLICY, save_checkpoint, save_for_resume, save_snapshot
    from .ppo import PPOConfig
    from .runlog import MetricsLog, plot_curves

    explicit = {k: getattr(args, k) for k in PPO_OPTIONS if getattr(args, k) is not None}
    if args.arch:
        explicit["arch"] = args.arch
    seed = explicit.get("seed", PPOConfig.seed)
    out = Path(args.out or f"runs/{args.task}-seed{seed}")
    start = _resume if args.resume else _start_fresh
    ppo, cur, preset, elapsed0, first_success = start(args, explicit, out, argv)
    cfg = ppo.cfg
    t0 = time.perf_counter()
    eval_s = 0.0  # time spent in periodic evaluations: not training time

    def train_time() -> float:
        return elapsed0 + time.perf_counter() - t0 - eval_s

    def extra(metrics: dict | None) -> dict:
        return {
            "preset": preset,
            "curriculum": cur.state_dict() if cur else None,
            "metrics": metrics or {},
            "elapsed_s": train_time(),
            "first_success": first_success,
            "command": _command(argv),
        }

    last: dict | None = None
    saved_at = ppo.updates if args.resume else -1
    if args.snapshot_every and ppo.updates == 0:
        save_snapshot(out, ppo, extra(None))  # the untrained policy: where a learning montage starts
    label = f"quad-train {args.task}"
    progress = _Progress(label, ppo.global_step, cfg.num_updates * cfg.batch_size)
    try:
        with _Stop() as stop, MetricsLog(out / "metrics.csv") as log:
            while ppo.updates < cfg.num_updates and stop.signal is None:
                m = ppo.iterate()
                m["time_s"] = train_time()
                first_success, dt = _evaluate_and_advance(ppo, args, cur, m, first_success)
                eval_s += dt
                log.write(m)  # the row first: a kill before the save leaves a row the resume drops
                last = m
                if args.snapshot_every and (ppo.updates % args.snapshot_every == 0 or ppo.updates == cfg.num_updates):
                    save_snapshot(out, ppo, extra(m))  # before the checkpoint: a resume redoes it, never skips it
                if ppo.updates % args.checkpoint_every == 0 or ppo.updates == cfg.num_updates:
                    save_for_resume(out, ppo, extra(m))
                    saved_at = ppo.updates
                progress.update(m)
            if saved_at != ppo.updates:
                save_for_resume(out, ppo, extra(last))
    except KeyboardInterrupt:  # a second Ctrl-C: the last saved checkpoint stands
        progress.close()
        print(f"\nquad-train: aborted; the checkpoint of update {saved_at} in {out} is intact.", file=sys.stderr)
        print(f"Resume with: {_command(_resume_argv(argv))}", file=sys.stderr)
        return 130
    finally:
        progress.close()
    plot_curves(out / "metrics.csv", out / "curves.png", f"{args.task}, {out.name}", cur.cfg.radii if cur else ())
    if stop.signal is not None and ppo.updates < cfg.num_updates:
        print(
            f"quad-train: stopped by {stop.signal} after update {ppo.updates}/{cfg.num_updates}; "
            f"checkpoint saved in {out / 'checkpoint.pt'}.\nResume with: {_command(_resume_argv(argv))}",
            file=sys.stderr,
        )
        return 130
    save_checkpoint(out / POLICY, ppo, extra(last))
    summary = f"quad-train: done, {ppo.global_step:,} steps in {ppo.updates} updates; policy in {out / POLICY}"
    if args.eval_episodes:
        summary += _final_evaluation(
            ppo,
            args,
            cur,
            out,
            lambda: {
                "policy": POLICY,
                "global_step": ppo.global_step,
                "updates": ppo.updates,
                "train_time_s": extra(last)["elapsed_s"],
                "first_success": first_success,
                "time_breakdown_s": _time_breakdown(out / "metrics.csv"),
            },
        )
    print(summary, flush=True)
    return 0


SUCCESS_BAR = 0.95  # the bar: success rate over 100 deterministic episodes
SUCCESS_KEY = {"circle": "circle_success_rate"}  # hover and waypoint use evaluate()'s success_rate


def _evaluate_and_advance(agent, args, cur, m: dict, first_success: dict | None) -> tuple[dict | None, float]:
    """After an iteration of `agent` (PPO or SAC) with metrics row `m`: every --eval-every
    iterations, the deterministic evaluation into m's eval columns and, the first time it passes
    SUCCESS_BAR at the final curriculum stage, `first_success`; then the curriculum's stage into
    `m` and its advance on the iteration's episodes. Returns (first_success, seconds spent
    evaluating), the latter not counted as training time."""
    from .evaluate import evaluate

    eval_s = 0.0
    if args.eval_every and agent.updates % args.eval_every == 0:
        te = time.perf_counter()
        r = evaluate(agent.act_deterministic, _eval_config(agent, cur), episodes=args.eval_episodes or 100)
        eval_s = time.perf_counter() - te
        m["eval_success_rate"] = r[SUCCESS_KEY.get(args.task, "success_rate")]
        m["eval_error_m"] = r["mean_error_last_window_m"]
        final_stage = cur is None or cur.stage == len(cur.cfg.radii) - 1
        if first_success is None and final_stage and m["eval_success_rate"] >= SUCCESS_BAR:
            first_success = {
                "global_step": agent.global_step,
                "update": agent.updates,
                "train_time_s": m["time_s"],
                "success_rate": m["eval_success_rate"],
                "episodes": r["episodes"],
            }
    if cur is not None:
        m["curriculum_stage"], m["target_radius"] = cur.stage, cur.radius
        n = int(m["episodes"])
        if cur.observe(agent.ep_success[len(agent.ep_success) - n :] if n else []):
            agent.env.set_target_radius(cur.radius)
    return first_success, eval_s


def _final_evaluation(agent, args, cur, out: Path, meta) -> str:
    """The end-of-run evaluation of `agent` (PPO or SAC) over --eval-episodes episodes, written to
    eval.json after `meta()` (called once the evaluation is done, so its training time counts as
    before) and the curriculum's final stage; returns the summary line's evaluation clause."""
    from .evaluate import evaluate
    from .runlog import write_json

    result = evaluate(agent.act_deterministic, _eval_config(agent, cur), episodes=args.eval_episodes)
    info = meta()
    if cur is not None:
        info.update(curriculum_stage=cur.stage, target_radius=cur.radius)
    write_json(out / "eval.json", {**info, **result})
    return f"; evaluation: success {result['success_rate']:.0%} over {args.eval_episodes} episodes"


def _eval_config(ppo, cur):
    """The environment a policy is judged on: the training one, at the radius the waypoint
    curriculum has reached."""
    if cur is None:
        return ppo.env_cfg
    return dataclasses.replace(ppo.env_cfg, target_radius=cur.radius)


def _time_breakdown(metrics_path: Path, columns: tuple[str, ...] | None = None) -> dict:
    """Where the training time went, summed over every update in metrics.csv (header `columns`,
    by default runlog.COLUMNS): the environment (dynamics, observations, rewards, resets), policy
    inference and bookkeeping during rollouts, and the PPO update (GAE is in the rollout figure)."""
    from .runlog import COLUMNS, read_metrics

    m = read_metrics(metrics_path, columns or COLUMNS)
    parts = {k: float(np.nansum(m[k])) for k in ("env_s", "inference_s", "update_s")}
    total = sum(parts.values())
    return {**parts, "fractions": {k: (v / total if total else None) for k, v in parts.items()}}


def _resume_argv(argv: list[str]) -> list[str]:
    return argv if "--resume" in argv else [*argv, "--resume"]


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(argv)
        if args.out is not None and not args.out.strip():
            raise UsageError("--out: empty path; expected the run directory")
        if args.motor_tau is not None and not (math.isfinite(args.motor_tau) and args.motor_tau >= 0):
            raise UsageError(f"--motor-tau must be a finite number of seconds ≥ 0, got {args.motor_tau}")
        if args.algo == "sb3" and getattr(args, "randomize", None):
            raise UsageError("--randomize trains our PPO only; the SB3 comparison runs on the nominal plant")
        ours = ("--arch", args.arch, "--obs-history", args.obs_history, "--bptt-steps", args.bptt_steps)
        ours += ("--sensor-noise", args.sensor_noise, "--motor-tau", args.motor_tau)
        given = [ours[i] for i in range(0, len(ours), 2) if ours[i + 1] is not None]
        if args.algo != "ppo" and given:
            raise UsageError(f"{', '.join(given)}: options of our PPO (--algo ppo), not of --algo {args.algo}")
        if args.set and args.algo != "sac":
            raise UsageError("--set sets SAC hyper-parameters; it needs --algo sac")
        if args.snapshot_every and args.algo != "ppo":
            raise UsageError(f"--snapshot-every is for our PPO; --algo {args.algo} writes no snapshots")
        _resolve_vehicle(args)
        if ALGOS[args.algo] is not None:
            from importlib import import_module

            return import_module(f".{ALGOS[args.algo]}", __package__).train_from_cli(args, argv)
        return _train(args, argv)
    except SystemExit as e:  # --help
        return e.code if isinstance(e.code, int) else 0
    except UsageError as e:
        print(f"quad-train: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C before training started (during the training loop, see _Stop)
        print("\nquad-train: interrupted", file=sys.stderr)
        return 130
    except OSError as e:  # a write that failed (disk full, the run directory removed under us)
        where = f"{e.filename}: " if e.filename else ""
        print(f"quad-train: error: {where}{e.strerror or e}", file=sys.stderr)
        return 1
    except Exception as e:
        from quadpilot.core.vehicle_file import UnknownVehicleError, VehicleFileError

        from .checkpoint import CheckpointError
        from .ppo import NonFiniteError
        from .runlog import RunDirBusy

        if isinstance(e, UnknownVehicleError):  # --vehicle: neither a shipped name nor a file path
            print(f"quad-train: error: --vehicle: {e}", file=sys.stderr)
            return 2
        if isinstance(e, (CheckpointError, NonFiniteError, RunDirBusy, VehicleFileError)):
            print(f"quad-train: error: {e}", file=sys.stderr)
            return 1
        raise
    finally:
        from .runlog import release_run_dirs

        release_run_dirs()


if __name__ == "__main__":
    sys.exit(main())
