"""NumPy-only foundations shared by training, runtime and simulator: vehicle parameters and vehicle
files, batched dynamics, frames, the observation layout, reward and termination maths, the mission
(task, start, target over time, success judge), sensor noise, randomisation, PX4 mc_raptor's
observation contract. Imports nothing of ours."""

from .dynamics import DT, MOTOR_NAMES, STATE_DIM, STATE_NAMES, action_to_command, hover_command, step
from .observation import HOVER_LAYOUT, LAYOUTS, TRACK_LAYOUT, ObsLayout, build_observation, get_layout
from .params import ParamBatch, VehicleParams
from .vehicle_file import CRAZYFLIE, PRESETS, SEED_VEHICLE, get_preset

__all__ = [
    "CRAZYFLIE",
    "DT",
    "HOVER_LAYOUT",
    "LAYOUTS",
    "MOTOR_NAMES",
    "PRESETS",
    "SEED_VEHICLE",
    "STATE_DIM",
    "STATE_NAMES",
    "TRACK_LAYOUT",
    "ObsLayout",
    "ParamBatch",
    "VehicleParams",
    "action_to_command",
    "build_observation",
    "get_layout",
    "get_preset",
    "hover_command",
    "step",
]
