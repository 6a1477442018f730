"""quad-export: write a trained policy (policy.pt) as an ONNX file that flies as it is.

The graph holds observation normalisation, the deterministic action, clipping and the map to motor
commands in [0, 1] (PX4 HIL_ACTUATOR_CONTROLS convention); the file carries metadata and golden
vectors. After writing, it checks the file (onnx.checker, full check) and prints the parity of
PyTorch, ONNX Runtime and the training-side path on observations from real rollouts and from the
edges of the training range.

--format c writes the same policy as dependency-free C99 for a microcontroller instead: a
directory with policy.c (weights as static const float arrays, no heap, libm only) and policy.h
(the entry point, the observation layout and the output convention). It is generated from the
ONNX file exported first, and compiled with the system C compiler (if there is one) for the
parity check. --format px4-raptor writes, for a policy trained with quad-train --contract px4-raptor,
the policy.tar PX4's mc_raptor module loads from the SD card (docs/px4.md).

--target cortex-m4f|cortex-m7 also cross-compiles it with arm-none-eabi-gcc into a
bare-metal image (DIR/policy.elf) that checks the model's golden vectors when it boots and exits
through semihosting with status 0 only if they match; if qemu-system-arm is installed it is booted
once (mps2-an386 for the M4F, mps2-an500 for the M7) and the result printed.

Exit codes: 0 written and parity within tolerance; 1 the checkpoint cannot be used (malformed,
truncated, not a quadpilot checkpoint), or the export or its parity check failed; 2 a bad flag
(including a checkpoint path that does not exist, a policy.tar or ONNX file already exported, or an output that
cannot be written).
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

from quadpilot.console import Parser, UsageError, os_error_line

PARITY_TOLERANCE = 1e-5  # max abs difference in thrust command u², a fraction of full thrust (onnx_export.check_parity)
MAX_PARITY_SAMPLES = 1_000_000  # ~70 MB of observations; the default 10 000 takes seconds


class _BadFlag(Exception):
    """A flag value refused after parsing: exit code 2, one line."""


def _check_args(args) -> Path:
    """Refuse bad flag values before anything is loaded; returns the output path."""
    from quadpilot.console import check_output_path, input_path_problem

    from .onnx_export import OpsetError, check_opset

    try:
        check_opset(args.opset)
    except OpsetError as e:
        raise _BadFlag(f"--opset {args.opset}: {e}") from None
    if not 2 <= args.parity_samples <= MAX_PARITY_SAMPLES:
        raise _BadFlag(f"--parity-samples must be in 2..{MAX_PARITY_SAMPLES:,}, got {args.parity_samples:,}")
    ckpt = args.checkpoint
    if (why := input_path_problem(ckpt, "policy.pt (or checkpoint.pt) written by quad-train")) is not None:
        raise _BadFlag(why)
    from quadpilot.runtime.rltools_tar import is_policy_tar

    if is_policy_tar(ckpt):
        raise _BadFlag(
            f"{ckpt} is a PX4 mc_raptor policy.tar, already exported; fly it with quad-sitl {shlex.quote(str(ckpt))} "
            "(quad-export reads the policy.pt quad-train writes)"
        )
    if ckpt.suffix.lower() == ".onnx":
        pt = ckpt.with_suffix(".pt")
        source = f"; its checkpoint is {shlex.quote(str(pt))}" if pt.is_file() else ""
        raise _BadFlag(
            f"{ckpt} is an ONNX file, already exported; fly it with quad-sitl {shlex.quote(str(ckpt))} "
            f"(quad-export reads the policy.pt quad-train writes{source})"
        )
    if args.vehicle is not None:
        if args.format != "onnx":
            raise _BadFlag(f"--vehicle needs --format onnx (then export the .pt it writes with --format {args.format})")
        from quadpilot.core.vehicle_file import UnknownVehicleError, VehicleFileError, resolve_vehicle

        try:
            args.vehicle = resolve_vehicle(args.vehicle)
        except (UnknownVehicleError, VehicleFileError) as e:
            raise _BadFlag(f"--vehicle: {e}") from None
    if args.format == "c":
        out = args.output or ckpt.with_name(f"{ckpt.stem}_c")
    elif args.format == "px4-raptor":
        out = args.output or ckpt.parent
    elif args.vehicle is not None:  # <name>_<vehicle>.onnx and .pt beside the checkpoint, not over it
        out = args.output or ckpt.with_name(f"{ckpt.stem}_{_file_stem(args.vehicle.name)}.onnx")
    else:
        out = args.output or ckpt.with_suffix(".onnx")
    try:
        check_output_path(out, "--output", directory=args.format != "onnx")
    except ValueError as e:
        raise _BadFlag(str(e)) from None
    if args.target is not None and args.format != "c":
        raise _BadFlag(f"--target {args.target} needs --format c (it cross-compiles the C)")
    if out.resolve() == ckpt.resolve():
        if args.output is not None:
            raise _BadFlag(f"--output {out} is the checkpoint itself; name another file")
        raise _BadFlag(f"the default output {out} is the checkpoint itself; name another file with --output")
    if args.vehicle is not None:
        _check_retarget_output(out, ckpt)
    return out


def _file_stem(name: str) -> str:
    """A vehicle's name as part of a file name: letters, digits, '-' and '_' only."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name) or "vehicle"


