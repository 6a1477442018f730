"""Any rotor layout and any output order: the dynamics give each rotor the torque its position and
spin give it, the hover trim holds the vehicle still, RotorPy computes the same wrench for the same
vehicle file, a per-drone arm scales the whole frame, and an idle speed (omega_min) clips the
commanded rotor speed as RotorPy clips it while motors off stop the rotors.

The oracle is written in the body FRD frame the vehicle files use, independently of the model's
FLU rows: a rotor at r = (x, y, 0) pushing F along −z_FRD (up) makes r × F = (−y·F, x·F, 0); a
rotor spinning counter-clockwise seen from above is driven by a motor torque along up, so the body
feels a clockwise torque seen from above, +z_FRD (z points down): +k_m·F for "ccw", −k_m·F for
"cw". FRD → FLU is (τx, −τy, −τz).
"""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from quadpilot.core import dynamics
from quadpilot.core.dynamics import IDX, step
from quadpilot.core.params import NUM_MOTORS, ParamBatch, Rotor, VehicleParams, allocation_matrix, unit_layout
from quadpilot.core.vehicle_file import PX4_SIH_QUADX, SEED_VEHICLE, load_vehicle_file, resolve_vehicle

H = 0.01  # s
HUMMINGBIRD = Path(__file__).parents[1] / "data" / "vehicles" / "rotorpy_hummingbird.toml"


def frame(name: str, rotors) -> VehicleParams:
    """The seed vehicle's mass, inertia and rotors on another frame (rotors in FRD, output order)."""
    return dataclasses.replace(SEED_VEHICLE, name=name, arm=None, rotors=[Rotor(*r) for r in rotors])


LAYOUTS = {
    # "+" frame numbered clockwise from the nose: a layout the project never had
    "plus": frame("plus", [(0.105, 0.0, "ccw"), (0.0, 0.105, "cw"), (-0.105, 0.0, "ccw"), (0.0, -0.105, "cw")]),
    # PX4's quad-X with its outputs permuted: output 1 is PX4's 3, 2 is 1, 3 is 4, 4 is 2
    "permuted-quad-x": frame(
        "permuted",
        [(0.0742, -0.0742, "cw"), (0.0742, 0.0742, "ccw"), (-0.0742, 0.0742, "cw"), (-0.0742, -0.0742, "ccw")],
    ),
    # the centre of mass 2 cm ahead of the rotors' centre, a wide frame: the trim is not an equal split
    "offset-centre-of-mass": frame(
        "offset", [(0.08, 0.12, "ccw"), (-0.12, -0.12, "ccw"), (0.08, -0.12, "cw"), (-0.12, 0.12, "cw")]
    ),
    "rotorpy-hummingbird": load_vehicle_file(HUMMINGBIRD),
    "px4-sih-quadx": PX4_SIH_QUADX,
}
IDS = sorted(LAYOUTS)


def frd_torque(vehicle: VehicleParams, i: int, force: float) -> np.ndarray:
    """Body torque (N·m, FLU) of rotor i alone pushing `force` N, from the FRD physics above."""
    r = vehicle.rotors[i]
    tau_frd = np.cross([r.x, r.y, 0.0], [0.0, 0.0, -force])
    tau_frd[2] += (1.0 if r.spin == "ccw" else -1.0) * vehicle.k_m * force
    return tau_frd * np.array([1.0, -1.0, -1.0])


def at_rest(n=1, z=5.0):
    s = np.zeros((n, 12))
    s[:, IDX["z"]] = z
    return s


