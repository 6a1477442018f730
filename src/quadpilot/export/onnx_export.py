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
from torch.nn import functional as F

from quadpilot.atomic_files import atomic_write
from quadpilot.core.dynamics import MOTOR_NAMES, action_to_command
from quadpilot.core.observation import build_observation
from quadpilot.core.state import PITCH, POS, RATES, ROLL, STATE_DIM, VEL, YAW
from quadpilot.train.algorithms import CheckpointError, load_checkpoint, trained_policy
from quadpilot.train.envs import QuadBatch
from quadpilot.train.runs.checkpoint import TrainedPolicy

ONNX_SCHEMA = "quadpilot.onnx/1"
INPUT, OUTPUT = "obs", "action"
DEFAULT_OPSET = 18
NATIVE_OPSET = 18
"""The operator set torch's exporter implements (torch/onnx/_internal/exporter/_constants.py,
TORCHLIB_OPSET). Below it the exporter runs the ONNX version converter, which on our graphs either
fails (the LSTM's Split has no num_outputs before 18) or gives up and leaves the file at 18 with no
error, so a lower request would silently get another opset."""


class OpsetError(ValueError):
    """An operator set version quad-export cannot write; the message says which it can."""


def supported_opsets() -> range:
    """The operator set versions `export_onnx` writes exactly: from the exporter's native one to
    the newest that both the runtime checks graphs for (`modelfile.model.OPSETS`) and the installed
    onnx package defines (above that the exporter silently falls back to 18)."""
    import onnx

    from quadpilot.modelfile.model import OPSETS

    return range(max(NATIVE_OPSET, OPSETS.start), min(OPSETS.stop, onnx.defs.onnx_opset_version() + 1))


def check_opset(opset: object) -> int:
    """`opset` if quad-export can write it; OpsetError naming the accepted range otherwise."""
    ok = supported_opsets()
    if isinstance(opset, bool) or not isinstance(opset, int) or opset not in ok:
        raise OpsetError(
            f"operator set {opset!r} is not one quad-export writes; expected {ok.start} to {ok.stop - 1} "
            f"(default {DEFAULT_OPSET})"
        )
    return opset


ACTION_MEANING = (
    "normalised rotor speed omega/omega_max in [0, 1] per motor (thrust proportional to its square), "
    "PX4 quad-X order: " + ", ".join(f"{i} {name}" for i, name in enumerate(MOTOR_NAMES))
)


_ACTIVATION_NAMES = {nn.Tanh: "tanh", nn.ReLU: "relu", nn.ELU: "elu"}


class _Deployable(nn.Module):
    """Shared pieces: observation normalisation in front, clipped action → motor command behind."""

    def __init__(self, policy: TrainedPolicy) -> None:
        super().__init__()
        self.normalize = bool(policy.normalize_obs)
        rms = policy.obs_rms
        self.register_buffer("obs_mean", torch.as_tensor(rms.mean, dtype=torch.float32))
        self.register_buffer("obs_inv_std", torch.as_tensor(1.0 / rms.std, dtype=torch.float32))
        self.obs_clip = float(rms.clip)
        self.u_hover = float(policy.env_config.params.hover_command)

    def _normalized(self, obs: torch.Tensor) -> torch.Tensor:
        if not self.normalize:
            return obs
        return torch.clamp((obs - self.obs_mean) * self.obs_inv_std, -self.obs_clip, self.obs_clip)

    def _command(self, mean: torch.Tensor) -> torch.Tensor:
        a = torch.clamp(mean, -1.0, 1.0)
        return torch.clamp(self.u_hover * torch.sqrt(1.0 + a), 0.0, 1.0)

    def _spec(self) -> dict:
        """The architecture metadata: what the NumPy backend computes, with initializer names."""
        return {
            "normalize": {"mean": "obs_mean", "inv_std": "obs_inv_std", "clip": self.obs_clip}
            if self.normalize
            else None,
            "action_clip": [-1.0, 1.0],
            "u_hover": self.u_hover,
            "command_clip": [0.0, 1.0],
        }


