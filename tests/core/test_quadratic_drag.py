"""Quadratic parasitic drag per body axis (`VehicleParams.c_dx, c_dy, c_dz`) against RotorPy 3.0.0's
own model: rotorpy/vehicles/multirotor.py with aerodynamics on and every aerodynamic term but the
parasitic drag zero (k_d, k_z, k_h, k_flap), so that the two simulators differ only in the law
under test. Rotors stopped, so the only forces are gravity and drag; a vehicle tilted, moving and
in wind, so that each axis' coefficient, the rotation both ways and the wind all count."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadpilot.core import dynamics
from quadpilot.core.frames import euler_to_rotmat
from quadpilot.core.params import ParamBatch
from quadpilot.core.state import ATT, VEL, Z
from quadpilot.core.vehicle_file import load_vehicle_file

HUMMINGBIRD = Path(__file__).parents[1] / "data" / "vehicles" / "rotorpy_hummingbird.toml"
DT = 1e-3  # s: short against the drag's time constant, so RotorPy's RK45 and our step agree closely


def rotorpy_drag_only():
    from rotorpy.vehicles.hummingbird_params import quad_params

    params = dict(quad_params, k_d=0.0, k_z=0.0, k_h=0.0, k_flap=0.0)
    # c_Dx ≠ c_Dy here (RotorPy's Hummingbird has them equal) so that a swapped axis shows
    params.update(c_Dx=0.5e-2, c_Dy=2e-2, c_Dz=1e-2)
    return params


def rotorpy_velocity_after(params, attitude, velocity, wind) -> np.ndarray:
    from rotorpy.vehicles.multirotor import Multirotor

    quat = Rotation.from_matrix(euler_to_rotmat(*attitude)).as_quat()  # [x, y, z, w], as RotorPy's q
    state = {
        "x": np.array([0.0, 0.0, 5.0]),
        "v": np.asarray(velocity, float),
        "q": quat,
        "w": np.zeros(3),
        "wind": np.asarray(wind, float),
        "rotor_speeds": np.zeros(4),
    }
    rp = Multirotor(params, initial_state=state, aero=True)
    return rp.step(state, {"cmd_motor_speeds": np.zeros(4)}, DT)["v"]


CASES = [  # (roll, pitch, yaw) rad, velocity m/s ENU, wind m/s ENU
    ((0.0, 0.0, 0.0), (3.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (0.0, 3.0, 0.0), (0.0, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (0.0, 0.0, -3.0), (0.0, 0.0, 0.0)),
    ((0.3, -0.2, 1.1), (2.0, -1.0, 0.5), (0.0, 0.0, 0.0)),
    ((-0.4, 0.5, -2.5), (1.0, 4.0, -1.0), (-3.0, 2.0, 0.5)),
    ((0.1, 0.2, 0.3), (0.0, 0.0, 0.0), (5.0, -4.0, 0.0)),
]


@pytest.mark.parametrize("attitude, velocity, wind", CASES)
def test_the_velocity_change_is_rotorpys(attitude, velocity, wind):
    rp_params = rotorpy_drag_only()
    v = dataclasses.replace(
        load_vehicle_file(HUMMINGBIRD), drag=0.0, c_dx=rp_params["c_Dx"], c_dy=rp_params["c_Dy"], c_dz=rp_params["c_Dz"]
    )
    s = np.zeros((1, 12))
    s[0, Z], s[0, VEL], s[0, ATT] = 5.0, velocity, attitude
    s1, _ = dynamics.step(
        s, np.zeros((1, 4)), np.zeros((1, 4)), ParamBatch.from_preset(v, 1), DT, wind=np.array([wind], float)
    )
    ours = (s1[0, VEL] - s[0, VEL]) / DT + np.array([0.0, 0.0, v.gravity])  # drag / m, world ENU
    theirs = (rotorpy_velocity_after(rp_params, attitude, velocity, wind) - s[0, VEL]) / DT
    theirs += np.array([0.0, 0.0, 9.81])  # RotorPy's g
    assert np.linalg.norm(ours) > 0.05 or np.linalg.norm(np.subtract(velocity, wind)) == 0
    # within what one step at the start-of-step velocity differs from RotorPy's RK45 over it: gravity
    # changes v by g·DT during the step, and the drag with it (about 3e-4 m/s² here)
    np.testing.assert_allclose(ours, theirs, rtol=2e-3, atol=1e-3)


def test_without_quadratic_drag_the_wind_changes_nothing():
    """The quadratic law is the only one that reads `wind` (the linear one takes it as a force)."""
    v = load_vehicle_file(HUMMINGBIRD)
    assert v.c_dx == v.c_dy == v.c_dz == 0.0
    s = np.zeros((1, 12))
    s[0, Z], s[0, VEL] = 5.0, (1.0, 2.0, 0.0)
    params = ParamBatch.from_preset(v, 1)
    still = dynamics.step(s, np.zeros((1, 4)), np.zeros((1, 4)), params, DT)
    windy = dynamics.step(s, np.zeros((1, 4)), np.zeros((1, 4)), params, DT, wind=np.array([[4.0, 0.0, 0.0]]))
    assert still[0].tobytes() == windy[0].tobytes()


def test_a_wind_of_the_wrong_shape_is_refused_naming_it():
    v = dataclasses.replace(load_vehicle_file(HUMMINGBIRD), c_dx=0.005)
    params = ParamBatch.from_preset(v, 2)
    s, w = np.zeros((12, 2)), np.zeros((4, 2))
    with pytest.raises(ValueError, match=r"wind must have shape \(2, 3\) \(m/s, world ENU\), got \(3,\)"):
        dynamics.Stepper(2, 4, np.float64).step(s, w, w.copy(), params, 0.01, wind=np.zeros(3))


def test_the_stepper_takes_one_substep_of_the_control_period_by_default():
    v = load_vehicle_file(HUMMINGBIRD)
    params = ParamBatch.from_preset(v, 1)
    s0 = np.zeros((1, 12))
    s0[0, Z], s0[0, ATT] = 5.0, (0.3, -0.2, 0.1)
    u = np.full((1, 4), 0.6)
    want, _ = dynamics.step(s0, u, u, params, dynamics.DT, substeps=1)
    s, w = np.array(s0.T, order="C"), np.array(u.T, order="C")  # copies: the rows are advanced in place
    dynamics.Stepper(1, 4, np.float64).step(s, w, np.array(u.T, order="C"), params)
    assert s.T.tobytes() == want.tobytes()
