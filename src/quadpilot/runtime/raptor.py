"""The RAPTOR foundation policy (Eschmann et al. 2025, arXiv 2509.11481), the policy PX4's mc_raptor
module flies, run through the `px4-raptor` contract (`core.px4_raptor`) by our node.

    policy = load_raptor("raptor:foundation", backend="numpy")   # or a path to an RLtools .h5 checkpoint
    monitor = SafetyMonitor(policy)

How a user selects it: `quad-sitl raptor:foundation [--vehicle NAME]` (or `quad-sitl CHECKPOINT.h5`, or
`quad-sitl policy.tar`, a policy of the same shape trained here and written by `quad-export --format px4-raptor`);
`raptor:foundation` is the checkpoint the foundation-policy package ships (the same weights and
checkpoint name, logs/2025-04-19_16-16-17, as PX4's src/modules/mc_raptor/blob/policy.h). The
weights are checked (`gru.check_weights`), and the checkpoint's own example is replayed before it
flies, as mc_raptor's test_policy does (mean absolute difference below 1e-5, or refused).

In the node (`autopilot.node`) the policy builds its own observation from the state
(`own_observation`) and runs at every simulator step, as mc_raptor runs on every gyro update; its
executor (`core.px4_raptor.Executor`) advances the GRU state on 100 Hz steps: every
IMU_GYRO_RATEMAX / 100-th call, the gyro rate being the simulator's step rate measured from the
first two steps' timestamps (PX4 reads it from the parameter). The safety monitor's fallback gets
the observation in the hover layout (`core.px4_raptor.fallback_observation`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from pathlib import Path

import numpy as np

from quadpilot.core import px4_raptor
from quadpilot.core.vehicle_file import get_preset
from quadpilot.modelfile.contract import ModelContractError, ModelInfo

from .gru import EXAMPLE_TOLERANCE, GruStep, OnnxGruStep, check_example, weights_from_h5
from .policy import Policy

FOUNDATION = "raptor:foundation"
"""The policy name that selects the foundation-policy package's checkpoint."""
RAPTOR_BACKENDS = ("numpy", "onnxruntime", "c")
DEFAULT_VEHICLE = "px4_sih_quadx"
"""The vehicle quad-sitl flies RAPTOR on unless --vehicle says otherwise (PX4 flies it in SIH)."""
GOLDEN_STEPS = 20
ACTION_MEANING = "PX4 quad-X motor commands (a + 1)/2 of the clamped policy output, as mc_raptor writes them"


def foundation_checkpoint() -> Path:
    """The checkpoint the foundation-policy package ships; ModelContractError if not installed."""
    try:
        import importlib.resources as resources

        return Path(str(resources.files("foundation_policy").joinpath("blob", "checkpoint.h5")))
    except ModuleNotFoundError:
        raise ModelContractError(
            f"{FOUNDATION} needs the foundation-policy package: pip install foundation-policy"
        ) from None


VEHICLE_BESIDE = "vehicle.toml"
"""A policy.tar's own vehicle, written beside it by quad-export --format px4-raptor: what quad-sitl
flies it on unless --vehicle says otherwise (policy.tar itself names no airframe: mc_raptor flies
whatever it is loaded on)."""


def load_raptor(path, backend: str = "numpy", vehicle=None) -> RaptorPolicy:
    """A checked RAPTOR policy from `raptor:foundation`, an RLtools .h5 checkpoint or an RLtools
    policy.tar (the file mc_raptor loads: `rltools_tar.read_policy_tar` checks it whole; see the module
    docstring); ModelContractError, one line, if not."""
    if backend not in RAPTOR_BACKENDS:
        raise ValueError(f"a RAPTOR policy runs on the {', '.join(RAPTOR_BACKENDS)} backend, not {backend!r}")
    if str(path).startswith("raptor:") and str(path) != FOUNDATION:
        raise ModelContractError(f"{path}: unknown RAPTOR policy name; expected {FOUNDATION}")
    file = foundation_checkpoint() if str(path) == FOUNDATION else Path(path)
    if not file.is_file():
        raise ModelContractError(f"{file}: no such checkpoint file")
    if file.suffix.lower() == ".tar":  # the file mc_raptor loads, from quad-export --format px4-raptor
        from .rltools_tar import PolicyTarError, read_policy_tar

        try:
            tar = read_policy_tar(file)
        except PolicyTarError as e:
            raise ModelContractError(str(e)) from None
        example = {"input": tar.example_in, "output": tar.example_out}
        beside = file.parent / VEHICLE_BESIDE
        if vehicle is None and (beside.exists() or beside.is_symlink()):
            from quadpilot.core.vehicle_file import load_vehicle_file

            if not beside.is_file():
                raise ModelContractError(
                    f"{path}: its {VEHICLE_BESIDE} is not a file; expected the vehicle file quad-export wrote"
                )
            try:
                vehicle = load_vehicle_file(beside)
                px4_raptor.policy_order(vehicle)
            except ValueError as e:  # VehicleFileError, or a frame the contract cannot fly
                raise ModelContractError(f"{path}: its {VEHICLE_BESIDE}: {e}") from None
        return raptor_from_weights(tar.weights, example, str(path), tar.sha256, backend, vehicle or DEFAULT_VEHICLE)
    weights, example = weights_from_h5(file)
    sha256 = hashlib.sha256(file.read_bytes()).hexdigest()
    return raptor_from_weights(weights, example, str(path), sha256, backend, vehicle or DEFAULT_VEHICLE)


