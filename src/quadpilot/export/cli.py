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
parity check.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

PARITY_TOLERANCE = 1e-5  # max abs difference in motor command (the export issue's bar)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        print(f"quad-export: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def main(argv: list[str] | None = None) -> int:
    from .onnx_export import DEFAULT_OPSET

    p = _Parser(prog="quad-export", description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1])
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
        choices=("onnx", "c"),
        default="onnx",
        help="onnx: an ONNX file with metadata. c: C99 source and header for a microcontroller. Default: onnx",
    )
    p.add_argument("--opset", type=int, default=DEFAULT_OPSET, help=f"ONNX opset version. Default: {DEFAULT_OPSET}")
    p.add_argument(
        "--parity-samples",
        type=int,
        default=10_000,
        metavar="N",
        help="Observations for the parity check (half rollouts, half range edges). Default: 10000",
    )
    try:
        args = p.parse_args(argv)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else 0
    if args.parity_samples < 2:
        print("quad-export: error: --parity-samples must be ≥ 2", file=sys.stderr)
        return 2
    if args.format == "c":
        return _main_c(args)
    out = args.output or args.checkpoint.with_suffix(".onnx")

    from quadpilot.train.checkpoint import CheckpointError

    from .onnx_export import check_parity, export_onnx

    try:
        meta = export_onnx(args.checkpoint, out, args.opset)
    except (CheckpointError, OSError) as e:
        print(f"quad-export: error: {e}", file=sys.stderr)
        return 2
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
    print(f"parity over {over} (max abs difference in motor command):")
    for k, v in parity.items():
        if k not in counts:
            print(f"  {k.replace('_', ' '):32s} {v:.2e}")
    if worst > PARITY_TOLERANCE:
        print(f"quad-export: error: parity {worst:.2e} exceeds {PARITY_TOLERANCE:g}", file=sys.stderr)
        return 1
    print(f"parity within {PARITY_TOLERANCE:g}: ok")
    return 0


def _main_c(args) -> int:
    import tempfile

    from quadpilot.runtime.cbackend import CCompilerError, CPolicy, build_library
    from quadpilot.runtime.model import ModelContractError
    from quadpilot.train.checkpoint import CheckpointError

    from .c_export import export_c
    from .onnx_export import check_parity

    out = args.output or args.checkpoint.with_name(f"{args.checkpoint.stem}_c")
    if out.exists() and not out.is_dir():
        print(
            f"quad-export: error: {out} exists and is not a directory (--format c writes a directory)", file=sys.stderr
        )
        return 2
    with tempfile.TemporaryDirectory(prefix="quad-export-") as tmp:
        onnx_path = Path(tmp) / "policy.onnx"
        try:
            exported = export_c(args.checkpoint, out, args.opset, onnx_path=onnx_path)
        except (CheckpointError, ModelContractError, OSError) as e:
            print(f"quad-export: error: {e}", file=sys.stderr)
            return 2
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
        return _report_parity(check_parity(args.checkpoint, onnx_path, args.parity_samples, extra_policies=extra))


if __name__ == "__main__":
    sys.exit(main())