def _check_retarget_output(out: Path, ckpt: Path) -> None:
    """--vehicle writes the retargeted policy as <output>.pt: never the ONNX file itself, never the
    checkpoint, never a file that is not an earlier retargeted policy."""
    pt = out.with_suffix(".pt")
    if out.suffix == ".pt":
        raise _BadFlag(f"--output {out}: with --vehicle the retargeted policy is written as {pt}; name a .onnx file")
    if pt.resolve() == ckpt.resolve():
        raise _BadFlag(f"--vehicle writes {pt}, which is the checkpoint itself; name another --output")
    if pt.exists() and not _is_retargeted(pt):
        raise _BadFlag(
            f"--vehicle writes {pt}, and {pt} exists and is not a retargeted policy; name another --output or move it"
        )


def _is_retargeted(path: Path) -> bool:
    """Whether `path` is a policy an earlier quad-export --vehicle wrote (then it may be replaced)."""
    from quadpilot.train.algorithms import load_checkpoint
    from quadpilot.train.runs.checkpoint import CheckpointError

    try:
        return "retargeted" in load_checkpoint(path).get("extra", {})
    except (CheckpointError, OSError):
        return False


def main(argv: list[str] | None = None) -> int:
    from .onnx_export import DEFAULT_OPSET

    p = Parser(prog="quad-export", description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("checkpoint", type=Path, help="policy.pt (or checkpoint.pt) written by quad-train")
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        help="ONNX file to write (--format c: the directory for policy.c and policy.h). "
        "Default: the checkpoint's name with .onnx (--format c: <name>_c/ beside the checkpoint)",
    )
    p.add_argument(
        "--format",
        choices=("onnx", "c", "px4-raptor"),
        default="onnx",
        help="onnx: an ONNX file with metadata. c: C99 source and header for a microcontroller. px4-raptor: for a "
        "policy from quad-train --contract px4-raptor, the policy.tar PX4's mc_raptor module loads (with its "
        ".sha256 and the same GRU as policy.onnx) in the --output directory (default: the checkpoint's). "
        "Default: onnx",
    )
    p.add_argument(
        "--target",
        choices=("cortex-m4f", "cortex-m7"),
        help="with --format c: also build a bare-metal image for this core (arm-none-eabi-gcc, hard float) that "
        "checks the golden vectors at boot, and boot it in QEMU if qemu-system-arm is installed. Default: none",
    )
    p.add_argument(
        "--opset",
        type=int,
        default=DEFAULT_OPSET,
        help=f"ONNX operator set version, one the exporter writes exactly and the runtime checks "
        f"(quadpilot.export.onnx_export.supported_opsets). Default: {DEFAULT_OPSET}",
    )
    p.add_argument(
        "--vehicle",
        metavar="NAME|FILE.toml",
        help="Fly a generalist policy (quad-train --randomize airframes) on this airframe, retrained in nothing: "
        "its hover command goes into the graph, its rotor order into the action head "
        "(quadpilot.train.ppo.retarget); the retargeted policy is written beside the ONNX file as <name>.pt "
        "(default output: <checkpoint>_<vehicle>.onnx). Default: the policy's own vehicle",
    )
    p.add_argument(
        "--parity-samples",
        type=int,
        default=10_000,
        metavar="N",
        help=f"Observations for the parity check (half rollouts, half range edges), 2 to {MAX_PARITY_SAMPLES:,}. "
        "Default: 10000",
    )
    try:
        args = p.parse_args(argv)
    except UsageError as e:
        print(f"quad-export: error: {e}", file=sys.stderr)
        return 2
    except SystemExit as e:  # --help
        return e.code if isinstance(e.code, int) else 0
    try:
        out = _check_args(args)
    except _BadFlag as e:
        print(f"quad-export: error: {e}", file=sys.stderr)
        return 2
    if args.target is not None:
        from quadpilot.ccode.target import CC, CrossToolError, require_tool

        try:
            require_tool(CC)
        except CrossToolError as e:
            print(f"quad-export: error: --target {args.target}: {e}", file=sys.stderr)
            return 1
    aside = None  # --vehicle: (the ONNX file's stat before, the earlier retargeted policy set aside)
    try:
        if args.format == "px4-raptor":
            return _main_px4_raptor(args, out)
        if args.vehicle is not None:
            aside = _set_aside(out)
            args.checkpoint = _retargeted(args, out)
        from quadpilot.train.raptor.distill import CONTRACT, is_student_checkpoint

        if is_student_checkpoint(args.checkpoint):
            print(
                f"quad-export: error: {args.checkpoint} is a {CONTRACT} policy (quad-train --contract {CONTRACT}); "
                f"export it with --format {CONTRACT} (it writes policy.tar and the same GRU as policy.onnx)",
                file=sys.stderr,
            )
            return 1
        return _main_c(args, out) if args.format == "c" else _main_onnx(args, out)
    except Exception as e:  # one line, exit 1, for what the checks let through (see _failure)
        if aside is not None:
            _put_back(out, *aside)
            aside = None
        message = _failure(e)
        if message is None:
            raise
        print(f"quad-export: error: {message}", file=sys.stderr)
        return 1
    finally:
        if aside is not None and aside[1] is not None:  # the ONNX file names the new one
            aside[1].unlink(missing_ok=True)


