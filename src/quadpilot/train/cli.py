"""quad-train: train a quadrotor policy with PPO (feed-forward or recurrent) or SAC, with checkpoints
that survive Ctrl-C and kill -9.

Writes into the run directory (default runs/<task>-seed<S>; runs/<task>-sac-seed<S> for SAC):
  config.json         algorithm, environment and curriculum configuration, preset, command line(s)
  metrics.csv         one row per iteration (a PPO update; fixed header), flushed as each ends
  checkpoint.pt       latest resumable state (checkpoint.prev.pt: the one before it; SAC: and replay/)
  policy.pt           final deployable checkpoint (what quad-export reads)
  eval.json           deterministic evaluation of the final policy
  curves.png          episode return, length, success rate (and curriculum stage) against steps
  snapshots/          with --snapshot-every N: policy-<steps>.pt, the deployable policy at 0 steps,
                      every N updates and at the end (python -m quadpilot.studies.learning_montage draws them)

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
import inspect
import itertools
import sys
import textwrap

from quadpilot.console import Parser, UsageError, docs_quick, positive_float, quick

from .runs.options import (
    PPO_NETWORK_OPTIONS,
    PPO_UPDATE_OPTIONS,
    SIZE_OPTIONS,
    check_heading_offset,
    check_motor_tau,
    resolve_vehicle_arg,
    upper_bounds,
)

QUICK_TOTAL_STEPS, QUICK_EVAL_EPISODES = 2048, 2
"""Under QUADPILOT_DOCS_QUICK: at most one small rollout of training and two evaluation episodes."""

ALGOS = ("ppo", "sb3", "sac")
"""--algo: our PPO, a comparison baseline from another library trained on the same environment with
settings matched to the PPO preset (`sb3_baseline`), or our SAC."""


def field_docs(cls) -> dict[str, str]:
    """The docstring under each field of a dataclass (docs/architecture.md style 1: it becomes --help)."""
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


def int_at_least(lo: int, hi: int = 2**62):
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


def build_parser() -> argparse.ArgumentParser:
    from quadpilot.core.vehicle_file import shipped_names

    from .envs import TASKS
    from .ppo import PRESETS, PPOConfig

    docs = field_docs(PPOConfig)
    defaults = PPOConfig()
    p = Parser(
        prog="quad-train",
        description=__doc__.split("\n\n")[0],
        epilog="\n\n".join(__doc__.split("\n\n")[1:]),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        allow_abbrev=False,
    )
    p.add_argument(
        "--task", required=True, choices=TASKS, help="What to learn: hover, waypoint (with curriculum), circle."
    )
    upper = upper_bounds()
    for name, (metavar, lo) in SIZE_OPTIONS.items():
        doc = docs.get(name, "").replace("%", "%%")
        p.add_argument(
            "--" + name.replace("_", "-"),
            type=int_at_least(lo, upper[name]),
            metavar=metavar,
            help=f"{doc} Default: the preset's, else {getattr(defaults, name)}.",
        )
    p.add_argument(
        "--epochs",
        type=int_at_least(1, 1000),
        metavar="K",
        help=f"PPO (ppo, sb3): passes over each rollout per update. Default: the preset's, else {defaults.epochs}.",
    )
    p.add_argument(
        "--lr",
        type=positive_float,
        metavar="LR",
        help=f"PPO (ppo, sb3): Adam's learning rate (at the start, if annealed). Default: the preset's, else "
        f"{defaults.lr:g}.",
    )
    p.add_argument(
        "--lr-schedule",
        choices=("constant", "linear"),
        help="PPO (ppo, sb3): constant, or linear (annealed to 0 over --total-steps). Default: the preset's, else "
        f"{defaults.lr_schedule}.",
    )
    p.add_argument(
        "--algo",
        choices=ALGOS,
        default="ppo",
        help="Who learns: ppo (ours; recurrent with --arch lstm), sb3 (Stable-Baselines3 PPO with settings matched "
        "to the preset, for comparison; needs the dev extra) or sac (our Soft Actor-Critic, quadpilot.train.sac; "
        "--rollout-steps is then vector steps per iteration, a metrics row, and --minibatch-size the "
        "transitions per gradient step). Every option works with every algorithm but for those that say "
        "otherwise. Default: ppo.",
    )
    p.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        help="PPO hyper-parameter preset (ppo, sb3): fast (batched PPO tuned here), seed001 (the ENPM 667 recipe) "
        "or sb3_defaults (Stable-Baselines3 PPO's defaults). Options given explicitly override it. Default: fast.",
    )
    p.add_argument(
        "--vehicle",
        metavar="NAME|FILE.toml",
        help=f"Airframe: a shipped vehicle ({', '.join(shipped_names())}; quadpilot/vehicles/*.toml) or a vehicle "
        "file of the same schema (quadpilot.core.vehicle_file). It travels with the policy (checkpoint, ONNX "
        "metadata). Default: seed.",
    )
    p.add_argument(
        "--contract",
        choices=("px4-raptor",),
        help="Train a policy for a flight controller's fixed contract: px4-raptor, the policy PX4's mc_raptor "
        "module loads (dense 22-16, GRU 16, dense 16-4; its 22 inputs and 4 motor outputs), distilled from "
        "an MLP hover teacher (--teacher, else the shipped one of the vehicle, else one trained first). "
        "Then quad-export --format px4-raptor writes its policy.tar. Default: none (our own layouts).",
    )
    p.add_argument(
        "--teacher",
        metavar="FILE",
        help="--contract px4-raptor: the quad-train policy.pt (MLP, hover, the same vehicle) to distill.",
    )
    _add_randomize_option(p)
    _add_sensor_options(p)
    p.add_argument(
        "--out", metavar="DIR", help="Run directory. Default: runs/<task>-seed<S> (SAC: runs/<task>-sac-seed<S>)."
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="Continue the run in DIR from checkpoint.pt (or checkpoint.prev.pt if that is unreadable). "
        "Only --total-steps and --threads may differ from the original run.",
    )
    p.add_argument(
        "--init-from",
        metavar="POLICY.pt",
        help="Start the network from this PPO policy (policy.pt or a checkpoint): its shape, weights (action head in "
        "this vehicle's rotor order) and observation statistics; optimiser, schedule and seed are this run's "
        "(quadpilot.train.ppo.init_from). For fine-tuning a generalist (--randomize airframes) on one --vehicle. "
        "Default: a fresh network",
    )
    p.add_argument(
        "--eval-episodes",
        type=int_at_least(0, upper["num_envs"]),  # evaluated as one batch of drones
        default=100,
        metavar="N",
        help="Deterministic evaluation episodes of the final policy written to eval.json (0: skip). Default: 100.",
    )
    p.add_argument(
        "--eval-every",
        type=int_at_least(0),
        default=10,
        metavar="N",
        help="Also evaluate the deterministic policy every N updates (--eval-episodes episodes, 100 if that is 0; "
        "logged as eval_success_rate in metrics.csv; its time is not counted as training time) and record in "
        "eval.json the steps and training seconds at which success first reached 95 %%. 0: never. Default: 10.",
    )
    p.add_argument(
        "--checkpoint-every",
        type=int_at_least(1),
        default=1,
        metavar="N",
        help="Save checkpoint.pt every N updates (and always at the end and on Ctrl-C); a kill loses at most "
        "N updates. Default: 1 (a save costs milliseconds).",
    )
    p.add_argument(
        "--snapshot-every",
        type=int_at_least(0),
        default=0,
        metavar="N",
        help="Keep the policy every N updates (and at 0 steps and at the end) as snapshots/policy-<steps>.pt "
        "(not --algo sb3), "
        "a small deployable file like policy.pt (~50 kB for PPO's default network), for "
        "python -m quadpilot.studies.learning_montage. 0: none. Default: 0.",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="NAME=VALUE",
        help="Set a hyper-parameter of the algorithm: a field of quadpilot.train.ppo.PPOConfig (ppo, sb3) or "
        "quadpilot.train.sac.SACConfig (sac), e.g. ent_coef=0.01, updates_per_step=4, critic_hidden=128,128, "
        "autotune_alpha=false; repeatable; it wins over the preset and the other flags.",
    )
    return p


# --- environment options --------------------------------------------------------------------


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
        "params (the same without wind), pushes (default plus random pushes) or airframes (a new airframe every "
        "episode, 25 g to 3 kg, quadpilot.core.randomization.AIRFRAMES, its plant off its file by mass ±30 %%, k_f "
        "±20 %%: a generalist, which quad-export --vehicle FILE then exports for any quad-X). The policy observes "
        "nothing new and keeps the nominal hover command (airframes: the drawn file's). Without PRESET: default. "
        "Default: off.",
    )


def _add_sensor_options(p: argparse.ArgumentParser) -> None:
    from quadpilot.core.sensor_noise import SENSOR_NOISE_PRESETS

    p.add_argument(
        "--arch",
        choices=("mlp", "lstm"),
        help="PPO's network (ppo only, as --obs-history and --bptt-steps): mlp (two tanh layers each for actor "
        "and critic) or lstm (one LSTM layer each, trained "
        "on sequences with the hidden state reset at episode starts; quadpilot.train.ppo.recurrent). Default: "
        "the preset's, else mlp.",
    )
    p.add_argument(
        "--update",
        choices=("numpy", "torch"),
        help="How PPO computes its update and the rollout's forward passes (ppo only): numpy (the loss, its "
        "hand-written gradient, the gradient clip and Adam in NumPy, quadpilot.train.ppo.numpy_ppo; --arch mlp "
        "only) or torch (autograd and torch.optim.Adam, the reference). The two agree to float32 rounding, "
        "not bit for bit. Default: numpy for mlp, torch for lstm.",
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
    p.add_argument(
        "--reward",
        action="append",
        metavar="NAME=VALUE",
        help="Set a weight or limit of the reward: a field of quadpilot.core.reward.RewardConfig, e.g. "
        "heading_sigma=0.5; repeatable; on top of the task's own reward. Default: the task's.",
    )
    p.add_argument(
        "--timing",
        metavar="PRESET",
        help="The loop's timing in training (quadpilot.core.timing): per episode an action delay, an observation "
        "delay and a jitter are drawn per drone and applied at the control rate. link: delays of 0-30 ms each way "
        "and up to ±10 ms of jitter, what a radio link, an estimator and an ESC add; none: the state of now and a "
        "command that acts now. --action-delay, --obs-delay and --jitter change one range. Default: link.",
    )
    for flag, what in (
        ("--action-delay", "from the policy's output to the rotors"),
        ("--obs-delay", "age of the state the policy sees"),
        ("--jitter", "per-step spread of both delays, ±"),
    ):
        p.add_argument(
            flag,
            metavar="MS[:MS]",
            help=f"Milliseconds {what}: one value, or a range drawn per episode (e.g. 0:30); overrides --timing's.",
        )
    p.add_argument(
        "--init-rotor",
        choices=("hover", "rest", "random"),  # train.envs.INIT_ROTOR (not imported: --help stays torch-free)
        help="Rotor speeds at the start of an episode: hover (at the hover command), rest (stopped, as a "
        "drone whose motors were just armed; with a motor lag the policy must spin them up) or random "
        "(uniform between the two, per rotor). Default: hover.",
    )
    p.add_argument(
        "--heading-offset",
        type=float,
        metavar="DEG",
        help="Commanded heading of an episode: its start yaw plus an offset uniform in ±DEG (0 to 180), so the "
        "policy learns to turn to a heading as well as to hold one. Default: 30 (0 with --obs-version 1).",
    )
    p.add_argument(
        "--obs-version",
        type=int,
        choices=(1, 2),
        help="2: the policy sees its attitude relative to the commanded heading and is paid for holding it "
        "(quadpilot.core.observation); 1: world-frame attitude and no heading term, as policies trained before "
        "hover success included yaw (to reproduce one). Default: 2.",
    )


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(argv)
        if docs_quick():  # the documentation's commands run as a smoke test (console.docs_quick)
            args.total_steps = quick(args.total_steps, QUICK_TOTAL_STEPS)
            args.eval_episodes = quick(args.eval_episodes, QUICK_EVAL_EPISODES)
        if args.out is not None and not args.out.strip():
            raise UsageError("--out: empty path; expected the run directory")
        check_motor_tau(args)
        check_heading_offset(args)
        given = [f"--{k.replace('_', '-')}" for k in PPO_NETWORK_OPTIONS if getattr(args, k) is not None]
        if args.algo != "ppo" and given:
            raise UsageError(f"{', '.join(given)}: options of our PPO (--algo ppo), not of --algo {args.algo}")
        given = [f"--{k.replace('_', '-')}" for k in PPO_UPDATE_OPTIONS if getattr(args, k) is not None]
        if args.algo == "sac" and given:
            raise UsageError(f"{', '.join(given)}: PPO's update settings, not SAC's (use --set NAME=VALUE)")
        if args.algo == "sac" and args.preset:
            raise UsageError(
                "--preset chooses a PPO recipe; --algo sac takes SACConfig's defaults and --set NAME=VALUE"
            )
        if args.snapshot_every and args.algo == "sb3":
            raise UsageError("--snapshot-every is for our PPO and SAC; --algo sb3 writes no snapshots")
        resolve_vehicle_arg(args)
        if args.vehicle is not None and args.randomize == "airframes":  # its rotor aerodynamics would go to every draw
            raise UsageError(
                "--vehicle with --randomize airframes: the training draws every episode's airframe itself; "
                "train without --vehicle, then export for a vehicle with quad-export --vehicle FILE"
            )
        if args.init_from is not None and (args.resume or args.contract is not None or args.algo != "ppo"):
            why = (
                "a resumed run continues from its own checkpoint"
                if args.resume
                else "the contract distils its own"
                if args.contract is not None
                else f"not --algo {args.algo}"
            )
            raise UsageError(f"--init-from starts a fresh run of our PPO; {why}")
        if args.teacher is not None and args.contract is None:
            raise UsageError("--teacher is for --contract px4-raptor (the policy distilled from it)")
        if args.contract is not None:
            from .algorithms import ALGORITHMS
            from .raptor import cli as raptor_cli

            return raptor_cli.train_from_cli(args, argv, ALGORITHMS)
        if args.algo == "sb3":
            from . import sb3_baseline

            return sb3_baseline.train_from_cli(args, argv)
        from .algorithms import ALGORITHMS
        from .runs.loop import train

        return train(args, argv, ALGORITHMS)
    except SystemExit as e:  # --help
        return e.code if isinstance(e.code, int) else 0
    except UsageError as e:
        print(f"quad-train: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C before training started (during the training loop, see run.Stop)
        print("\nquad-train: interrupted", file=sys.stderr)
        return 130
    except OSError as e:  # a write that failed (disk full, the run directory removed under us)
        where = f"{e.filename}: " if e.filename else ""
        print(f"quad-train: error: {where}{e.strerror or e}", file=sys.stderr)
        return 1
    except Exception as e:
        from quadpilot.core.vehicle_file import UnknownVehicleError, VehicleFileError

        from .runs.checks import CheckpointError
        from .runs.runlog import RunDirBusy
        from .runs.trainer import NonFiniteError

        if isinstance(e, UnknownVehicleError):  # --vehicle: neither a shipped name nor a file path
            print(f"quad-train: error: --vehicle: {e}", file=sys.stderr)
            return 2
        from .raptor.distill import StudentCheckpointError

        if isinstance(e, (CheckpointError, NonFiniteError, RunDirBusy, VehicleFileError, StudentCheckpointError)):
            print(f"quad-train: error: {e}", file=sys.stderr)
            return 1
        raise
    finally:
        from .runs.runlog import release_run_dirs

        release_run_dirs()


if __name__ == "__main__":
    sys.exit(main())
