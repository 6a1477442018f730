"""The quadrotor model against the physics it claims: hover trim, free fall, torque signs of the
PX4 quad-X motor pairs, analytic rotations, batch equivalence, convergence, motor lag and drag.

Frames: world ENU (z up), body FLU (x forward, y left, z up). Motors in PX4 quad-X order:
0 front-right CCW, 1 rear-left CCW, 2 front-left CW, 3 rear-right CW.
"""

import dataclasses
import math

import numpy as np
import pytest

from quadpilot.core import dynamics
from quadpilot.core.dynamics import IDX, hover_command, step
from quadpilot.core.frames import euler_to_rotmat
from quadpilot.core.params import ParamBatch
from quadpilot.core.vehicle_file import CRAZYFLIE, SEED_VEHICLE

PRESETS = [SEED_VEHICLE, CRAZYFLIE]
PRESET_IDS = [p.name for p in PRESETS]
DT = 0.01

# Rotor geometry written out from the airframe, independently of the model's torque rows:
# position (x, y) in FLU as multiples of arm/√2, and the direction of the rotor's spin seen from
# above (+1 = counter-clockwise). A CCW rotor is driven by a +z motor torque, so the body feels −z.
GEOMETRY = {
    0: ((+1.0, -1.0), +1),  # front-right, CCW
    1: ((-1.0, +1.0), +1),  # rear-left, CCW
    2: ((+1.0, +1.0), -1),  # front-left, CW
    3: ((-1.0, -1.0), -1),  # rear-right, CW
}


def at_rest(n=1, z=10.0, dtype=np.float64):
    s = np.zeros((n, 12), dtype=dtype)
    s[:, IDX["z"]] = z
    return s


def fly(state, command, params, steps, dt=DT, substeps=1, rotor=None):
    """Hold `command` for `steps` control steps; returns the trajectory (steps + 1, N, 12)."""
    rotor = np.array(command, copy=True) if rotor is None else rotor
    traj = [state]
    for _ in range(steps):
        state, rotor = step(state, rotor, command, params, dt, substeps)
        traj.append(state)
    return np.stack(traj)


def command_for_thrusts(preset, thrusts):
    """Rotor commands ω/ω_max giving the per-rotor thrusts (N): F = k_f·(u·ω_max)²."""
    return np.sqrt(np.asarray(thrusts, dtype=np.float64) / preset.k_f) / preset.omega_max


def expected_torque(preset, thrusts):
    """Body torque (N·m, FLU) from r_i × F_i ẑ plus the rotor reaction torques."""
    a = preset.arm / math.sqrt(2.0)
    tau = np.zeros(3)
    for i, f in enumerate(thrusts):
        (x, y), spin = GEOMETRY[i]
        tau += np.cross([a * x, a * y, 0.0], [0.0, 0.0, f])
        tau[2] += -spin * preset.k_m * f
    return tau


# --- 1. hover trim ------------------------------------------------------------------------


@pytest.mark.parametrize("preset", PRESETS, ids=PRESET_IDS)
def test_hover_trim_holds_for_ten_seconds(preset):
    params = ParamBatch.from_preset(preset, 1)
    s0 = at_rest(z=10.0)
    s0[0, IDX["yaw"]] = 0.7  # any heading: hover must not care
    cmd = np.full((1, 4), hover_command(preset))
    traj = fly(s0, cmd, params, steps=1000)
    drift = traj[:, 0, :] - s0[0]
    assert np.max(np.abs(drift[:, IDX["z"]])) < 1e-6
    assert np.max(np.abs(drift[:, [IDX["x"], IDX["y"]]])) < 1e-9
    assert np.max(np.abs(drift[:, 3:6])) < 1e-9  # no velocity builds up
    assert np.max(np.abs(drift[:, 6:12])) < 1e-12  # attitude and rates untouched


def test_hover_command_matches_weight():
    for preset in PRESETS:
        u = hover_command(preset)
        assert 4 * preset.k_f * (u * preset.omega_max) ** 2 == pytest.approx(preset.mass * preset.gravity, rel=1e-12)
        assert u == pytest.approx(preset.hover_command, rel=1e-12)


# --- 2. free fall -------------------------------------------------------------------------


