"""The simulator's plant with RotorPy's quadratic body drag and rotor aerodynamics (`VehicleParams.c_dx`, k_d ...): it
steps `core.dynamics.step` with the wind (the scalar step declines such a vehicle), and its
accelerometer measures the drag as the dynamics applies it."""

import dataclasses

import numpy as np

from quadpilot.core import dynamics
from quadpilot.core.params import ParamBatch
from quadpilot.core.state import ATT, VEL, Z
from quadpilot.core.vehicle_file import PX4_SIH_QUADX
from quadpilot.simulator import sensors
from quadpilot.simulator.plant import Plant

VEHICLE = dataclasses.replace(PX4_SIH_QUADX, c_dx=0.02, c_dy=0.03, c_dz=0.05, k_d=1e-4, k_z=2e-4, k_h=3e-3, k_flap=1e-5)
WIND = (3.0, -2.0, 0.5)


def start() -> np.ndarray:
    s = np.zeros(12)
    s[Z], s[VEL], s[ATT] = 5.0, (1.0, 0.5, -0.2), (0.1, -0.05, 0.7)
    return s


def test_the_plant_flies_core_dynamics_with_the_wind_bit_for_bit():
    plant = Plant(VEHICLE, 0.01, wind=WIND)
    plant.reset(start())
    params = ParamBatch.from_preset(VEHICLE, 1)
    s, w = start()[None], plant.rotor[None].copy()
    cmd = np.array([0.55, 0.5, 0.52, 0.53])
    for _ in range(50):
        plant.step(cmd, armed=True)
        s, w = dynamics.step(
            s, w, cmd[None], params, 0.01, force=(VEHICLE.drag * np.array(WIND))[None], wind=np.array([WIND])
        )
    assert plant.state.tobytes() == s[0].tobytes() and plant.rotor.tobytes() == w[0].tobytes()
    still = Plant(VEHICLE, 0.01)
    still.reset(start())
    for _ in range(50):
        still.step(cmd, armed=True)
    assert np.abs(still.state[VEL] - plant.state[VEL]).max() > 0.05  # the wind acts through the drag


def test_the_accelerometer_measures_the_drag_the_dynamics_applies():
    """Specific force = Rᵀ(a + g·e_z), with a the acceleration of one dynamics step (constant over
    the step: v1 = v0 + h·a)."""
    plant = Plant(VEHICLE, 0.01, wind=WIND)
    plant.reset(start())
    measured = plant.specific_force_flu()
    h = 1e-6
    s1, _ = dynamics.step(
        plant.state[None],
        plant.rotor[None],
        plant.rotor[None],
        plant.params,
        h,
        force=(VEHICLE.drag * np.array(WIND))[None],
        wind=np.array([WIND]),
    )
    a = (s1[0, VEL] - plant.state[VEL]) / h + np.array([0.0, 0.0, VEHICLE.gravity])
    np.testing.assert_allclose(measured, sensors.world_to_body(plant.state, a), rtol=1e-6, atol=1e-6)
    drag = sensors.air_force_flu(plant.state, plant.rotor, VEHICLE, WIND)
    assert np.linalg.norm(drag) > 0.1  # the term is not negligible in this check


def test_wind_adds_no_assumed_linear_drag_to_a_vehicle_with_its_own_drag_law():
    """DEFAULT_WIND_DRAG stands in for a vehicle without any drag law; RotorPy's quadratic drag and
    rotor aerodynamics act on the wind themselves, so nothing is added to them."""
    from quadpilot.simulator import DEFAULT_WIND_DRAG, SimConfig

    windy = dict(wind=(3.0, 0.0, 0.0))
    assert SimConfig(**windy).effective_drag == DEFAULT_WIND_DRAG  # the seed vehicle: no drag law
    quadratic_only = dataclasses.replace(VEHICLE, drag=0.0)
    own = SimConfig(**windy, airframe=quadratic_only)
    assert own.effective_drag == 0.0 and own.vehicle_params.c_dx == VEHICLE.c_dx
