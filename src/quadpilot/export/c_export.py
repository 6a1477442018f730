"""`quad-export --format c`: the policy as dependency-free C99 (policy.c, policy.h) for a flight
controller's microcontroller.

There is one path from a checkpoint to C, through the ONNX file: the checkpoint is exported with
`export_onnx` (the deployable module: normalisation, network, action clip and motor map), that
file's contract is checked (`modelfile.model.read_model`), and `ccode.generate.generate` writes the C
from the file's initializers and metadata. It is the generator the runtime's `c` backend runs on a
`.onnx` file, fed the same data, so the C cannot drift from the ONNX file: its weights are the
file's float32 initializers, the header's facts (observation layout, output convention, control
period, vehicle, task, source checkpoint SHA-256, envelope) the file's metadata.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from quadpilot.ccode.generate import CCode, generate, initializers
from quadpilot.modelfile.model import ModelInfo, read_model

from .onnx_export import DEFAULT_OPSET, export_onnx


@dataclass(frozen=True)
class CExport:
    header: Path
    source: Path
    info: ModelInfo
    """The metadata of the ONNX file the C was generated from."""
    code: CCode


def c_from_onnx(onnx_path: str | os.PathLike, out_dir: str | os.PathLike) -> CExport:
    """Check an exported ONNX file's contract and write its C (policy.h, policy.c) into `out_dir`."""
    model, info = read_model(onnx_path)
    code = generate(info, initializers(model))
    header, source = code.write(out_dir)
    return CExport(header, source, info, code)


def export_c(
    checkpoint: str | os.PathLike,
    out_dir: str | os.PathLike,
    opset: int = DEFAULT_OPSET,
    onnx_path: str | os.PathLike | None = None,
) -> CExport:
    """Export `checkpoint` to ONNX (to `onnx_path`, or a temporary file) and write the C of that
    file into `out_dir`. Raises CheckpointError for a checkpoint that cannot be used."""
    if onnx_path is not None:
        export_onnx(checkpoint, onnx_path, opset)
        return c_from_onnx(onnx_path, out_dir)
    with tempfile.TemporaryDirectory(prefix="quad-export-") as tmp:
        path = Path(tmp) / "policy.onnx"
        export_onnx(checkpoint, path, opset)
        return c_from_onnx(path, out_dir)