@pytest.mark.parametrize("preset", PRESETS, ids=PRESET_IDS)
def test_zero_thrust_falls_with_g(preset):
    params = ParamBatch.from_preset(preset, 1)
    z0, g = 100.0, preset.gravity
    s0 = at_rest(z=z0)
    s0[0, IDX["roll"]] = 0.3  # attitude is irrelevant with no thrust
    traj = fly(s0, np.zeros((1, 4)), params, steps=300)
    t = DT * np.arange(301)
    # The position update p + h·v + h²/2·a is exact for constant acceleration: only rounding left.
    np.testing.assert_allclose(traj[:, 0, IDX["z"]], z0 - 0.5 * g * t**2, rtol=0, atol=1e-9)
    np.testing.assert_allclose(traj[:, 0, IDX["vz"]], -g * t, rtol=0, atol=1e-9)
    assert np.all(traj[:, 0, [IDX["x"], IDX["y"], IDX["vx"], IDX["vy"]]] == 0.0)


# --- 3. motor pairs -----------------------------------------------------------------------

# (rotors raised, body rate they must make positive, why)
PAIRS = [
    ((1, 2), "p", "left rotors up lift the left side: positive roll rate"),
    ((1, 3), "q", "rear rotors up pitch the nose down: positive pitch rate in FLU"),
    ((2, 3), "r", "CW rotors up: their +z reaction turns the body CCW seen from above"),
]
RATE_INDEX = {"p": 0, "q": 1, "r": 2}
INERTIA = {"p": "ixx", "q": "iyy", "r": "izz"}


@pytest.mark.parametrize("preset", PRESETS, ids=PRESET_IDS)
@pytest.mark.parametrize(("pair", "rate", "why"), PAIRS, ids=["roll", "pitch", "yaw"])
def test_raising_a_motor_pair_gives_the_expected_rate_sign(preset, pair, rate, why):
    params = ParamBatch.from_preset(preset, 1)
    f_hover = preset.hover_thrust
    thrusts = np.full(4, f_hover)
    thrusts[list(pair)] *= 1.1
    cmd = command_for_thrusts(preset, thrusts)[None, :]
    s1, _ = step(at_rest(), cmd, cmd, params, DT)
    rates = s1[0, 9:12]
    k = RATE_INDEX[rate]
    assert rates[k] > 0, why
    # From rest there is no gyroscopic term: ω after one step is h·τ/I.
    tau = expected_torque(preset, thrusts)
    inertia = np.array([preset.ixx, preset.iyy, preset.izz])
    np.testing.assert_allclose(rates[k], DT * tau[k] / inertia[k], rtol=1e-9)
    others = [i for i in range(3) if i != k]
    assert np.all(np.abs(rates[others]) <= 1e-9 * rates[k]), f"{rate} pair leaked into other axes: {rates}"
    # more total thrust than weight: the vehicle climbs
    assert s1[0, IDX["vz"]] > 0


@pytest.mark.parametrize("preset", PRESETS, ids=PRESET_IDS)
@pytest.mark.parametrize(("pair", "rate", "why"), PAIRS, ids=["roll", "pitch", "yaw"])
def test_differential_pair_at_fixed_total_thrust(preset, pair, rate, why):
    """Pair up by ΔF, the other pair down by ΔF: same total thrust, so no vertical acceleration,
    and twice the torque of raising the pair alone."""
    params = ParamBatch.from_preset(preset, 1)
    f_hover, df = preset.hover_thrust, 0.05 * preset.hover_thrust
    thrusts = np.full(4, f_hover - df)
    thrusts[list(pair)] = f_hover + df
    assert thrusts.sum() == pytest.approx(4 * f_hover, rel=1e-15)
    cmd = command_for_thrusts(preset, thrusts)[None, :]
    s1, _ = step(at_rest(), cmd, cmd, params, DT)
    k = RATE_INDEX[rate]
    rates = s1[0, 9:12]
    assert rates[k] > 0, why
    inertia = getattr(preset, INERTIA[rate])
    np.testing.assert_allclose(rates[k], DT * expected_torque(preset, thrusts)[k] / inertia, rtol=1e-9)
    np.testing.assert_allclose(rates[k], DT * 4 * df * _lever(preset, rate) / inertia, rtol=1e-9)
    others = [i for i in range(3) if i != k]
    assert np.all(np.abs(rates[others]) <= 1e-9 * rates[k])
    assert abs(s1[0, IDX["vz"]]) < 1e-12  # total thrust unchanged: still weight
    assert abs(s1[0, IDX["z"]] - 10.0) < 1e-12


