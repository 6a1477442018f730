"""Oracle tests of the rigid-body quadrotor dynamics (`core.dynamics`) against closed forms.

World ENU (z up), body FLU. R = Rz(ψ)·Ry(θ)·Rx(φ), built here from elementary matrices.
Rotors in PX4's quad-X order: 0 front-right CCW, 1 rear-left CCW, 2 front-left CW, 3 rear-right CW.
For a rotor at body position (x_i, y_i, 0) lifting F_i along +z_body, τ = r × F = (y_i·F_i, −x_i·F_i, 0);
a rotor spinning CCW seen from above is driven by a +z motor torque, so it pushes the body with −z
(k_m·F_i), a CW one with +z. The integrator (module docstring): body rates by forward Euler on
I·ω̇ = τ − ω × (I·ω); Euler angles with the mid-step rates; position p + h·v + h²/2·a, velocity v + h·a.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

from quadpilot.core import dynamics
from quadpilot.core.dynamics import IDX, STATE_DIM, hover_command, step
from quadpilot.core.params import GRAVITY, ParamBatch
from quadpilot.core.vehicle_file import SEED_VEHICLE

V = SEED_VEHICLE
H = 0.01  # s, one control step
A = V.arm / math.sqrt(2.0)  # moment arm of each rotor about the body x and y axes (X frame)
HOVER_F = V.mass * GRAVITY / 4.0  # N per rotor at hover
U_HOVER = math.sqrt(HOVER_F / V.k_f) / V.omega_max  # ω/ω_max at hover: F = k_f·(u·ω_max)²


def rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def one(n=1):
    return ParamBatch.from_preset(V, n)


def state(**kw) -> np.ndarray:
    s = np.zeros((1, STATE_DIM))
    for k, v in kw.items():
        s[0, IDX[k]] = v
    return s


def run(s, cmd, steps, params=None, substeps=1):
    params = params or one(s.shape[0])
    cmd = np.broadcast_to(np.asarray(cmd, float), (s.shape[0], 4)).copy()
    w = cmd.copy()
    for _ in range(steps):
        s, w = step(s, w, cmd, params, H, substeps)
    return s


# --- gravity, trim -------------------------------------------------------------------------------


@pytest.mark.parametrize("substeps", [1, 4])
def test_free_fall_with_motors_off(substeps):
    """Motors off: z = z0 + vz0·t − g·t²/2, vz = vz0 − g·t; horizontal velocity unchanged. The
    position update p + h·v + h²/2·a is exact for constant acceleration, so after 100 steps only
    float64 rounding remains (≈1e-14 m); 1e-9 leaves room for that and nothing else."""
    s0 = state(x=1.0, y=-2.0, z=10.0, vx=0.5, vy=-0.25, vz=1.0)
    s = run(s0, 0.0, 100, substeps=substeps)
    t = 1.0
    np.testing.assert_allclose(s[0, IDX["z"]], 10.0 + 1.0 * t - 0.5 * 9.81 * t * t, rtol=0, atol=1e-9)  # 6.095 m
    np.testing.assert_allclose(s[0, IDX["vz"]], 1.0 - 9.81 * t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s[0, [IDX["x"], IDX["y"]]], [1.0 + 0.5 * t, -2.0 - 0.25 * t], rtol=0, atol=1e-9)
    np.testing.assert_allclose(s[0, [IDX["vx"], IDX["vy"]]], [0.5, -0.25], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(s[0, 6:12], 0.0)


def test_hover_trim_thrust_equals_weight_and_holds_still():
    assert float(hover_command(V)) == pytest.approx(U_HOVER, rel=1e-12)
    assert 4 * V.k_f * (U_HOVER * V.omega_max) ** 2 == pytest.approx(V.mass * 9.81, rel=1e-12)
    s0 = state(x=0.3, y=-0.7, z=2.0, yaw=1.0)
    s = run(s0, U_HOVER, 500)  # 5 s
    np.testing.assert_allclose(s, s0, rtol=0, atol=1e-9)


# --- torques ------------------------------------------------------------------------------------

# rotor: (x_i, y_i) in units of arm/√2 (FLU) and spin (+1 CCW seen from above)
ROTORS = {0: (1.0, -1.0, +1), 1: (-1.0, 1.0, +1), 2: (1.0, 1.0, -1), 3: (-1.0, -1.0, -1)}
# the signs physics gives, rotor by rotor, when that one rotor alone is raised above hover:
#   roll rate p (+ = left side up), pitch rate q (+ = nose down in FLU), yaw rate r (+ = CCW from above)
SIGNS = {
    0: (-1, -1, -1),  # front-right: lifts the right side and the nose; CCW → body yaws CW
    1: (+1, +1, -1),  # rear-left: lifts the left side and the tail; CCW → body yaws CW
    2: (+1, -1, +1),  # front-left: lifts the left side and the nose; CW → body yaws CCW
    3: (-1, +1, +1),  # rear-right: lifts the right side and the tail; CW → body yaws CCW
}
DF = 0.2 * HOVER_F  # N, the extra thrust of the raised rotor(s)


def raised(*rotors) -> np.ndarray:
    cmd = np.full((1, 4), U_HOVER)
    for i in rotors:
        cmd[0, i] = U_HOVER * math.sqrt(1.2)  # F ∝ u²: 1.2 × hover thrust
    return cmd


@pytest.mark.parametrize("rotor", [0, 1, 2, 3])
def test_each_rotor_alone_gives_the_torque_of_its_position_and_spin(rotor):
    """One step from rest: ω1 = h·τ/I exactly (no gyroscopic term at ω = 0), with
    τ = (y_i·a·ΔF, −x_i·a·ΔF, −spin_i·k_m·ΔF)."""
    x_i, y_i, spin = ROTORS[rotor]
    s = run(state(z=5.0), raised(rotor), 1)
    p, q, r = s[0, 9:12]
    np.testing.assert_allclose(p, H * y_i * A * DF / V.ixx, rtol=1e-9)
    np.testing.assert_allclose(q, H * (-x_i) * A * DF / V.iyy, rtol=1e-9)
    np.testing.assert_allclose(r, H * (-spin) * V.k_m * DF / V.izz, rtol=1e-9)
    assert tuple(int(np.sign(v)) for v in (p, q, r)) == SIGNS[rotor]
    # the motor table names the same rotor
    assert dynamics.MOTOR_LAYOUT[dynamics.MOTOR_NAMES[rotor]] == ROTORS[rotor]
    # and the attitude follows: after 10 steps each angle has the sign of its rate
    s10 = run(state(z=5.0), raised(rotor), 10)
    assert tuple(int(np.sign(v)) for v in s10[0, 6:9]) == SIGNS[rotor]


@pytest.mark.parametrize(
    "pair, rates, why",
    [
        ((1, 2), (+1, 0, 0), "left pair up: left side up, +roll in FLU"),
        ((0, 3), (-1, 0, 0), "right pair up: −roll"),
        ((0, 2), (0, -1, 0), "front pair up: nose up, −pitch in FLU"),
        ((1, 3), (0, +1, 0), "rear pair up: nose down, +pitch in FLU"),
        ((0, 1), (0, 0, -1), "the two CCW rotors up: reaction torque −z, the body yaws clockwise"),
        ((2, 3), (0, 0, +1), "the two CW rotors up: the body yaws counter-clockwise"),
    ],
)
def test_each_rotor_pair_gives_a_pure_torque_about_one_axis(pair, rates, why):
    s = run(state(z=5.0), raised(*pair), 1)
    magnitude = (2 * A * DF / V.ixx, 2 * A * DF / V.iyy, 2 * V.k_m * DF / V.izz)
    expected = [H * sgn * m for sgn, m in zip(rates, magnitude, strict=True)]
    np.testing.assert_allclose(s[0, 9:12], expected, rtol=1e-9, atol=1e-12, err_msg=why)


def test_pure_yaw_torque_turns_the_yaw_angle_by_the_constant_torque_formula():
    """CCW pair up by ΔF each: τ_z = −2·k_m·ΔF. From rest, ψ(t) = ½·(τ_z/I_zz)·t², which the
    mid-step rate integration reproduces exactly for a constant torque about one axis."""
    s = run(state(z=5.0), raised(0, 1), 20)
    alpha = -2 * V.k_m * DF / V.izz
    t = 20 * H
    np.testing.assert_allclose(s[0, IDX["r"]], alpha * t, rtol=1e-9)
    np.testing.assert_allclose(s[0, IDX["yaw"]], 0.5 * alpha * t * t, rtol=1e-9)
    np.testing.assert_allclose(s[0, [IDX["roll"], IDX["pitch"], IDX["p"], IDX["q"]]], 0.0, atol=1e-12)


def test_gyroscopic_coupling_sign():
    """Torque-free, ω = (p, q, 0): ṙ = −(I_yy − I_xx)·p·q / I_zz (Euler's equations)."""
    p0, q0 = 2.0, 3.0
    s = run(state(z=5.0, p=p0, q=q0), U_HOVER, 1)
    np.testing.assert_allclose(s[0, IDX["r"]], -H * (V.iyy - V.ixx) * p0 * q0 / V.izz, rtol=1e-12)
    np.testing.assert_allclose(s[0, [IDX["p"], IDX["q"]]], [p0, q0], rtol=1e-12)


@pytest.mark.parametrize("phi0, theta0", [(0.4, 0.0), (0.3, 0.5), (-0.2, -0.6)])
def test_euler_angle_rates_of_a_body_yaw_rate_in_a_tilted_attitude(phi0, theta0):
    """ZYX kinematics, [φ̇, θ̇, ψ̇] = W(φ, θ)·[p, q, r]: spinning about the body z axis alone gives
    φ̇ = r·cos φ·tan θ, θ̇ = −r·sin φ, ψ̇ = r·cos φ / cos θ (at θ = 0: the body z axis is
    (0, −sin φ, cos φ), so the yaw turns by r·cos φ and the pitch by −r·sin φ). Torque-free with one
    non-zero rate, so r stays constant and one step moves the angles by h times these rates.
    Cross-check against the rotation itself: R(φ1, θ1, ψ1) ≈ R0·(I + h·[ω]×) to O(h²)."""
    psi0, r0 = 0.25, 1.0
    s = run(state(z=5.0, roll=phi0, pitch=theta0, yaw=psi0, r=r0), U_HOVER, 1)
    np.testing.assert_allclose(s[0, IDX["r"]], r0, rtol=1e-12)
    c, sn = math.cos(phi0), math.sin(phi0)
    np.testing.assert_allclose(s[0, IDX["roll"]], phi0 + H * r0 * c * math.tan(theta0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(s[0, IDX["pitch"]], theta0 - H * r0 * sn, rtol=0, atol=1e-12)
    np.testing.assert_allclose(s[0, IDX["yaw"]], psi0 + H * r0 * c / math.cos(theta0), rtol=0, atol=1e-12)
    w = np.array([[0.0, -r0, 0.0], [r0, 0.0, 0.0], [0.0, 0.0, 0.0]])  # [ω]× for ω = (0, 0, r)
    r_expected = rz(psi0) @ ry(theta0) @ rx(phi0) @ (np.eye(3) + H * w)
    r_got = rz(s[0, IDX["yaw"]]) @ ry(s[0, IDX["pitch"]]) @ rx(s[0, IDX["roll"]])
    np.testing.assert_allclose(r_got, r_expected, atol=2 * (H * r0) ** 2)


# --- thrust direction ---------------------------------------------------------------------------


def expected_accel(roll, pitch, yaw, thrust=V.mass * GRAVITY):
    """a = T/m · R·e_z − g·e_z with R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    r = rz(yaw) @ ry(pitch) @ rx(roll)
    return thrust / V.mass * r[:, 2] - np.array([0.0, 0.0, GRAVITY])


def test_tilted_hover_rolled_right_accelerates_towards_minus_y():
    """Roll +θ about x (FLU: the left side up, the right side down) tilts the thrust to the right of
    a drone facing east (+x), that is towards −y (south): a = (0, −g·sin θ, g·(cos θ − 1))."""
    theta = 0.2
    s = run(state(z=5.0, roll=theta), U_HOVER, 1)
    a = s[0, 3:6] / H  # one step from rest, attitude constant (no torque): v1 = h·a exactly
    np.testing.assert_allclose(a, [0.0, -GRAVITY * math.sin(theta), GRAVITY * (math.cos(theta) - 1)], atol=1e-9)
    np.testing.assert_allclose(a, expected_accel(theta, 0.0, 0.0), atol=1e-9)
    assert a[1] < -1.9  # −9.81·sin 0.2 = −1.949 m/s²
    np.testing.assert_allclose(s[0, 0:3], [0.0, 0.0, 5.0] + 0.5 * H * H * a, atol=1e-12)


@pytest.mark.parametrize(
    "roll, pitch, yaw, direction",
    [
        (0.0, 0.2, 0.0, (+1, 0)),  # +pitch in FLU is nose down: facing east, accelerate east
        (0.0, 0.2, math.pi / 2, (0, +1)),  # facing north, nose down: accelerate north
        (0.2, 0.0, math.pi / 2, (+1, 0)),  # facing north, rolled right: accelerate east
        (0.1, -0.25, 0.7, None),
        (-0.3, 0.15, -2.5, None),
    ],
)
def test_thrust_acceleration_is_r_times_e_z(roll, pitch, yaw, direction):
    s = run(state(z=5.0, roll=roll, pitch=pitch, yaw=yaw), U_HOVER, 1)
    a = s[0, 3:6] / H
    np.testing.assert_allclose(a, expected_accel(roll, pitch, yaw), atol=1e-9)
    if direction is not None:
        assert tuple(int(np.sign(round(v, 9))) for v in a[:2]) == direction


# --- batching -----------------------------------------------------------------------------------


@pytest.mark.parametrize("substeps", [1, 3])
def test_a_batched_step_equals_n_single_steps(substeps):
    n = 6
    rng = np.random.default_rng(11)
    params = one(n).with_entries(
        [1, 3, 4],
        mass=[0.7, 0.6, 0.8],
        ixx=[0.0021, 0.0026, 0.0023],
        k_m=[0.009, 0.007, 0.008],
        motor_tau=[0.02, 0.0, 0.05],
    )
    s0 = rng.normal(0.0, 0.3, (n, STATE_DIM))
    s0[:, 2] += 5.0
    w0 = rng.uniform(0.4, 0.9, (n, 4))
    cmd = rng.uniform(0.0, 1.0, (n, 4))
    sb, wb = step(s0, w0, cmd, params, H, substeps)
    for i in range(n):
        si, wi = step(s0[i : i + 1], w0[i : i + 1], cmd[i : i + 1], params.subset([i]), H, substeps)
        np.testing.assert_allclose(sb[i], si[0], rtol=0, atol=1e-12, err_msg=f"drone {i}")
        np.testing.assert_allclose(wb[i], wi[0], rtol=0, atol=1e-12, err_msg=f"drone {i}")


# --- action → command ---------------------------------------------------------------------------


def test_action_is_thrust_relative_to_hover():
    """u = u_hover·√(1 + a) with a clipped to [−1, 1], then u clipped to [0, 1]: a = −1 is zero
    thrust, 0 hover, +1 twice hover thrust (F ∝ u², so F/F_hover = 1 + a)."""
    a = np.array([[-1.0, -0.5, 0.0, 0.5], [1.0, -3.0, 3.0, 0.0]])
    u = dynamics.action_to_command(a, 0.5)
    np.testing.assert_allclose(
        u,
        [
            [0.0, 0.5 * math.sqrt(0.5), 0.5, 0.5 * math.sqrt(1.5)],
            [0.5 * math.sqrt(2.0), 0.0, 0.5 * math.sqrt(2.0), 0.5],
        ],
    )
    np.testing.assert_allclose((u / 0.5) ** 2, 1.0 + np.clip(a, -1.0, 1.0), rtol=0, atol=1e-12)
    # a per-drone hover command (N, 1); twice hover thrust of a heavy drone would need u > 1: held at 1
    u = dynamics.action_to_command(np.array([[1.0, 0.0, -1.0, 0.5], [1.0, 0.0, -1.0, 0.5]]), np.array([[0.8], [0.6]]))
    np.testing.assert_allclose(
        u, [[1.0, 0.8, 0.0, 0.8 * math.sqrt(1.5)], [0.6 * math.sqrt(2.0), 0.6, 0.0, 0.6 * math.sqrt(1.5)]]
    )


@pytest.mark.parametrize("kind", ["force", "torque"])
def test_external_force_and_torque_keep_a_float32_state_float32(kind):
    """An external push (world force / m, body torque) is cast to the state's dtype: a float32 batch
    stays float32, and equals the float64 step to float32 precision. From hover, 0.5 N along +x for
    10 ms gives Δvx = h·F/m; 0.01 N·m about x gives Δp = h·τ/I_xx."""
    params = one(1)
    s0 = state(z=1.0)
    cmd = np.full((1, 4), U_HOVER)
    ext = {kind: np.array([[0.5, 0.0, 0.0]] if kind == "force" else [[0.01, 0.0, 0.0]])}
    s64, _ = step(s0, cmd, cmd, params, H, **ext)
    s32, w32 = step(s0.astype(np.float32), cmd.astype(np.float32), cmd.astype(np.float32), params, H, **ext)
    assert s32.dtype == np.float32 and w32.dtype == np.float32
    np.testing.assert_allclose(s32, s64, rtol=1e-5, atol=1e-7)
    if kind == "force":
        assert float(s64[0, IDX["vx"]]) == pytest.approx(H * 0.5 / V.mass, rel=1e-12)
    else:
        assert float(s64[0, IDX["p"]]) == pytest.approx(H * 0.01 / V.ixx, rel=1e-12)


def test_commands_outside_zero_one_are_motors_off_and_full_speed():
    """Commands are clipped to [0, 1] before F = f_max·u²: −0.5 is motors off (free fall, not the
    thrust of +0.5), 1.5 is full speed."""
    s0 = state(z=10.0)
    params = one()
    off, _ = step(s0, np.zeros((1, 4)), np.full((1, 4), -0.5), params, H)
    assert float(off[0, IDX["vz"]]) == pytest.approx(-GRAVITY * H, rel=1e-12)
    full, _ = step(s0, np.ones((1, 4)), np.full((1, 4), 1.5), params, H)
    ref, _ = step(s0, np.ones((1, 4)), np.ones((1, 4)), params, H)
    np.testing.assert_array_equal(full, ref)
    f_max = V.k_f * V.omega_max**2
    assert float(full[0, IDX["vz"]]) == pytest.approx((4 * f_max / V.mass - GRAVITY) * H, rel=1e-12)


def test_one_param_batch_steps_with_each_step_length_and_dtype_it_is_given():
    """The per-drone constants derived from a ParamBatch depend on the step length (the motor lag's
    e^(−h/τ)) and on the state's dtype: one batch used with h, then 2h, then float32 gives what a
    fresh batch gives each time. Rotor from 0 towards command 1 with τ = 0.02 s: ω = 1 − e^(−h/τ)."""
    lagged = replace(V, motor_tau=0.02)
    shared = ParamBatch.from_preset(lagged, 1)
    s0, w0, cmd = state(z=1.0), np.zeros((1, 4)), np.ones((1, 4))
    for h in (H, 2 * H):
        _, w = step(s0, w0, cmd, shared, h)
        np.testing.assert_allclose(w, 1.0 - math.exp(-h / 0.02), rtol=1e-12)
        np.testing.assert_array_equal(w, step(s0, w0, cmd, ParamBatch.from_preset(lagged, 1), h)[1])
    s32, w32 = step(s0.astype(np.float32), w0.astype(np.float32), cmd.astype(np.float32), shared, H)
    assert s32.dtype == np.float32 and w32.dtype == np.float32
    np.testing.assert_allclose(w32, 1.0 - math.exp(-H / 0.02), rtol=1e-6)


def test_motor_lag_decay_is_exact_in_float64_and_safe_for_lag_free_drones():
    """ω ← ω_cmd + e^(−h/τ)·(ω − ω_cmd): from rest towards command 1 the rotor reaches 1 − e^(−h/τ)
    after one step, computed in float64 even from float32 parameters (τ = 0.02 as float32 is
    0.0199999995529651…). A lag-free drone in the same batch (τ = 0) follows its command exactly, and
    no division by τ = 0 happens on the way (np.errstate raises on one)."""
    batch = ParamBatch.from_preset(V, 2).with_entries([0], motor_tau=0.02)
    s0, w0, cmd = np.tile(state(z=1.0), (2, 1)), np.zeros((2, 4)), np.ones((2, 4))
    with np.errstate(all="raise"):
        _, w = step(s0, w0, cmd, batch, H)
    np.testing.assert_allclose(w[0], 1.0 - math.exp(-H / 0.02), rtol=1e-14)
    np.testing.assert_array_equal(w[1], 1.0)
    tau32 = float(np.float32(0.02))
    _, w = step(s0[:1], w0[:1], cmd[:1], ParamBatch.from_preset(replace(V, motor_tau=0.02), 1).astype(np.float32), H)
    np.testing.assert_allclose(w, 1.0 - math.exp(-H / tau32), rtol=1e-14)


def test_yaw_wraps_from_plus_pi_to_minus_pi():
    """Yaw is kept in [−π, π): from π − 0.001 at r = 1 rad/s, one 10 ms step reaches π + 0.009,
    which is −π + 0.009."""
    params = one()
    s0 = state(z=1.0, yaw=math.pi - 0.001, r=1.0)
    u = np.full((1, 4), U_HOVER)
    s, _ = step(s0, u, u, params, H)
    assert float(s[0, IDX["yaw"]]) == pytest.approx(-math.pi + 0.009, abs=1e-12)
    s, _ = step(state(z=1.0, yaw=-math.pi + 0.001, r=-1.0), u, u, params, H)
    assert float(s[0, IDX["yaw"]]) == pytest.approx(math.pi - 0.009, abs=1e-12)