@pytest.mark.parametrize("name", IDS)
@pytest.mark.parametrize("rotor", range(NUM_MOTORS))
def test_each_rotor_alone_gives_the_torque_of_its_position_and_spin(name, rotor):
    """From rest at the hover trim, raising one rotor's thrust by ΔF gives, after one step, body
    rates h·τ/I exactly (no gyroscopic term at zero rate), τ that rotor's torque."""
    v = LAYOUTS[name]
    params = ParamBatch.from_preset(v, 1)
    trim = v.hover_thrusts
    df = 0.2 * float(trim.mean())
    thrusts = trim.copy()
    thrusts[rotor] += df
    cmd = (np.sqrt(thrusts / v.k_f) / v.omega_max)[None]
    s1, _ = step(at_rest(), cmd, cmd, params, H)
    want = H * frd_torque(v, rotor, df) / np.array([v.ixx, v.iyy, v.izz])
    np.testing.assert_allclose(s1[0, 9:12], want, rtol=1e-9, atol=1e-15)


def test_the_plus_frame_rotors_turn_the_body_the_way_a_pilot_expects():
    """The "+" frame, output by output: the nose rotor pitches the nose up (−q in FLU), the right
    rotor lifts the right side (−p), the tail rotor pitches the nose down (+q), the left rotor
    lifts the left side (+p); CCW rotors yaw the body clockwise seen from above (−r), CW ones
    counter-clockwise (+r)."""
    v = LAYOUTS["plus"]
    params = ParamBatch.from_preset(v, 1)
    expected = {0: (0, -1, -1), 1: (-1, 0, +1), 2: (0, +1, -1), 3: (+1, 0, +1)}
    for rotor, signs in expected.items():
        cmd = np.full((1, 4), v.hover_command)
        cmd[0, rotor] *= math.sqrt(1.2)
        s1, _ = step(at_rest(), cmd, cmd, params, H)
        got = tuple(int(np.sign(round(x, 12))) for x in s1[0, 9:12])
        assert got == signs, (rotor, got)


@pytest.mark.parametrize("name", IDS)
def test_the_hover_trim_holds_any_layout_still(name):
    """`hover_commands` (the allocation solved for zero torque) holds hover for 5 s; on the layout
    whose centre of mass is off the rotors' centre, the equal split (`hover_command`) does not."""
    v = LAYOUTS[name]
    params = ParamBatch.from_preset(v, 1)
    trim = np.asarray(v.hover_commands)[None]
    s = at_rest()
    s[0, IDX["yaw"]] = 0.4
    s0, w = s.copy(), trim.copy()
    for _ in range(500):
        s, w = step(s, w, trim, params, H)
    assert np.abs(s - s0).max() < 1e-6, np.abs(s - s0).max()
    balanced = np.allclose(v.hover_thrusts, v.hover_thrust, rtol=1e-12)
    assert balanced == (name != "offset-centre-of-mass")
    if not balanced:
        equal = np.full((1, 4), v.hover_command)
        s, w = s0.copy(), equal.copy()
        for _ in range(100):
            s, w = step(s, w, equal, params, H)
        assert np.abs(s[0, 6:9]).max() > 0.05  # it tips over within a second
    else:
        assert np.all(np.asarray(v.hover_commands) == v.hover_command)
        assert dynamics.hover_command(v) == pytest.approx(v.hover_command, rel=1e-12)