def _lever(preset, rate):
    """Torque per newton of differential thrust: arm/√2 for roll and pitch, k_m for yaw."""
    return preset.k_m if rate == "r" else preset.arm / math.sqrt(2.0)


@pytest.mark.parametrize("preset", PRESETS, ids=PRESET_IDS)
def test_rear_pair_up_pitches_nose_down_and_accelerates_forward(preset):
    params = ParamBatch.from_preset(preset, 1)
    f_hover, df = preset.hover_thrust, 0.02 * preset.hover_thrust
    thrusts = np.array([f_hover - df, f_hover + df, f_hover - df, f_hover + df])  # rear (1, 3) up
    cmd = command_for_thrusts(preset, thrusts)[None, :]
    traj = fly(at_rest(), cmd, params, steps=20)
    end = traj[-1, 0]
    assert end[IDX["pitch"]] > 0.01  # nose down in FLU
    assert end[IDX["vx"]] > 0 and end[IDX["x"]] > 0  # thrust tilted forward
    assert abs(end[IDX["roll"]]) < 1e-9 and abs(end[IDX["yaw"]]) < 1e-9
    assert abs(end[IDX["vy"]]) < 1e-9


# --- 4. analytic rotations ----------------------------------------------------------------


@pytest.mark.parametrize("preset", PRESETS, ids=PRESET_IDS)
def test_torque_free_roll_is_uniform_rotation(preset):
    params = ParamBatch.from_preset(preset, 1)
    p0 = 1.2  # rad/s
    s0 = at_rest()
    s0[0, IDX["p"]] = p0
    cmd = np.full((1, 4), hover_command(preset))  # equal rotors: no torque
    traj = fly(s0, cmd, params, steps=100)[:, 0]
    t = DT * np.arange(101)
    roll, pitch, yaw = traj[:, IDX["roll"]], traj[:, IDX["pitch"]], traj[:, IDX["yaw"]]
    np.testing.assert_allclose(roll, p0 * t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(pitch, 0.0, atol=1e-14)
    np.testing.assert_allclose(yaw, 0.0, atol=1e-14)
    np.testing.assert_allclose(traj[:, IDX["p"]], p0, rtol=1e-14)
    body_z = euler_to_rotmat(roll, pitch, yaw)[:, :, 2]
    expected = np.stack([np.zeros_like(t), -np.sin(p0 * t), np.cos(p0 * t)], axis=1)
    np.testing.assert_allclose(body_z, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("preset", PRESETS, ids=PRESET_IDS)
def test_constant_roll_torque_from_rest(preset):
    """τx from (1, 2) up and (0, 3) down, τy = τz = 0: φ(t) = ½·(τx/Ixx)·t². The model advances the
    angles with the mid-step rate, which is exact for constant angular acceleration, so the only
    error left is rounding; 1e-12 rad over 100 steps."""
    params = ParamBatch.from_preset(preset, 1)
    f_hover = preset.hover_thrust
    alpha = 1.0  # rad/s², chosen; ΔF follows
    df = alpha * preset.ixx / (4 * preset.arm / math.sqrt(2.0))
    thrusts = np.array([f_hover - df, f_hover + df, f_hover + df, f_hover - df])
    tau = expected_torque(preset, thrusts)
    assert tau[0] == pytest.approx(alpha * preset.ixx, rel=1e-12)
    assert abs(tau[1]) < 1e-15 and abs(tau[2]) < 1e-15
    cmd = command_for_thrusts(preset, thrusts)[None, :]
    traj = fly(at_rest(), cmd, params, steps=100)[:, 0]
    t = DT * np.arange(101)
    np.testing.assert_allclose(traj[:, IDX["roll"]], 0.5 * tau[0] / preset.ixx * t**2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(traj[:, IDX["p"]], tau[0] / preset.ixx * t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(traj[:, IDX["pitch"]], 0.0, atol=1e-12)
    np.testing.assert_allclose(traj[:, IDX["yaw"]], 0.0, atol=1e-12)


def test_torque_free_tumble_conserves_angular_momentum_and_energy():
    """With no torque, the world-frame angular momentum R·I·ω and the energy ½ωᵀIω are constant
    (Euler's equations with the gyroscopic term ω × Iω). The integrator is first order in them.
    Measured over 0.5 s from ω = (2, 0.5, 3) rad/s on the seed vehicle: relative drift of |L|
    1.07e-2 at h = 10 ms, 1.07e-3 at h = 1 ms; of the energy 3.3e-3 and 3.2e-4. With the
    gyroscopic term's sign flipped the drift stays at 2.6e-2 and 5.3e-2 however small h is."""
    preset = SEED_VEHICLE
    params = ParamBatch.from_preset(preset, 1)
    inertia = np.diag([preset.ixx, preset.iyy, preset.izz])
    s0 = at_rest()
    s0[0, 9:12] = [2.0, 0.5, 3.0]
    cmd = np.full((1, 4), hover_command(preset))  # equal rotors: no torque

    def drift(substeps):
        traj = fly(s0, cmd, params, steps=50, substeps=substeps)[:, 0]
        rot = euler_to_rotmat(traj[:, IDX["roll"]], traj[:, IDX["pitch"]], traj[:, IDX["yaw"]])
        w = traj[:, 9:12]
        momentum = np.einsum("tij,jk,tk->ti", rot, inertia, w)
        energy = 0.5 * np.einsum("ti,ij,tj->t", w, inertia, w)
        return (
            np.max(np.linalg.norm(momentum - momentum[0], axis=1)) / np.linalg.norm(momentum[0]),
            np.max(np.abs(energy / energy[0] - 1)),
        )

    dl_coarse, de_coarse = drift(1)
    dl_fine, de_fine = drift(10)
    assert dl_fine < 3e-3 and de_fine < 1e-3
    assert 5 < dl_coarse / dl_fine < 20 and 5 < de_coarse / de_fine < 20  # first order in h


# --- 5. batch equivalence -----------------------------------------------------------------


def random_fleet(n, dtype, seed=0):
    """N different drones: randomised parameters, motor lag on about half, drag on about two thirds,
    random states, rotor speeds and commands (some outside [0, 1] to exercise the clip)."""
    rng = np.random.default_rng(seed)
    base = ParamBatch.from_preset(SEED_VEHICLE, n)

    def jitter(a):
        return a * rng.uniform(0.8, 1.2, n)

    params = dataclasses.replace(
        base,
        mass=jitter(base.mass),
        ixx=jitter(base.ixx),
        iyy=jitter(base.iyy),
        izz=jitter(base.izz),
        k_f=jitter(base.k_f),
        k_m=jitter(base.k_m),
        arm=jitter(base.arm),
        omega_max=jitter(base.omega_max),
        motor_tau=np.where(rng.random(n) < 0.5, 0.0, rng.uniform(0.005, 0.05, n)),
        drag=np.where(rng.random(n) < 0.33, 0.0, rng.uniform(0.01, 0.5, n)),
    ).astype(dtype)
    state = np.concatenate(
        [
            rng.uniform(-5, 5, (n, 3)),
            rng.uniform(-2, 2, (n, 3)),
            rng.uniform(-0.6, 0.6, (n, 2)),
            rng.uniform(-np.pi, np.pi, (n, 1)),
            rng.uniform(-3, 3, (n, 3)),
        ],
        axis=1,
    ).astype(dtype)
    # non-dyadic values so that rounding in the rotor update would show
    rotor = (0.05 + 0.9 * rng.random((n, 4)) / 3.0).astype(dtype)
    command = rng.uniform(-0.1, 1.1, (n, 4)).astype(dtype)
    return params, state, rotor, command


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("substeps", [1, 3])
def test_batched_step_equals_single_steps_bit_for_bit(dtype, substeps):
    n = 64
    params, state, rotor, command = random_fleet(n, dtype)
    assert np.any(params.motor_tau > 0) and np.any(params.motor_tau == 0)
    assert np.any(params.drag > 0) and np.any(params.drag == 0)
    s_b, w_b = state, rotor
    for _ in range(5):
        s_b, w_b = step(s_b, w_b, command, params, DT, substeps)
    assert s_b.dtype == dtype and w_b.dtype == dtype
    for i in range(n):
        p_i = params.subset([i])
        s_i, w_i = state[i : i + 1], rotor[i : i + 1]
        for _ in range(5):
            s_i, w_i = step(s_i, w_i, command[i : i + 1], p_i, DT, substeps)
        assert np.array_equal(s_i[0], s_b[i]), f"drone {i}: state differs alone vs in the batch"
        assert np.array_equal(w_i[0], w_b[i]), f"drone {i}: rotor differs alone vs in the batch"


def test_step_does_not_modify_inputs_and_checks_shapes():
    params, state, rotor, command = random_fleet(4, np.float64)
    copies = [a.copy() for a in (state, rotor, command)]
    step(state, rotor, command, params)
    for a, c in zip((state, rotor, command), copies, strict=True):
        assert np.array_equal(a, c)
    with pytest.raises(ValueError, match="state must have shape"):
        step(state[:3], rotor, command, params)
    with pytest.raises(ValueError, match="rotor and command"):
        step(state, rotor[:, :3], command, params)
    with pytest.raises(ValueError, match="rotor and command"):
        step(state, rotor, command[:, :3], params)
    with pytest.raises(ValueError, match="state must be float32 or float64, got int64"):
        step(state.astype(np.int64), rotor, command, params)
    with pytest.raises(ValueError, match=r"armed must have shape \(4,\), got \(3,\)"):
        step(state, rotor, command, params, armed=np.ones(3, bool))
    for name in ("force", "torque"):
        with pytest.raises(ValueError, match=rf"{name} must have shape \(4, 3\)"):
            step(state, rotor, command, params, **{name: np.zeros((4, 2))})


def test_step_returns_new_c_ordered_arrays_of_the_state_dtype():
    """What callers index and hash: (N, 12) and (N, M) in the state's dtype, C-ordered, whatever the
    dtype the rotor speeds and commands come in."""
    for dtype in (np.float32, np.float64):
        params, state, rotor, command = random_fleet(5, dtype)
        other = np.float64 if dtype == np.float32 else np.float32
        s, w = step(state, rotor.astype(other), command.astype(other), params)
        assert s.dtype == w.dtype == dtype and s.flags.c_contiguous and w.flags.c_contiguous
        assert s.shape == state.shape and w.shape == rotor.shape


def test_one_parameter_batch_steps_both_dtypes_each_with_its_own_constants():
    """The derived constants are cached on the ParamBatch per step length and dtype: a float32 step
    after a float64 one on the same batch gives what a fresh batch gives."""
    params, state, rotor, command = random_fleet(6, np.float64)
    step(state, rotor, command, params)
    f32 = [a.astype(np.float32) for a in (state, rotor, command)]
    got = step(*f32, params)
    want = step(*f32, dataclasses.replace(params))  # a new batch: no cache
    assert all(a.tobytes() == b.tobytes() for a, b in zip(got, want, strict=True))


def test_stepper_refuses_rows_and_params_of_another_shape():
    params, state, rotor, command = random_fleet(4, np.float64)
    stepper = dynamics.Stepper(4, 4, np.float64)
    s, w, u = (np.ascontiguousarray(a.T) for a in (state, rotor, command))
    for bad in ((s[:, :3], w, u), (s, w[:3], u), (s, w, u[:3])):
        with pytest.raises(ValueError, match="rows must have shapes"):
            stepper.step(*bad, params)
    with pytest.raises(ValueError, match="params hold 3 drones of 4 rotors, expected 4 of 4"):
        stepper.step(s, w, u, random_fleet(3, np.float64)[0])


# --- 6. convergence in the step length ----------------------------------------------------


def test_halving_the_step_barely_changes_a_hover_to_tilt_trajectory():
    """1 s from hover with a small roll command (left pair +0.25 % thrust, right pair −0.25 %):
    the vehicle rolls to 0.26 rad (15°) and slides 0.21 m to the right. Measured difference
    between substeps=1 (h = 10 ms) and substeps=2 (h = 5 ms) at t = 1 s: 2.1e-3 m in position,
    6.4e-3 m/s in velocity (first order: each step's acceleration uses the attitude at its start),
    3e-16 rad in attitude and 4e-16 rad/s in rates (constant torque: the rotation update is exact).
    Tolerances: about 5× the translational figures, rounding level for the rotation."""
    preset = SEED_VEHICLE
    params = ParamBatch.from_preset(preset, 1)
    f = preset.hover_thrust
    cmd = command_for_thrusts(preset, [0.9975 * f, 1.0025 * f, 1.0025 * f, 0.9975 * f])[None, :]
    coarse = fly(at_rest(), cmd, params, steps=100, substeps=1)[-1, 0]
    fine = fly(at_rest(), cmd, params, steps=100, substeps=2)[-1, 0]
    assert coarse[IDX["roll"]] > 0.2  # a real manoeuvre, not a hover
    assert coarse[IDX["y"]] < -0.1  # positive roll tilts the thrust to −y (right)
    diff = np.abs(coarse - fine)
    assert np.max(diff[0:3]) < 1e-2, diff[0:3]
    assert np.max(diff[3:6]) < 3e-2, diff[3:6]
    assert np.max(diff[6:12]) < 1e-12, diff[6:12]
    # and the error is first order: halving again roughly halves it
    finer = fly(at_rest(), cmd, params, steps=100, substeps=4)[-1, 0]
    ratio = np.max(np.abs(coarse - finer)[0:6]) / np.max(np.abs(fine - finer)[0:6])
    assert 1.5 < ratio < 4.5, ratio


# --- 7. motor lag and drag ----------------------------------------------------------------


def test_motor_lag_reaches_63_percent_after_one_time_constant():
    tau = 0.05  # s, five control steps
    preset = dataclasses.replace(SEED_VEHICLE, motor_tau=tau)
    params = ParamBatch.from_preset(preset, 1)
    u0, u1 = hover_command(preset), 0.9
    rotor = np.full((1, 4), u0)
    cmd = np.full((1, 4), u1)
    state = at_rest()
    history = [rotor[0, 0]]
    for _ in range(10):
        state, rotor = step(state, rotor, cmd, params, DT)
        history.append(rotor[0, 0])
    history = np.array(history)
    frac = (history - u0) / (u1 - u0)
    assert frac[5] == pytest.approx(1 - math.exp(-1), abs=1e-12)  # t = τ
    assert frac[10] == pytest.approx(1 - math.exp(-2), abs=1e-12)  # t = 2τ
    assert np.all(np.diff(frac) > 0)  # monotone approach, no overshoot
    assert state[0, IDX["vz"]] > 0  # more thrust than hover, even if late


def test_motor_lag_slows_the_thrust_response():
    lagged = ParamBatch.from_preset(dataclasses.replace(SEED_VEHICLE, motor_tau=0.05), 1)
    instant = ParamBatch.from_preset(SEED_VEHICLE, 1)
    rotor = np.full((1, 4), hover_command(SEED_VEHICLE))
    cmd = np.full((1, 4), 0.9)
    s_lag, _ = step(at_rest(), rotor, cmd, lagged, DT)
    s_now, _ = step(at_rest(), rotor, cmd, instant, DT)
    assert 0 < s_lag[0, IDX["vz"]] < s_now[0, IDX["vz"]]


def test_without_lag_the_rotor_follows_the_command_at_once():
    params = ParamBatch.from_preset(SEED_VEHICLE, 1)
    rotor = np.full((1, 4), 0.2)
    cmd = np.array([[0.9, 0.1, 0.55, 1.3]])  # the last one is clipped to full speed
    _, rotor1 = step(at_rest(), rotor, cmd, params, DT)
    np.testing.assert_array_equal(rotor1, np.clip(cmd, 0, 1))


def test_linear_drag_gives_terminal_velocity():
    """Free fall against drag c: m·v̇ = −m·g − c·v, so v → −m·g/c with time constant m/c."""
    drag = 0.665  # N·s/m, makes m/c = 1 s for the seed vehicle
    preset = dataclasses.replace(SEED_VEHICLE, drag=drag)
    params = ParamBatch.from_preset(preset, 1)
    traj = fly(at_rest(z=500.0), np.zeros((1, 4)), params, steps=2000)[:, 0]
    vz = traj[:, IDX["vz"]]
    v_terminal = -preset.mass * preset.gravity / drag
    assert np.all(np.diff(vz) < 0) and np.all(vz > v_terminal)  # monotone, never beyond terminal
    assert vz[-1] == pytest.approx(v_terminal, rel=1e-6)  # 20 time constants
    t = 1.0  # s; the explicit velocity update lags the exponential by O(h)
    assert vz[100] == pytest.approx(v_terminal * (1 - math.exp(-t)), rel=1e-2)
    # without drag, the same 1 s of falling is faster
    no_drag = fly(at_rest(z=500.0), np.zeros((1, 4)), ParamBatch.from_preset(SEED_VEHICLE, 1), steps=100)
    assert no_drag[-1, 0, IDX["vz"]] < vz[100]


def test_module_constants_describe_the_state():
    assert dynamics.STATE_NAMES[dynamics.POS] == ("x", "y", "z")
    assert dynamics.STATE_NAMES[dynamics.RATES] == ("p", "q", "r")
    assert dynamics.MOTOR_NAMES == ("front_right", "rear_left", "front_left", "rear_right")
