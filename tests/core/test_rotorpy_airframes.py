"""Every airframe RotorPy 3.0.0 ships (rotorpy/vehicles/*_params.py), converted to a vehicle file by
`core.rotorpy_vehicle`, against RotorPy's own `Multirotor` with aerodynamics on: the same forces and
moments at any state (tilted, turning, moving, in wind, rotors at any speed), and the same flight
for the same motor commands. RotorPy is the reference: it is not our code."""

import dataclasses
import importlib
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadpilot.core import dynamics
from quadpilot.core.frames import euler_to_rotmat
from quadpilot.core.params import ParamBatch
from quadpilot.core.rotorpy_vehicle import RotorPyAirframeError, main, vehicle_from_rotorpy
from quadpilot.core.state import ATT, POS, RATES, VEL, Z
from quadpilot.core.vehicle_file import load_vehicle_file, vehicle_to_toml

AIRFRAMES = ["hummingbird", "crazyflie", "crazyfliebrushless", "px4_sihsim_quadx"]
G_ROTORPY = 9.81  # m/s², Multirotor.g


def rotorpy_params(name: str) -> dict:
    return importlib.import_module(f"rotorpy.vehicles.{name}_params").quad_params


# RotorPy ships every airframe with k_flap = 0 and equal c_Dx, c_Dy: one more, its Hummingbird with
# blade flapping and unequal drag, so that every term and axis is checked
VARIANTS = {"hummingbird_flapping": ("hummingbird", {"k_flap": 5e-6, "c_Dy": 2e-2})}


@pytest.fixture(params=AIRFRAMES + sorted(VARIANTS))
def airframe(request, tmp_path):
    """(RotorPy's quad_params, our vehicle read back from the file written for them)."""
    name = request.param
    path = tmp_path / f"{name}.toml"
    if name in VARIANTS:
        base, changes = VARIANTS[name]
        rp = dict(rotorpy_params(base), **changes)
        path.write_text(vehicle_to_toml(vehicle_from_rotorpy(rp, name)), encoding="utf-8")
        return rp, load_vehicle_file(path)
    assert main([f"rotorpy.vehicles.{name}_params", "-o", str(path)]) == 0
    return rotorpy_params(name), load_vehicle_file(path)


def rotorpy_state(s: np.ndarray, omega: np.ndarray, wind) -> dict:
    return {
        "x": s[POS].copy(),
        "v": s[VEL].copy(),
        "q": Rotation.from_matrix(euler_to_rotmat(*s[ATT])).as_quat(),  # [x, y, z, w]
        "w": s[RATES].copy(),
        "wind": np.asarray(wind, float),
        "rotor_speeds": np.asarray(omega, float),
    }


def test_nothing_of_the_dynamics_is_dropped(airframe):
    rp, v = airframe
    assert (v.c_dx, v.c_dy, v.c_dz) == (rp["c_Dx"], rp["c_Dy"], rp["c_Dz"])
    assert (v.k_d, v.k_z, v.k_h, v.k_flap) == (rp["k_d"], rp["k_z"], rp["k_h"], rp["k_flap"])
    assert (v.mass, v.ixx, v.iyy, v.izz, v.k_f) == (rp["mass"], rp["Ixx"], rp["Iyy"], rp["Izz"], rp["k_eta"])
    assert (v.omega_max, v.omega_min, v.motor_tau) == (rp["rotor_speed_max"], rp["rotor_speed_min"], rp["tau_m"])
    assert v.k_m * v.k_f == pytest.approx(rp["k_m"], rel=1e-11)


def test_the_forces_and_moments_are_rotorpys(airframe):
    """Linear and angular acceleration at the start of a step (our step is explicit in both: the
    velocity and rate change over one step over its length), against RotorPy's body wrench."""
    from rotorpy.vehicles.multirotor import Multirotor

    rp, v = airframe
    model = Multirotor(rp, aero=True)
    rng = np.random.default_rng(0)
    params = ParamBatch.from_preset(v, 1)
    inertia = np.diag([v.ixx, v.iyy, v.izz])
    for _ in range(20):
        s = np.zeros(12)
        s[Z], s[ATT], s[VEL], s[RATES] = 5.0, rng.normal(0, 0.4, 3), rng.normal(0, 3, 3), rng.normal(0, 2, 3)
        wind = rng.normal(0, 3, 3)
        u = rng.uniform(0.3, 1.0, 4)  # ω/ω_max, held: our rotor state equals the command (no change)
        omega = u * v.omega_max
        h = 1e-3
        s1, _ = dynamics.step(s[None], u[None], u[None], params, h, wind=wind[None])
        ours_acc = (s1[0, VEL] - s[VEL]) / h
        ours_alpha = (s1[0, RATES] - s[RATES]) / h
        rot = euler_to_rotmat(*s[ATT])
        force, moment = model.compute_body_wrench(s[RATES], omega, rot.T @ (s[VEL] - wind))
        theirs_acc = rot @ force / v.mass - np.array([0.0, 0.0, G_ROTORPY])
        w = s[RATES]
        theirs_alpha = np.linalg.solve(inertia, moment - np.cross(w, inertia @ w))
        scale_a = max(1.0, np.abs(theirs_acc).max())
        np.testing.assert_allclose(ours_acc, theirs_acc, rtol=1e-6, atol=1e-9 * scale_a)
        np.testing.assert_allclose(ours_alpha, theirs_alpha, rtol=1e-6, atol=1e-6 * np.abs(theirs_alpha).max())