class DeployablePolicy(_Deployable):
    """Raw observations (B, obs_dim) float32 → motor commands (B, 4) float32 in [0, 1]."""

    recurrent = False

    def __init__(self, policy: TrainedPolicy) -> None:
        super().__init__(policy)
        self.actor = policy.model.actor
        # SAC: the actor ends in Tanh, a = tanh(z); then u·√(1 + a) is computed as
        # u·√(2p/(p + q)), p = e^(2·min(z, 0)), q = e^(−2·max(z, 0)): the same function without the
        # cancellation of 1 + tanh(z) near a = −1 (motor off), where float32 leaves 1 + a at 0 or
        # 6e-8 and the √ turns that into ~1e-4 of command that two runtimes would not agree on.
        self.squash = isinstance(self.actor[-1], nn.Tanh)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        x = self._normalized(obs)
        if not self.squash:
            return self._command(self.actor(x))
        z = self.actor[:-1](x)
        p, q = torch.exp(2.0 * torch.clamp(z, max=0.0)), torch.exp(-2.0 * torch.clamp(z, min=0.0))
        return torch.clamp(self.u_hover * torch.sqrt(2.0 * p / (p + q)), 0.0, 1.0)

    def spec(self) -> dict:
        layers, mods = [], list(self.actor.named_children())
        for k, (name, mod) in enumerate(mods):
            if isinstance(mod, nn.Linear):
                nxt = mods[k + 1][1] if k + 1 < len(mods) else None
                act = _ACTIVATION_NAMES.get(type(nxt)) if nxt is not None else None
                layers.append({"weight": f"actor.{name}.weight", "bias": f"actor.{name}.bias", "activation": act})
        return {"kind": "mlp", **self._spec(), "layers": layers}


class DeployableRecurrentPolicy(_Deployable):
    """One control step of the recurrent actor with explicit state:
    (obs (B, obs_dim), h_in (B, H), c_in (B, H)) → (motor commands (B, 4), h_out, c_out).

    The LSTM cell is written out from the trained `nn.LSTM`'s own weights (gate order i, f, g, o,
    as torch documents for nn.LSTM) so that the graph is plain Gemm/Sigmoid/Tanh arithmetic any
    runtime computes; the parity check compares it with the fused nn.LSTM used in training."""

    recurrent = True

    def __init__(self, policy: TrainedPolicy) -> None:
        super().__init__(policy)
        self.lstm = policy.model.actor_lstm
        self.head = policy.model.actor_head
        self.hidden = policy.model.hidden

    def forward(self, obs: torch.Tensor, h_in: torch.Tensor, c_in: torch.Tensor):
        x = self._normalized(obs)
        lstm = self.lstm
        gates = F.linear(x, lstm.weight_ih_l0, lstm.bias_ih_l0) + F.linear(h_in, lstm.weight_hh_l0, lstm.bias_hh_l0)
        i, f, g, o = gates.chunk(4, dim=-1)
        c_out = torch.sigmoid(f) * c_in + torch.sigmoid(i) * torch.tanh(g)
        h_out = torch.sigmoid(o) * torch.tanh(c_out)
        return self._command(self.head(h_out)), h_out, c_out

    def spec(self) -> dict:
        names = {k: f"lstm.{k}_l0" for k in ("weight_ih", "weight_hh", "bias_ih", "bias_hh")}
        head = [{"weight": "head.weight", "bias": "head.bias", "activation": None}]
        return {"kind": "lstm", "hidden": self.hidden, **self._spec(), "lstm": names, "layers": head}


def deployable(policy: TrainedPolicy) -> DeployablePolicy | DeployableRecurrentPolicy:
    if getattr(policy, "obs_history", 1) > 1:  # the runtime knows no stacked-history layout
        raise CheckpointError(
            f"{policy.source}: an observation-history policy (obs_history={policy.obs_history}) is evaluated "
            "in-process only; export an MLP or LSTM policy"
        )
    return (DeployableRecurrentPolicy if policy.recurrent else DeployablePolicy)(policy).eval()