@pytest.mark.parametrize("name", ["rotorpy-hummingbird", "px4-sih-quadx"])
def test_rotorpy_computes_the_same_wrench_for_the_same_vehicle_file(name):
    """RotorPy 3.0.0's own model of the vehicle (rotorpy/vehicles/*_params.py), aerodynamics off,
    one rotor spinning at a time: its body wrench (FLU) equals our allocation matrix's, and our
    dynamics' one-step rate change from rest is that moment over the inertia."""
    from rotorpy.vehicles.multirotor import Multirotor

    if name == "px4-sih-quadx":
        from rotorpy.vehicles.px4_sihsim_quadx_params import quad_params
    else:
        from rotorpy.vehicles.hummingbird_params import quad_params
    v = resolve_vehicle("px4_sih_quadx") if name == "px4-sih-quadx" else load_vehicle_file(HUMMINGBIRD)
    rp = Multirotor(quad_params, aero=False)
    np.testing.assert_allclose(rp.f_to_TM, allocation_matrix(v), rtol=1e-9, atol=1e-15)
    params = ParamBatch.from_preset(v, 1)
    for i in range(4):
        omega = np.zeros(4)
        omega[i] = 0.6 * v.omega_max
        force, moment = rp.compute_body_wrench(np.zeros(3), omega, np.zeros(3))
        thrusts = v.k_f * omega**2
        np.testing.assert_allclose(force, [0.0, 0.0, thrusts.sum()], rtol=1e-12)
        np.testing.assert_allclose(allocation_matrix(v) @ thrusts, [force[2], *moment], rtol=1e-9, atol=1e-15)
        cmd = (omega / v.omega_max)[None]
        s1, _ = step(at_rest(), cmd, cmd, params, H)
        np.testing.assert_allclose(s1[0, 9:12] * np.array([v.ixx, v.iyy, v.izz]) / H, moment, rtol=1e-9, atol=1e-12)


def test_a_per_drone_arm_scales_the_whole_frame():
    """ParamBatch.arm is a per-drone scale of the layout (what randomising `arm` did for the quad-X):
    twice the arm, twice the roll and pitch torque of the same thrusts; yaw unchanged."""
    v = LAYOUTS["offset-centre-of-mass"]
    base = ParamBatch.from_preset(v, 2)
    params = base.with_entries(np.array([1]), arm=2.0 * v.arm)
    cmd = np.tile(np.array([0.5, 0.6, 0.7, 0.8]), (2, 1))
    s1, _ = step(at_rest(2), cmd, cmd, params, H)
    np.testing.assert_allclose(s1[1, 9:11], 2.0 * s1[0, 9:11], rtol=1e-12)
    assert s1[1, 11] == s1[0, 11]
    assert params.layout == base.layout == unit_layout(v)


def test_the_quad_x_rows_are_seed_001s_written_out():
    """For PX4's quad-X the compiled mixer is the hand-written one: sums and differences of the
    rotor thrusts times arm/√2 (roll, pitch) and k_m (yaw), no per-rotor multiplication."""
    d = dynamics._derived(ParamBatch.from_preset(SEED_VEHICLE, 1), H, np.float64)
    src = d.wrench.source
    assert "a0 * (-f[0] + f[1] + f[2] - f[3])" in src
    assert "a1 * (-f[0] + f[1] - f[2] + f[3])" in src
    assert "a2 * (-f[0] - f[1] + f[2] + f[3])" in src
    assert "k0" not in src  # no per-rotor coefficient


def test_the_dynamics_step_any_rotor_count():
    """core.dynamics is written over the layout, not four rotors: a hexacopter batch (rotors every
    60°, spins alternating round the frame) hovers on an equal command and yaws with its CW rotors raised. A
    VehicleParams, which the policy and the actuator outputs use, refuses six rotors."""
    angles = np.radians([90, 270, 330, 150, 30, 210])  # from +x towards +y (FLU), in an arbitrary output order
    spins = [-1, 1, -1, 1, 1, -1]
    layout = tuple((math.cos(a), math.sin(a), float(s)) for a, s in zip(angles, spins, strict=True))
    base = ParamBatch.from_preset(SEED_VEHICLE, 1)
    hexa = dataclasses.replace(base, layout=layout)
    assert hexa.n_rotors == 6
    u = float(dynamics.hover_command(hexa)[0])
    assert 6 * SEED_VEHICLE.k_f * (u * SEED_VEHICLE.omega_max) ** 2 == pytest.approx(SEED_VEHICLE.weight)
    cmd = np.full((1, 6), u)
    s, w = at_rest(), cmd.copy()
    for _ in range(100):
        s, w = step(s, w, cmd, hexa, H)
    assert np.abs(s - at_rest()).max() < 1e-9
    cmd[0, np.array(spins) < 0] *= 1.05
    s1, _ = step(at_rest(), cmd, cmd, hexa, H)
    assert s1[0, 11] > 0 and abs(s1[0, 9]) < 1e-12 and abs(s1[0, 10]) < 1e-12
    with pytest.raises(ValueError, match=r"rotors: 6 rotor\(s\); expected 4"):
        dataclasses.replace(SEED_VEHICLE, arm=None, rotors=[Rotor(math.cos(a), -math.sin(a), "cw") for a in angles])