def test_the_same_commands_fly_the_same_flight(airframe):
    """Two seconds open loop at 100 Hz from a tilted, moving start in a wind, the motor commands
    wandering around hover: RotorPy integrates with RK45 (and its own quaternion), we with one
    explicit step of 10 ms; positions agree within 1 cm of each other per metre travelled."""
    from rotorpy.vehicles.multirotor import Multirotor

    rp, v = airframe
    rng = np.random.default_rng(1)
    s = np.zeros(12)
    s[Z], s[ATT], s[VEL], s[RATES] = 5.0, (0.05, -0.04, 0.3), (1.0, -0.5, 0.2), (0.1, -0.1, 0.05)
    wind = np.array([2.0, -1.0, 0.0])
    u = np.full(4, v.hover_command)
    state = rotorpy_state(s, u * v.omega_max, wind)
    model = Multirotor(rp, initial_state=state, aero=True)
    params = ParamBatch.from_preset(v, 1)
    ours, w = s[None].copy(), u[None].copy()
    travelled = 0.0
    for _ in range(200):
        cmd = np.clip(v.hover_command + rng.normal(0, 0.004, 4), 0, 1)
        state = model.step(state, {"cmd_motor_speeds": cmd * v.omega_max}, 0.01)
        before = ours[0, POS].copy()
        ours, w = dynamics.step(ours, w, cmd[None], params, 0.01, wind=wind[None])
        travelled += float(np.linalg.norm(ours[0, POS] - before))
    gap = float(np.linalg.norm(ours[0, POS] - state["x"]))
    assert travelled > 0.5 and gap <= 0.01 * travelled, (gap, travelled)


def test_an_airframe_the_model_cannot_hold_is_refused_in_one_line():
    rp = dict(rotorpy_params("hummingbird"), Ixy=1e-5)
    with pytest.raises(RotorPyAirframeError, match=r"Ixy = 1e-05: the model takes a diagonal inertia"):
        vehicle_from_rotorpy(rp, "x")
    pos = dict(rotorpy_params("hummingbird")["rotor_pos"], r1=np.array([0.1, 0.1, 0.02]))
    with pytest.raises(RotorPyAirframeError, match=r"rotor_pos r1: z = 0\.02"):
        vehicle_from_rotorpy(dict(rotorpy_params("hummingbird"), rotor_pos=pos), "x")
    with pytest.raises(RotorPyAirframeError, match="k_eta: missing"):
        vehicle_from_rotorpy({k: x for k, x in rotorpy_params("hummingbird").items() if k != "k_eta"}, "x")
    assert main(["../not/a/module"]) == 2
    assert main(["rotorpy.vehicles.no_such_params"]) == 1


def test_the_model_flies_without_rotor_aerodynamics_as_before():
    """Coefficients at 0 are no terms at all: the Hummingbird file without them steps exactly as a
    vehicle built without the fields."""
    v = vehicle_from_rotorpy(rotorpy_params("hummingbird"), "h")
    bare = dataclasses.replace(v, c_dx=0.0, c_dy=0.0, c_dz=0.0, k_d=0.0, k_z=0.0, k_h=0.0, k_flap=0.0)
    s = np.zeros((1, 12))
    s[0, Z], s[0, VEL] = 5.0, (1.0, 0.0, 0.0)
    u = np.full((1, 4), 0.4)
    a = dynamics.step(s, u, u, ParamBatch.from_preset(bare, 1), 0.01, wind=np.array([[3.0, 0.0, 0.0]]))
    b = dynamics.step(s, u, u, ParamBatch.from_preset(bare, 1), 0.01)
    assert a[0].tobytes() == b[0].tobytes()
    assert not math.isclose(
        dynamics.step(s, u, u, ParamBatch.from_preset(v, 1), 0.01)[0][0, 3], a[0][0, 3], rel_tol=1e-9
    )


