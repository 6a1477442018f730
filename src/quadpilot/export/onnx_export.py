"""The deployable policy and its ONNX file: everything inference needs is inside the graph.

    obs float32 [batch, obs_dim]  →  (obs − mean)/std clipped (if the run normalised)
                                  →  actor MLP → mean action clipped to [−1, 1]
                                  →  motor command u_hover·√(1 + a) clipped to [0, 1]
                                  →  action float32 [batch, 4]

The output is what PX4's HIL_ACTUATOR_CONTROLS carries in controls[0..3]: normalised rotor speed
ω/ω_max, thrust ∝ command², motors in PX4's quad-X order (0 front-right, 1 rear-left, 2 front-left,
3 rear-right), which is also the order of our model (`core.dynamics.MOTOR_LAYOUT`). The mapping is
`core.dynamics.action_to_command` written in torch; the parity check compares the two.

Metadata (ONNX `metadata_props`, all strings, JSON where structured) lets a runtime refuse a file it
does not understand: schema, observation layout, action meaning, control period, vehicle, task,
training steps, the SHA-256 of the source checkpoint and a few golden (obs → action) vectors.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

from quadpilot.core.dynamics import MOTOR_NAMES, action_to_command
from quadpilot.core.observation import build_observation
from quadpilot.train.checkpoint import TrainedPolicy, atomic_write, load_checkpoint
from quadpilot.train.envs import QuadBatch

ONNX_SCHEMA = "quadpilot.onnx/1"
INPUT, OUTPUT = "obs", "action"
DEFAULT_OPSET = 18
ACTION_MEANING = (
    "normalised rotor speed omega/omega_max in [0, 1] per motor (thrust proportional to its square), "
    "PX4 quad-X order: " + ", ".join(f"{i} {name}" for i, name in enumerate(MOTOR_NAMES))
)


class DeployablePolicy(nn.Module):
    """Raw observations (B, obs_dim) float32 → motor commands (B, 4) float32 in [0, 1]."""

    def __init__(self, policy: TrainedPolicy) -> None:
        super().__init__()
        self.actor = policy.model.actor
        self.normalize = bool(policy.ppo_config.normalize_obs)
        rms = policy.obs_rms
        self.register_buffer("obs_mean", torch.as_tensor(rms.mean, dtype=torch.float32))
        self.register_buffer("obs_inv_std", torch.as_tensor(1.0 / rms.std, dtype=torch.float32))
        self.obs_clip = float(rms.clip)
        self.u_hover = float(policy.env_config.params.hover_command)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        x = obs
        if self.normalize:
            x = torch.clamp((obs - self.obs_mean) * self.obs_inv_std, -self.obs_clip, self.obs_clip)
        a = torch.clamp(self.actor(x), -1.0, 1.0)
        return torch.clamp(self.u_hover * torch.sqrt(1.0 + a), 0.0, 1.0)


def reference_commands(policy: TrainedPolicy, obs: np.ndarray) -> np.ndarray:
    """The training-side path, for parity: the trainer's deterministic action, then `core`'s
    action-to-command map (float64)."""
    return action_to_command(policy(obs).astype(np.float64), policy.env_config.params.hover_command)


def parity_observations(policy: TrainedPolicy, n: int = 10_000, seed: int = 0) -> np.ndarray:
    """(n, obs_dim) float32: half from closed-loop rollouts of the policy itself from the training
    start distribution (what it sees in flight), half from the edges of the training range
    (positions up to the 5 m flight-area limit, ±5 m/s, any attitude, ±10 rad/s)."""
    rng = np.random.default_rng(seed)
    cfg = policy.env_config
    n_roll = n // 2
    drones = 100
    batch = QuadBatch(cfg, drones)
    batch.reset(np.ones(drones, bool), rng)
    seen = []
    while sum(len(s) for s in seen) < n_roll:
        seen.append(batch.obs.copy())
        _, _, term, trunc, _ = batch.step(policy(batch.obs.copy()))
        batch.reset(term | trunc, rng)
    rollout = np.concatenate(seen)[:n_roll]
    k = n - n_roll
    state = np.zeros((k, 12))
    state[:, 0:3] = rng.uniform(-5.0, 5.0, (k, 3))
    state[:, 3:6] = rng.uniform(-5.0, 5.0, (k, 3))
    state[:, 6] = rng.uniform(-np.pi, np.pi, k)
    state[:, 7] = rng.uniform(-np.pi / 2 + 0.01, np.pi / 2 - 0.01, k)
    state[:, 8] = rng.uniform(-np.pi, np.pi, k)
    state[:, 9:12] = rng.uniform(-10.0, 10.0, (k, 3))
    target_vel = rng.uniform(-2.0, 2.0, (k, 3)) if cfg.layout.dim == 21 else None
    edges = build_observation(state, np.zeros(3), target_vel)
    return np.concatenate([rollout, edges]).astype(np.float32)


def sha256_of(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def export_onnx(checkpoint: str | os.PathLike, out: str | os.PathLike, opset: int = DEFAULT_OPSET) -> dict:
    """Write the ONNX file for a policy checkpoint; returns the metadata written into it.

    Raises CheckpointError for a checkpoint that cannot be used."""
    import onnx

    checkpoint, out = Path(checkpoint), Path(out)
    ckpt = load_checkpoint(checkpoint)
    policy = TrainedPolicy(ckpt, str(checkpoint))
    module = DeployablePolicy(policy).eval()
    dim = policy.layout.dim
    example = torch.zeros(2, dim)
    # the exporter logs that torchvision (which we do not use) is missing; keep the CLI output ours
    logging.getLogger("torch.onnx._internal.exporter._registration").setLevel(logging.ERROR)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the exporter's progress chatter
        program = torch.onnx.export(
            module,
            (example,),
            dynamo=True,
            input_names=[INPUT],
            output_names=[OUTPUT],
            dynamic_shapes=({0: torch.export.Dim("batch")},),
            opset_version=opset,
            verbose=False,
        )
    model = program.model_proto
    golden_obs = parity_observations(policy, n=8, seed=1)
    with torch.inference_mode():
        golden_act = module(torch.from_numpy(golden_obs)).numpy()
    cfg = policy.env_config
    meta = {
        "quadpilot.schema": ONNX_SCHEMA,
        "quadpilot.obs_layout": json.dumps(policy.layout.to_json()),
        "quadpilot.action": ACTION_MEANING,
        "quadpilot.control_period_s": repr(float(cfg.dt)),
        "quadpilot.vehicle": json.dumps(cfg.to_json()["vehicle"]),
        "quadpilot.task": cfg.task,
        "quadpilot.training_steps": str(policy.global_step),
        "quadpilot.source_sha256": sha256_of(checkpoint),
        "quadpilot.golden": json.dumps({"obs": golden_obs.tolist(), "action": golden_act.tolist()}),
    }
    del model.metadata_props[:]
    for k, v in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = k, v
    model.producer_name = "quadpilot quad-export"
    onnx.checker.check_model(model, full_check=True)
    # small: the weights stay inside the file, no external data
    atomic_write(out, lambda f: f.write(model.SerializeToString()))
    return meta


def check_parity(checkpoint: str | os.PathLike, onnx_path: str | os.PathLike, n: int = 10_000) -> dict:
    """Max abs difference of the motor commands between the exported torch module, ONNX Runtime
    and the training-side path (TrainedPolicy + core.action_to_command) on `n` observations."""
    import onnxruntime as ort

    policy = TrainedPolicy(load_checkpoint(checkpoint), str(checkpoint))
    obs = parity_observations(policy, n)
    with torch.inference_mode():
        torch_out = DeployablePolicy(policy).eval()(torch.from_numpy(obs)).numpy()
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    session = ort.InferenceSession(str(onnx_path), opts, providers=["CPUExecutionProvider"])
    ort_out = session.run([OUTPUT], {INPUT: obs})[0]
    ref = reference_commands(policy, obs)
    return {
        "observations": int(obs.shape[0]),
        "torch_vs_onnxruntime": float(np.max(np.abs(torch_out - ort_out))),
        "training_path_vs_onnxruntime": float(np.max(np.abs(ref - ort_out))),
        "training_path_vs_torch": float(np.max(np.abs(ref - torch_out))),
    }