def raptor_from_weights(
    weights: dict, example: dict, name: str, sha256: str, backend: str = "numpy", vehicle=DEFAULT_VEHICLE
) -> RaptorPolicy:
    """A checked RAPTOR policy from the weight dict (`gru.GRU_KEYS`) and the checkpoint's example
    {"input": (T, B, 22), "output": (T, B, 4)}, whatever read them (an RLtools policy.tar reader
    can feed this); `name` labels it, `sha256` is its source's digest."""
    if backend not in RAPTOR_BACKENDS:
        raise ValueError(f"a RAPTOR policy runs on the {', '.join(RAPTOR_BACKENDS)} backend, not {backend!r}")
    if backend == "c":  # generated C (ccode.gru), compiled by the system C compiler: CCompilerError without one
        from .cgru import CGruStep

        step = CGruStep(weights)
    else:
        step = GruStep(weights) if backend == "numpy" else OnnxGruStep(weights)
    diff = check_example(step, example)
    if math.isnan(diff):
        raise ModelContractError(f"{name}: no input/output example to replay (mc_raptor's test_policy needs one)")
    if not diff < EXAMPLE_TOLERANCE:
        raise ModelContractError(
            f"{name}: the checkpoint's example is not reproduced (mean abs difference {diff:.3g}; "
            f"mc_raptor refuses above {EXAMPLE_TOLERANCE:g})"
        )
    xs, ys = example["input"][:GOLDEN_STEPS, 0], example["output"][:GOLDEN_STEPS, 0]
    info = ModelInfo(
        path=name,
        layout=px4_raptor.PX4_RAPTOR_LAYOUT,
        task="hover",
        control_period_s=1.0 / px4_raptor.TRAINING_RATE_HZ,
        vehicle=get_preset(vehicle) if isinstance(vehicle, str) else vehicle,
        training_steps=0,
        source_sha256=sha256,
        action_meaning=ACTION_MEANING,
        architecture={"kind": "gru", "hidden": 16, "layers": ["dense 22-16 relu", "gru 16", "dense 16-4"]},
        envelope={"max_distance_m": 1e3, "max_tilt_deg": 85.0},
        golden_obs=np.ascontiguousarray(xs),
        golden_action=np.stack([px4_raptor.motor_commands(y) for y in ys]),
    )
    return RaptorPolicy(info, step, backend)


class RaptorPolicy(Policy):
    """A policy that flies through mc_raptor's contract: `own_observation` builds the 22 inputs
    (with the executor's previous action), `act` runs one executor call and answers PX4 quad-X motor
    commands in [0, 1]."""

    def __init__(self, info: ModelInfo, step, backend: str, gyro_rate_hz: float | None = None) -> None:
        super().__init__(info)
        self.backend = backend
        self.executor = px4_raptor.Executor(step, step.initial_state, order=px4_raptor.policy_order(info.vehicle))
        self.gyro_rate_hz = gyro_rate_hz
        """Hz, the IMU_GYRO_RATEMAX the executor counts with; None: measured from the first two calls."""
        self.step_s: float | None = None
        self._last_us: int | None = None
        self.reset()

    def reset(self) -> None:
        """Raptor::reset: the GRU state to its initial value, the previous action to 0; the gyro rate
        is measured again unless it was given."""
        self.executor.reset()
        self._last_us = None
        self.step_s = None  # measured again (the node resets the policy for every flight)
        if self.gyro_rate_hz is not None:
            self.executor.force_sync = px4_raptor.force_sync_native(self.gyro_rate_hz)
            self.step_s = 1.0 / self.gyro_rate_hz

    def fly_on(self, vehicle) -> None:
        """Fly `vehicle` (VehicleParams): the contract knows no airframe, so the policy is the same and
        only its outputs follow the vehicle's rotor numbering (`px4_raptor.policy_order`; ValueError,
        one line, for a frame it cannot fly)."""
        self.executor.order = np.asarray(px4_raptor.policy_order(vehicle))
        self.info = dataclasses.replace(self.info, vehicle=vehicle)

    def own_observation(self, state, target, target_vel, heading, t_us: int) -> np.ndarray:
        """The observation `Raptor::observe` makes of this state (`core.px4_raptor.observation`), at
        simulated time t_us (µs): the second call after a reset sets the gyro rate, if not given."""
        if self.gyro_rate_hz is None and self._last_us is not None and self.step_s is None and t_us > self._last_us:
            self.step_s = (t_us - self._last_us) * 1e-6
            self.executor.force_sync = px4_raptor.force_sync_native(1.0 / self.step_s)
        self._last_us = t_us
        prev = self.executor.previous_action_input()
        return px4_raptor.observation(state, target, target_vel, 0.0 if heading is None else heading, prev)

    def act_unchecked(self, x: np.ndarray) -> np.ndarray:
        return self.executor.control(x)

    def verify_golden(self) -> float:
        """The file's first example steps, each a native call from the initial state (force_sync 1)."""
        force, self.executor.force_sync = self.executor.force_sync, 1
        try:
            return super().verify_golden()
        finally:
            self.executor.force_sync = force

    def make_fallback(self):
        """The safety monitor's fallback for this policy: the classical controller on the hover-layout
        form of the observation, holding the commanded heading."""
        return _HoverLayoutFallback(self)


class _HoverLayoutFallback:
    def __init__(self, policy: RaptorPolicy) -> None:
        self.policy = policy
        self._controller = None

    def reset(self) -> None:
        self._controller = None

    def act(self, obs: np.ndarray) -> np.ndarray:
        if self._controller is None:  # made at the hand-over, at the step the policy was running at
            from .fallback import FallbackController

            dt = self.policy.step_s or self.policy.info.control_period_s
            self._controller = FallbackController(self.policy.info.vehicle, dt, heading_frame=True)
        return self._controller.act(px4_raptor.fallback_observation(obs))
