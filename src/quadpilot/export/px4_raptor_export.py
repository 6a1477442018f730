"""`quad-export --format px4-raptor policy.pt`: the file PX4's mc_raptor module loads, from a policy
trained with `quad-train --contract px4-raptor`.

Writes, beside each other (OUT defaults to the checkpoint's folder):
- policy.tar: RLtools' checkpoint layout of mc_raptor's policy type (`runtime.rltools_tar`): the
  weights, and the example mc_raptor's `Raptor::test_policy` replays, 2 sequences of 500 steps: the
  contract's observations of two flights of this policy in our simulator from seeded starts (the
  plant in float64, the observations rounded to multiples of 2^-12 as the policy flies,
  `EXAMPLE_GRID`), and the policy's outputs on them, the policy computed by
  `runtime.gru.PortableStep` (float64 in one fixed order, no BLAS or libm, rounded to float32), so
  that the bytes depend neither on torch nor on the CPU's BLAS kernels or SIMD level. The same
  policy gives the same bytes on any machine.
- policy.tar.sha256 (`sha256sum -c` reads it): to compare with the file after the upload.
- vehicle.toml: the vehicle it was trained for, which quad-sitl flies it on unless --vehicle says
  otherwise (policy.tar names no airframe).
- policy.onnx: the same step as ONNX with explicit state (obs, h_in → action, h_out; the learned
  initial state in the metadata `quadpilot.initial_hidden_state`), for ONNX Runtime.
Then it checks parity: torch (the trained network), the runtime's NumPy step, ONNX Runtime, and the
file read back through the runtime's reader (`rltools_tar.read_policy_tar`, which replays all of the
example), on the example's 1,000 steps run as sequences from the initial state.
"""

from __future__ import annotations

import dataclasses
import json
import warnings
from pathlib import Path

import numpy as np
import torch

from quadpilot.atomic_files import atomic_write
from quadpilot.core import px4_raptor
from quadpilot.core.vehicle_file import vehicle_to_toml
from quadpilot.runtime import gru, rltools_tar
from quadpilot.runtime.raptor import VEHICLE_BESIDE
from quadpilot.train.envs import EnvConfig
from quadpilot.train.raptor.distill import StudentCheckpointError, fly, load_student, numpy_policy

EXAMPLE_SEED = 2025
"""Seed of the two flights the example is taken from."""
EXAMPLE_GRID = 2.0**-12
"""The example flights' observations are rounded to multiples of this before the policy sees them.
The flights' plant runs in float64 (training's float32 plant takes NumPy's float32 sin and cos,
whose last bits follow the CPU's SIMD level), and NumPy's float64 functions may still differ in a
last bit between machines; on this grid such a difference changes an observation only when a
value lies within it of a rounding boundary (a chance of some 1e-12 each). The policy step itself
(`gru.PortableStep`) is the same everywhere, so the flights and the file are."""


@dataclasses.dataclass(frozen=True)
class Exported:
    tar: Path
    sha256: str
    onnx: Path
    parity: dict
    checkpoint_name: str


def checkpoint_name(ckpt: dict) -> str:
    """The name mc_raptor logs for the file: the vehicle and the contract, within RLtools' characters."""
    vehicle = str(ckpt.get("env_config", {}).get("vehicle", {}).get("name", "vehicle"))
    name = "".join(c if c.isalnum() or c in "_.+-" else "_" for c in vehicle)[:60] or "vehicle"
    return f"quadpilot/{name}/px4-raptor"


def example(weights: dict, cfg: EnvConfig) -> tuple[np.ndarray, np.ndarray]:
    """(input (500, 2, 22), output (500, 2, 4)): two flights of the policy, and its outputs on them,
    the policy computed by `gru.PortableStep` (no BLAS: the same bits on any machine)."""
    step = gru.PortableStep(weights)
    policy = numpy_policy(step)

    def on_grid(x: np.ndarray, h):
        # x is the flight's row of observations (fly's xs[t]): rounded in place, so that the example
        # holds what the policy saw; every operation here is exact
        np.multiply(np.rint(x * np.float32(1 / EXAMPLE_GRID)), np.float32(EXAMPLE_GRID), out=x)
        return policy(x, h)

    cfg = dataclasses.replace(cfg, episode_steps=rltools_tar.EXAMPLE_STEPS, dtype="float64")
    xs = fly(on_grid, cfg, rltools_tar.EXAMPLE_BATCH, np.random.default_rng(EXAMPLE_SEED))["obs"]
    return xs, gru.sequences(step, xs)


def export_px4_raptor(checkpoint: Path, out_dir: Path) -> Exported:
    """Write policy.tar, its SHA-256 and policy.onnx into out_dir (see the module docstring)."""
    student, ckpt = load_student(checkpoint)
    weights = student.weights()
    # everything is made and checked before anything is written: a refused checkpoint leaves the
    # files already in out_dir as they were
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # overflow in a damaged network: judged by the checks below
            cfg = EnvConfig.from_json(ckpt["env_config"])
            px4_raptor.policy_order(cfg.params)
            toml = vehicle_to_toml(cfg.params).encode()
            ex_in, ex_out = example(weights, cfg)
            name = checkpoint_name(ckpt)
            data = rltools_tar.policy_tar_bytes(weights, ex_in, ex_out, checkpoint_name=name)
    except (KeyError, TypeError, ValueError, OverflowError) as e:
        what = f"missing entry {e}" if isinstance(e, KeyError) else str(e).splitlines()[0][:200]
        raise StudentCheckpointError(f"{checkpoint}: cannot be exported ({what})") from None
    model = gru.gru_onnx(weights)
    meta = {
        "quadpilot.contract": "px4-raptor",
        "quadpilot.initial_hidden_state": json.dumps([float(v) for v in weights["layers/1/initial_hidden_state"]]),
        "quadpilot.vehicle": json.dumps(ckpt.get("env_config", {}).get("vehicle")),
    }
    for k, v in meta.items():
        model.metadata_props.add(key=k, value=v)
    out_dir.mkdir(parents=True, exist_ok=True)
    tar = out_dir / "policy.tar"
    digest = rltools_tar.write_policy_tar_bytes(tar, data)
    onnx_path = out_dir / "policy.onnx"
    atomic_write(onnx_path, lambda f: f.write(model.SerializeToString()))
    atomic_write(out_dir / VEHICLE_BESIDE, lambda f: f.write(toml))
    return Exported(tar, digest, onnx_path, parity(student, weights, tar, ex_in), name)


def parity(student, weights: dict, tar: Path, xs: np.ndarray) -> dict:
    """Largest |difference| in raw action against torch over the sequences xs (T, B, 22), for each
    runtime path."""
    with torch.no_grad():
        ref, _ = student(torch.from_numpy(xs))
    ref = ref.numpy().astype(np.float64)
    back = rltools_tar.read_policy_tar(tar)
    paths = {
        "numpy": gru.GruStep(weights),
        "onnxruntime": gru.OnnxGruStep(weights),
        "policy.tar read back (numpy)": gru.GruStep(back.weights),
    }
    out = {"observations": int(xs.shape[0] * xs.shape[1])}
    out.update({k: float(np.max(np.abs(gru.sequences(step, xs) - ref))) for k, step in paths.items()})
    return out