@pytest.mark.parametrize("path", sorted((Path(__file__).parents[2] / "benchmarks" / "airframes").glob("*.toml")))
def test_a_vehicle_file_goes_to_rotorpy_and_back(path):
    """rotorpy_params (a vehicle for RotorPy's simulators) and vehicle_from_rotorpy are inverses on the
    airframe set, and RotorPy's Multirotor computes the wrench our dynamics does for it."""
    from rotorpy.vehicles.multirotor import Multirotor

    from quadpilot.core.rotorpy_vehicle import MIN_TAU_M_S, rotorpy_params

    v = load_vehicle_file(path)
    back = vehicle_from_rotorpy(rotorpy_params(v), v.name)
    assert back.motor_tau == max(v.motor_tau, MIN_TAU_M_S)  # RotorPy cannot step a rotor without lag
    assert dataclasses.replace(back, arm=v.arm, k_m=v.k_m, motor_tau=v.motor_tau) == v
    assert back.k_m == pytest.approx(v.k_m, rel=1e-12) and back.arm == pytest.approx(v.arm, rel=1e-9)
    model = Multirotor(rotorpy_params(v), aero=True)
    u = np.array([0.5, 0.6, 0.7, 0.8])
    force, moment = model.compute_body_wrench(np.zeros(3), u * v.omega_max, np.zeros(3))
    s = np.zeros(12)
    s[Z] = 5.0
    s1, _ = dynamics.step(s[None], u[None], u[None], ParamBatch.from_preset(v, 1), 1e-3)
    np.testing.assert_allclose((s1[0, VEL] - s[VEL]) / 1e-3 + [0, 0, G_ROTORPY], force / v.mass, rtol=1e-9, atol=1e-9)
    alpha = moment / np.array([v.ixx, v.iyy, v.izz])  # at rest: no gyroscopic term
    np.testing.assert_allclose(s1[0, RATES] / 1e-3, alpha, rtol=1e-7, atol=1e-9 * np.abs(alpha).max())


def test_a_vehicle_with_linear_drag_is_not_flown_in_rotorpy_without_it():
    from quadpilot.core.rotorpy_vehicle import rotorpy_params

    with pytest.raises(RotorPyAirframeError, match="RotorPy has no linear drag"):
        rotorpy_params(load_vehicle_file(Path(__file__).parents[2] / "src/quadpilot/vehicles/px4_sih_quadx.toml"))


def test_a_vehicle_without_motor_lag_steps_in_rotorpy():
    """RotorPy integrates the rotor speeds as (command − speed)/tau_m: the asymmetric frame (no lag)
    divided by zero in RotorPy's PX4 simulator before it was given MIN_TAU_M_S."""
    from rotorpy.vehicles.multirotor import Multirotor

    from quadpilot.core.rotorpy_vehicle import rotorpy_params

    v = load_vehicle_file(Path(__file__).parents[2] / "benchmarks/airframes/asymmetric.toml")
    assert v.motor_tau == 0.0
    model = Multirotor(rotorpy_params(v))
    state = {k: np.array(x, float) for k, x in model.initial_state.items()}
    out = model.step(state, {"cmd_motor_speeds": np.full(4, 0.6 * v.omega_max)}, 0.01)
    assert all(np.all(np.isfinite(x)) for x in out.values())
    np.testing.assert_allclose(out["rotor_speeds"], 0.6 * v.omega_max, rtol=1e-3)  # a lag far under the step


def test_one_step_of_spinning_rotors_lifts_and_turns_as_rotorpys(airframe):
    """One 10 ms step from rest with the rotors far from their commands (two at 95 %, two at 35 %,
    all from 30 % of full speed): the velocity and body rates it ends with are RotorPy's, which
    integrates the motor lag with the rest of the state, within 1 %. The thrust of the step is the
    mean of ω² along the lag; the end's ω² held for the whole step, as this model took it before, is
    off by a quarter on the 72 ms Crazyflie (the policies trained on it oscillated in RotorPy)."""
    from rotorpy.vehicles.multirotor import Multirotor

    rp, v = airframe
    assert v.motor_tau > 0.0  # every RotorPy airframe has one (RotorPy cannot step a rotor without it)
    s = np.zeros(12)
    s[Z] = 5.0
    w0 = np.full(4, 0.3)
    cmd = np.array([0.95, 0.35, 0.95, 0.35])
    state = rotorpy_state(s, w0 * v.omega_max, np.zeros(3))
    model = Multirotor(rp, initial_state=state, aero=True)
    theirs = model.step(state, {"cmd_motor_speeds": cmd * v.omega_max}, 0.01)
    ours, w = dynamics.step(s[None], w0[None], cmd[None], ParamBatch.from_preset(v, 1), 0.01)
    np.testing.assert_allclose(w[0] * v.omega_max, theirs["rotor_speeds"], rtol=1e-3)  # RK45 against exact
    lift = theirs["v"][2]  # m/s gained upwards (or lost) in the step
    np.testing.assert_allclose(ours[0, VEL][2], lift, rtol=0.01, atol=1e-3 * G_ROTORPY * 0.01)
    turn = theirs["w"]
    np.testing.assert_allclose(ours[0, RATES], turn, rtol=0.01, atol=0.01 * np.abs(turn).max())