def reference_commands(policy: TrainedPolicy, obs: np.ndarray, starts: np.ndarray | None = None) -> np.ndarray:
    """The training-side path, for parity: the trainer's deterministic action, then `core`'s
    action-to-command map (float64). MLP: obs (N, obs_dim) → (N, 4). Recurrent: obs (T, B, obs_dim)
    with episode starts (T, B), run through the training class's fused nn.LSTM → (T, B, 4)."""
    u_hover = policy.env_config.params.hover_command
    if not policy.recurrent and getattr(policy.model, "squash", None) == "tanh":
        # SAC: the network's z (float32), then tanh and the map in float64 (see DeployablePolicy)
        with torch.inference_mode():
            z = policy.model.unsquashed_mean(policy.network_input(obs)).numpy().astype(np.float64)
        return action_to_command(np.tanh(z), u_hover)
    if not policy.recurrent:
        return action_to_command(policy(obs).astype(np.float64), u_hover)
    t, b, d = obs.shape
    with torch.inference_mode():
        x = policy.network_input(obs.reshape(t * b, d)).reshape(t, b, d)
        mean, _ = policy.model.actor_sequence(x, policy.initial_state(b), torch.from_numpy(starts))
    return action_to_command(mean.clamp(-1.0, 1.0).numpy().astype(np.float64), u_hover)


def _edge_observations(cfg, k: int, rng: np.random.Generator) -> np.ndarray:
    """(k, obs_dim): positions up to the 5 m flight-area limit, ±5 m/s, any attitude, ±10 rad/s."""
    state = np.zeros((k, STATE_DIM))
    state[:, POS] = rng.uniform(-5.0, 5.0, (k, 3))
    state[:, VEL] = rng.uniform(-5.0, 5.0, (k, 3))
    state[:, ROLL] = rng.uniform(-np.pi, np.pi, k)
    state[:, PITCH] = rng.uniform(-np.pi / 2 + 0.01, np.pi / 2 - 0.01, k)
    state[:, YAW] = rng.uniform(-np.pi, np.pi, k)
    state[:, RATES] = rng.uniform(-10.0, 10.0, (k, 3))
    target_vel = rng.uniform(-2.0, 2.0, (k, 3)) if cfg.layout.dim == 21 else None
    return build_observation(state, np.zeros(3), target_vel)


def parity_observations(policy: TrainedPolicy, n: int = 10_000, seed: int = 0) -> np.ndarray:
    """(n, obs_dim) float32: half from closed-loop rollouts of the policy itself from the training
    start distribution (what it sees in flight), half from the edges of the training range."""
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
    edges = _edge_observations(cfg, n - n_roll, rng)
    return np.concatenate([rollout, edges]).astype(np.float32)