# --- idle speed and motors off ------------------------------------------------------------------

IDLE = dataclasses.replace(SEED_VEHICLE, name="idle", omega_min=400.0)  # rad/s, 20 % of omega_max


def test_the_commanded_speed_is_clipped_to_omega_min_and_omega_max_as_rotorpy_clips_it():
    """ω = clip(command·ω_max, ω_min, ω_max): RotorPy 3.0.0 rotorpy/vehicles/multirotor.py,
    Multirotor.step, np.clip(cmd_rotor_speeds, rotor_speed_min, rotor_speed_max). Without a lag the
    rotor state is the clipped command."""
    params = ParamBatch.from_preset(IDLE, 1)
    commands = np.array([[0.0, 0.1, 0.5, 1.3]])
    _, w = step(at_rest(), np.zeros((1, 4)), commands, params, H)
    want = np.clip(commands * IDLE.omega_max, IDLE.omega_min, IDLE.omega_max) / IDLE.omega_max
    np.testing.assert_allclose(w, want, rtol=1e-15)


def test_an_armed_motor_idles_at_omega_min_and_motors_off_stop_it():
    """Command 0, armed: the rotors idle at ω_min and lift (4·k_f·ω_min² up, 0.86 m/s² here);
    motors off (armed False): no thrust, free fall, whatever ω_min."""
    params = ParamBatch.from_preset(IDLE, 2)
    zero = np.zeros((2, 4))
    s1, w = step(at_rest(2), zero, zero, params, H, armed=np.array([True, False]))
    idle_acc = 4 * IDLE.k_f * IDLE.omega_min**2 / IDLE.mass - IDLE.gravity
    assert s1[0, IDX["vz"]] == pytest.approx(H * idle_acc, rel=1e-12)
    assert s1[1, IDX["vz"]] == pytest.approx(-H * IDLE.gravity, rel=1e-12)
    np.testing.assert_allclose(w, [[0.2] * 4, [0.0] * 4], rtol=1e-15)


def test_with_a_motor_lag_rotors_spin_up_from_rest_and_down_when_off():
    """The rotor state is not clipped: from rest it rises towards ω_min through the lag
    (1 − e^(−t/τ)), and motors off let it decay from hover (e^(−t/τ))."""
    v = dataclasses.replace(IDLE, motor_tau=0.05)
    params = ParamBatch.from_preset(v, 2)
    w = np.array([[0.0] * 4, [v.hover_command] * 4])
    s = at_rest(2)
    armed = np.array([True, False])
    for _ in range(10):  # 0.1 s = 2τ
        s, w = step(s, w, np.zeros((2, 4)), params, H, armed=armed)
    np.testing.assert_allclose(w[0], 0.2 * (1 - math.exp(-2.0)), rtol=1e-12)
    np.testing.assert_allclose(w[1], v.hover_command * math.exp(-2.0), rtol=1e-12)


def test_omega_min_must_be_below_omega_max():
    with pytest.raises(ValueError, match=r"omega_min = 2000\.0: expected below omega_max"):
        dataclasses.replace(SEED_VEHICLE, omega_min=2000.0)
    with pytest.raises(ValueError, match=r"armed must have shape \(1,\)"):
        step(at_rest(), np.zeros((1, 4)), np.zeros((1, 4)), ParamBatch.from_preset(IDLE, 1), H, armed=[True, False])