def _stat(path: Path):
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_ino, st.st_mtime_ns, st.st_size)


def _set_aside(out: Path) -> tuple:
    """Before --vehicle writes <output>.pt: the ONNX file's stat, and the earlier .pt moved aside
    (None if there was none), so that a failed export can leave the pair as it found it."""
    pt = out.with_suffix(".pt")
    if not pt.exists():
        return _stat(out), None
    kept = pt.with_name(pt.name + ".prev")
    pt.replace(kept)
    return _stat(out), kept


def _put_back(out: Path, onnx_before, kept: Path | None) -> None:
    """The export failed: if the ONNX file is the one from before (or still none), the retargeted
    policy goes back to what that file names (or away); a new ONNX file keeps the new policy."""
    pt = out.with_suffix(".pt")
    if _stat(out) != onnx_before:
        if kept is not None:
            kept.unlink(missing_ok=True)
        return
    pt.unlink(missing_ok=True)
    if kept is not None:
        kept.replace(pt)


def _retargeted(args, out: Path) -> Path:
    """Write the policy retargeted to --vehicle as <output>.pt and return its path."""
    import torch

    from quadpilot.atomic_files import atomic_write
    from quadpilot.train.algorithms import load_checkpoint
    from quadpilot.train.ppo.retarget import retarget_checkpoint

    vehicle = args.vehicle  # a VehicleParams by now (_check_args)
    data = retarget_checkpoint(load_checkpoint(args.checkpoint), vehicle, str(args.checkpoint))
    path = out.with_suffix(".pt")
    atomic_write(path, lambda f: torch.save(data, f))
    done = data["extra"]["retargeted"]
    order = " ".join(str(i + 1) for i in done["rotor_order"])
    trim = "" if done["hover_trim"] is None else ", hover trim " + " ".join(f"{t:+.3f}" for t in done["hover_trim"])
    what = f"rotors driven by outputs {order}{trim}"
    print(f"quad-export: {args.checkpoint} retargeted to {vehicle.name} ({what}): {path}")
    return path


def _failure(e: Exception) -> str | None:
    """The one-line message for an export that failed on its input or its output, None for a bug."""
    from quadpilot.modelfile.model import ModelContractError
    from quadpilot.runtime.rltools_tar import PolicyTarError
    from quadpilot.train.ppo.retarget import RetargetError
    from quadpilot.train.raptor.distill import StudentCheckpointError
    from quadpilot.train.runs.checkpoint import CheckpointError

    if isinstance(e, (CheckpointError, ModelContractError, StudentCheckpointError, PolicyTarError, RetargetError)):
        return str(e)
    if isinstance(e, OSError):
        return os_error_line(e)
    if isinstance(e, RuntimeError) and "operator set" in str(e):  # export_onnx's opset check
        return str(e)
    return None


def _main_onnx(args, out: Path) -> int:
    from .onnx_export import check_parity, export_onnx

    meta = export_onnx(args.checkpoint, out, args.opset)
    print(
        f"quad-export: wrote {out} ({out.stat().st_size / 1024:.1f} KiB; task {meta['quadpilot.task']}, "
        f"{int(meta['quadpilot.training_steps']):,} training steps, opset {args.opset}); onnx.checker: ok"
    )
    return _report_parity(check_parity(args.checkpoint, out, args.parity_samples))