def parity_sequences(
    policy: TrainedPolicy, steps: int = 500, sequences: int = 20, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """For a recurrent policy: obs (steps, sequences, obs_dim) float32 and episode starts
    (steps, sequences) bool. The first half is the policy's own closed-loop flight (episodes
    that end restart, and their state resets); at the half-way step every state is reset and
    the second half is observations from the edges of the training range."""
    rng = np.random.default_rng(seed)
    cfg = policy.env_config
    batch = QuadBatch(cfg, sequences)
    batch.reset(np.ones(sequences, bool), rng)
    state = policy.initial_state(sequences)
    obs = np.zeros((steps, sequences, policy.layout.dim), np.float32)
    starts = np.zeros((steps, sequences), bool)
    starts[0] = True
    half = steps // 2
    for t in range(half):
        obs[t] = batch.obs
        action, state = policy.step(batch.obs.copy(), state)
        _, _, term, trunc, _ = batch.step(action)
        done = term | trunc
        batch.reset(done, rng)
        if t + 1 < steps:
            starts[t + 1] |= done
        keep = torch.from_numpy(~done).float().unsqueeze(-1)
        state = (state[0] * keep, state[1] * keep)
    if half < steps:
        starts[half] = True
        obs[half:] = _edge_observations(cfg, (steps - half) * sequences, rng).reshape(steps - half, sequences, -1)
    return obs, starts


def _step_sequences(step, obs: np.ndarray, starts: np.ndarray, hidden: int) -> np.ndarray:
    """Run a batched recurrent step function (obs, h, c) → (action, h, c) over (T, B, D)."""
    t_len, b, _ = obs.shape
    h = np.zeros((b, hidden), np.float32)
    c = np.zeros((b, hidden), np.float32)
    out = np.zeros((t_len, b, 4), np.float32)
    for t in range(t_len):
        keep = (~starts[t]).astype(np.float32)[:, None]
        out[t], h, c = step(obs[t], h * keep, c * keep)
    return out


def _torch_step(module):
    """The recurrent torch module as a NumPy step function (obs, h, c) → (action, h, c)."""

    def step(o, h, c):
        with torch.inference_mode():
            return tuple(v.numpy() for v in module(*map(torch.from_numpy, (o, h, c))))

    return step


def _runtime_sequences(runtime_policy, obs: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """The runtime's batch-1 policy over (T, B, D), one sequence at a time, reset at starts."""
    t_len, b, _ = obs.shape
    out = np.zeros((t_len, b, 4), np.float32)
    for j in range(b):
        for t in range(t_len):
            if starts[t, j]:
                runtime_policy.reset()
            out[t, j] = runtime_policy.act(obs[t, j])
    return out


def sha256_of(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _golden(policy: TrainedPolicy, module) -> tuple[np.ndarray, np.ndarray]:
    """A short sequence of (obs → motor command) from zero recurrent state, stored in the file."""
    if not module.recurrent:
        obs = parity_observations(policy, n=8, seed=1)
        with torch.inference_mode():
            return obs, module(torch.from_numpy(obs)).numpy()
    obs, _ = parity_sequences(policy, steps=8, sequences=1, seed=1)
    starts = np.zeros(obs.shape[:2], bool)
    starts[0] = True
    act = _step_sequences(_torch_step(module), obs, starts, module.hidden)
    return obs[:, 0], act[:, 0]


def _resolve_weight_names(spec: dict, module: nn.Module, initializers: set[str]) -> dict:
    """The architecture spec names each weight by its initializer in the graph. The exporter's
    optimiser drops an all-zero bias (adding zeros is a no-op; an untrained head has one): such an
    entry becomes None, which readers take as zeros. Any other missing name is an exporter change
    the runtime must not guess about."""
    params = dict(module.named_parameters()) | dict(module.named_buffers())

    def resolve(name: str) -> str | None:
        if name in initializers:
            return name
        if name in params and not bool(params[name].detach().abs().max() > 0):
            return None
        raise RuntimeError(
            f"the ONNX exporter renamed {name!r}, which the runtime reads by name; found {sorted(initializers)}"
        )

    spec = json.loads(json.dumps(spec))
    for layer in spec["layers"]:
        layer["weight"], layer["bias"] = resolve(layer["weight"]), resolve(layer["bias"])
    if spec.get("lstm"):
        spec["lstm"] = {k: resolve(v) for k, v in spec["lstm"].items()}
    if spec["normalize"]:
        for k in ("mean", "inv_std"):
            spec["normalize"][k] = resolve(spec["normalize"][k])
    return spec


def export_onnx(checkpoint: str | os.PathLike, out: str | os.PathLike, opset: int = DEFAULT_OPSET) -> dict:
    """Write the ONNX file for a policy checkpoint; returns the metadata written into it.

    Raises CheckpointError for a checkpoint that cannot be used, OpsetError for an operator set
    outside `supported_opsets()`, and RuntimeError if the exporter wrote another opset than asked."""
    import onnx

    check_opset(opset)
    checkpoint, out = Path(checkpoint), Path(out)
    ckpt = load_checkpoint(checkpoint)
    policy = trained_policy(ckpt, str(checkpoint))
    module = deployable(policy)
    dim = policy.layout.dim
    batch = torch.export.Dim("batch")
    if module.recurrent:
        h = module.hidden
        example = (torch.zeros(2, dim), torch.zeros(2, h), torch.zeros(2, h))
        names_in, names_out = [INPUT, "h_in", "c_in"], [OUTPUT, "h_out", "c_out"]
        dynamic = ({0: batch}, {0: batch}, {0: batch})
    else:
        example = (torch.zeros(2, dim),)
        names_in, names_out = [INPUT], [OUTPUT]
        dynamic = ({0: batch},)
    # the exporter logs that torchvision (which we do not use) is missing; keep the CLI output ours
    logging.getLogger("torch.onnx._internal.exporter._registration").setLevel(logging.ERROR)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the exporter's progress chatter
        program = torch.onnx.export(
            module,
            example,
            dynamo=True,
            input_names=names_in,
            output_names=names_out,
            dynamic_shapes=dynamic,
            opset_version=opset,
            verbose=False,
        )
    model = program.model_proto
    written = {o.domain: o.version for o in model.opset_import}.get("", None)
    if written != opset:  # the exporter's version conversion can fail without an error
        raise RuntimeError(f"the ONNX exporter wrote operator set {written} when asked for {opset}; nothing written")
    spec = _resolve_weight_names(module.spec(), module, {t.name for t in model.graph.initializer})
    golden_obs, golden_act = _golden(policy, module)
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
        "quadpilot.architecture": json.dumps(spec),
        "quadpilot.envelope": json.dumps(
            {"max_distance_m": cfg.reward.max_distance, "max_tilt_deg": cfg.reward.max_tilt_deg}
        ),
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


def check_parity(
    checkpoint: str | os.PathLike, onnx_path: str | os.PathLike, n: int = 10_000, extra_policies: dict | None = None
) -> dict:
    """Max abs difference of the thrust commands (`_thrust_difference`) between the exported torch
    module and, on the same inputs: a batched ONNX Runtime session, the runtime's numpy and onnxruntime batch-1
    backends (which also check the file's contract and golden vectors on load), any runtime
    `Policy` in `extra_policies` (name → policy, e.g. the compiled C kernel; reported as
    `torch_vs_runtime_<name>`), and the training-side path (the trainer's network +
    core.action_to_command). MLP: `n` observations from rollouts and range edges. LSTM: n/500
    sequences of 500 steps with a state reset half-way (`parity_sequences`)."""
    import onnxruntime as ort

    from quadpilot.runtime.backends import load_policy as load_runtime_policy

    policy = trained_policy(load_checkpoint(checkpoint), str(checkpoint))
    module = deployable(policy)
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    session = ort.InferenceSession(str(onnx_path), opts, providers=["CPUExecutionProvider"])
    backends = {b: load_runtime_policy(onnx_path, b) for b in ("onnxruntime", "numpy")}
    backends |= extra_policies or {}
    if not module.recurrent:
        obs = parity_observations(policy, n)
        with torch.inference_mode():
            torch_out = module(torch.from_numpy(obs)).numpy()
        outs = {"onnxruntime_session": session.run([OUTPUT], {INPUT: obs})[0]}
        for name, p in backends.items():
            outs[f"runtime_{name}"] = np.stack([p.act(o) for o in obs])
        ref = reference_commands(policy, obs)
        count = {"observations": int(obs.shape[0])}
    else:
        obs, starts = parity_sequences(policy, sequences=max(1, n // 500))
        h = module.hidden

        def ort_step(o, hh, cc):
            return tuple(session.run(None, {INPUT: o, "h_in": hh, "c_in": cc}))

        torch_out = _step_sequences(_torch_step(module), obs, starts, h)
        outs = {"onnxruntime_session": _step_sequences(ort_step, obs, starts, h)}
        for name, p in backends.items():
            outs[f"runtime_{name}"] = _runtime_sequences(p, obs, starts)
        ref = reference_commands(policy, obs, starts)
        count = {"observations": int(obs.shape[0] * obs.shape[1]), "sequences": int(obs.shape[1])}
    result = {**count, "training_path_vs_torch": _thrust_difference(ref, torch_out)}
    for name, out in outs.items():
        result[f"torch_vs_{name}"] = _thrust_difference(torch_out, out)
    return result


def _thrust_difference(a: np.ndarray, b: np.ndarray) -> float:
    """Max abs difference of the rotor thrust commands u² (thrust k_f·(u·ω_max)² as a fraction of full
    thrust) of two arrays of motor commands u. Judged in thrust, not in u: u = u_hover·√(1 + a)
    turns a float32 rounding of the action a near −1 (a rotor near rest) into a difference in u without
    bound (√ has an infinite slope at 0: a rotor at 0.4 % speed differed by 1e-5 between torch and ONNX
    Runtime, everywhere above 5 % by at most 1.3e-6), while u² is linear in a."""
    a64, b64 = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.max(np.abs(a64 * a64 - b64 * b64)))
