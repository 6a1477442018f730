"""Torch-free runtime: the policy backends (NumPy, ONNX Runtime, C), the safety monitor and its
fallback controller, PX4 mc_raptor's policies (`policy.tar`, RAPTOR) and the shipped models.

    from quadpilot.runtime import load_policy, SafetyMonitor
    monitor = SafetyMonitor(load_policy("models/hover/policy.onnx", backend="numpy"))
    motors = monitor.act(obs)   # (4,) float32 in [0, 1], PX4 quad-X order

Imports numpy, onnx (to read the file) and onnxruntime only: never torch or gymnasium. The "c"
backend needs a C compiler at load time (`cbackend`), nothing else.
"""

from quadpilot.modelfile.model import ModelContractError, ModelInfo, read_model

from .backends import BACKENDS, NumpyPolicy, ObservationShapeError, OnnxRuntimePolicy, Policy, load_policy
from .cbackend import CCompilerError, CPolicy
from .fallback import FallbackController, FallbackGains
from .safety import ObservationLimits, SafetyMonitor

__all__ = [
    "BACKENDS",
    "CCompilerError",
    "CPolicy",
    "FallbackController",
    "FallbackGains",
    "ModelContractError",
    "ModelInfo",
    "NumpyPolicy",
    "ObservationLimits",
    "ObservationShapeError",
    "OnnxRuntimePolicy",
    "Policy",
    "SafetyMonitor",
    "load_policy",
    "read_model",
]