def _report_parity(parity: dict) -> int:
    counts = ("observations", "sequences")
    worst = max(v for k, v in parity.items() if k not in counts)
    over = f"{parity['observations']:,} observations"
    if "sequences" in parity:
        over += f" in {parity['sequences']} sequences with a state reset half-way"
    print(f"parity over {over} (max abs difference in thrust command, a fraction of full thrust):")
    for k, v in parity.items():
        if k not in counts:
            print(f"  {k.replace('_', ' '):32s} {v:.2e}")
    if worst > PARITY_TOLERANCE:
        print(f"quad-export: error: parity {worst:.2e} exceeds {PARITY_TOLERANCE:g}", file=sys.stderr)
        return 1
    print(f"parity within {PARITY_TOLERANCE:g}: ok")
    return 0


def _main_px4_raptor(args, out: Path) -> int:
    from .px4_raptor_export import export_px4_raptor

    e = export_px4_raptor(args.checkpoint, out)
    print(
        f"quad-export: wrote {e.tar} ({e.tar.stat().st_size / 1024:.1f} KiB, mc_raptor's policy type, checkpoint name "
        f"{e.checkpoint_name!r}), {e.tar.name}.sha256 ({e.sha256[:16]}...) and {e.onnx.name}; the stored example "
        "replays (mc_raptor's test_policy)"
    )
    print("upload: mavproxy.py --master=... then ftp put policy.tar /fs/microsd/raptor/policy.tar (docs/px4.md)")
    return _report_parity(e.parity)


def _main_c(args, out: Path) -> int:
    import tempfile

    from quadpilot.runtime.cbackend import CCompilerError, CPolicy, build_library

    from .c_export import export_c
    from .onnx_export import check_parity

    with tempfile.TemporaryDirectory(prefix="quad-export-") as tmp:
        onnx_path = Path(tmp) / "policy.onnx"
        exported = export_c(args.checkpoint, out, args.opset, onnx_path=onnx_path)
        info, net = exported.info, exported.code.network
        weights = sum(a.size for a in net.arrays().values())
        print(
            f"quad-export: wrote {exported.source} ({exported.source.stat().st_size / 1024:.1f} KiB) and "
            f"{exported.header.name} (task {info.task}, {info.training_steps:,} training steps; "
            f"{weights:,} float32 constants = {4 * weights / 1024:.1f} KiB of flash)"
        )
        extra = {}
        try:
            policy = CPolicy(info, exported.code, build_library(exported.code))
            worst = policy.verify_golden()
            print(f"compiled with the system C compiler ({policy.library.parent}); golden vectors: {worst:.2e}")
            extra["c"] = policy
        except CCompilerError as e:
            print(f"quad-export: note: the C was written but not compiled here, so its parity is not checked: {e}")
        status = _report_parity(check_parity(args.checkpoint, onnx_path, args.parity_samples, extra_policies=extra))
    if args.target is not None and status == 0:
        status = _cross_build(exported, out, args.target)
    return status


def _cross_build(exported, out: Path, target: str) -> int:
    """--target: the bare-metal image, its footprint, and one boot in QEMU where it is installed."""
    from quadpilot.ccode import target as ctarget

    try:
        image = ctarget.build_image(exported.code, exported.info, out, target)
    except ctarget.CrossToolError as e:
        print(f"quad-export: error: --target {target}: {e}", file=sys.stderr)
        return 1
    parts = ctarget.footprint(image)
    flash = sum(sum(parts[s].values()) for s in (".text", ".rodata", ".ARM.exidx", ".data"))
    policy = sum(parts[s].get("policy", 0) for s in (".text", ".rodata"))
    ram = sum(sum(parts[s].values()) for s in (".data", ".bss"))
    print(
        f"built {image.elf} for the {image.target.core} ({' '.join(image.target.flags)}): flash {flash:,} B "
        f"(policy.c {policy:,} B), static RAM {ram:,} B"
    )
    if ctarget.find_tool(ctarget.QEMU) is None:
        print(f"note: {ctarget.QEMU} not found, the image was not booted here ({ctarget.APT_INSTALL})")
        return 0
    try:
        run = ctarget.run_image(image)
    except ctarget.CrossToolError as e:
        print(f"quad-export: error: {e}", file=sys.stderr)
        return 1
    if run.status != 0:
        print(
            f"quad-export: error: the image exits with status {run.status} in QEMU {image.target.machine}: "
            f"{run.console.strip()[:200]}",
            file=sys.stderr,
        )
        return 1
    print(f"booted in QEMU {image.target.machine}: golden vectors reproduced (exit status 0)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
