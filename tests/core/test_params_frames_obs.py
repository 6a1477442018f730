"""Airframe presets, rotations between FLU body and ENU world, and the observation layout."""

import dataclasses
import itertools
import math

import numpy as np
import pytest

from quadpilot.core.dynamics import IDX
from quadpilot.core.frames import euler_to_quaternion, euler_to_rotmat, quaternion_to_euler, rotmat_to_euler
from quadpilot.core.observation import HOVER_LAYOUT, LAYOUTS, TRACK_LAYOUT, build_observation, get_layout
from quadpilot.core.params import ParamBatch
from quadpilot.core.vehicle_file import CRAZYFLIE, PRESETS, SEED_VEHICLE, get_preset

# --- 8. presets ---------------------------------------------------------------------------


@pytest.mark.parametrize("preset", [SEED_VEHICLE, CRAZYFLIE], ids=["seed", "crazyflie"])
def test_presets_are_flyable(preset):
    # hover well inside the rotor's range leaves control authority both ways
    assert 0.4 < preset.hover_command < 0.9
    assert 2.0 <= preset.thrust_to_weight <= 2.5
    # thrust-to-weight is (ω_max/ω_hover)², the same number seen from the rotor side
    assert preset.thrust_to_weight == pytest.approx(1.0 / preset.hover_command**2, rel=1e-12)
    assert 4 * preset.hover_thrust == pytest.approx(preset.mass * preset.gravity, rel=1e-12)


def test_seed_vehicle_matches_the_seed_table():
    assert (SEED_VEHICLE.mass, SEED_VEHICLE.arm) == (0.665, 0.105)
    assert (SEED_VEHICLE.ixx, SEED_VEHICLE.iyy, SEED_VEHICLE.izz) == (0.0023, 0.0025, 0.0037)
    assert CRAZYFLIE.mass == pytest.approx(0.027)


def test_get_preset():
    assert get_preset("seed") is SEED_VEHICLE
    assert get_preset("crazyflie") is CRAZYFLIE
    assert set(PRESETS) == {"seed", "crazyflie", "px4_sih_quadx"}
    with pytest.raises(ValueError, match="nope") as err:
        get_preset("nope")
    for name in PRESETS:
        assert name in str(err.value)


def test_scaled_multiplies_named_fields_only():
    heavy = SEED_VEHICLE.scaled(mass=1.1, k_f=0.95)
    assert heavy.mass == pytest.approx(0.665 * 1.1)
    assert heavy.k_f == pytest.approx(8.9e-7 * 0.95)
    assert heavy.ixx == SEED_VEHICLE.ixx and heavy.arm == SEED_VEHICLE.arm and heavy.name == "seed"
    assert SEED_VEHICLE.mass == 0.665  # the preset itself is untouched
    # a heavier vehicle with weaker rotors needs more command to hover
    assert heavy.hover_command > SEED_VEHICLE.hover_command


@pytest.mark.parametrize("bad", ["wingspan", "name"])
def test_scaled_rejects_unknown_fields(bad):
    with pytest.raises(ValueError, match=bad) as err:
        SEED_VEHICLE.scaled(**{bad: 2.0})
    assert "mass" in str(err.value)  # names what can be scaled


def test_param_batch_from_preset_and_subset():
    batch = ParamBatch.from_preset(CRAZYFLIE, 5, dtype=np.float32)
    assert batch.n == 5 and batch.mass.dtype == np.float32
    assert np.all(batch.mass == np.float32(CRAZYFLIE.mass))
    varied = dataclasses.replace(batch, mass=np.arange(1, 6, dtype=np.float32))
    sub = varied.subset([1, 3])
    assert sub.n == 2 and list(sub.mass) == [2.0, 4.0]
    assert varied.subset(np.array([True, False, False, False, True])).mass.tolist() == [1.0, 5.0]
    assert varied.astype(np.float64).mass.dtype == np.float64
    with pytest.raises(ValueError, match="at least one"):
        ParamBatch.from_preset(SEED_VEHICLE, 0)


# --- 9. frames ----------------------------------------------------------------------------


def random_angles(n=500, seed=0):
    rng = np.random.default_rng(seed)
    roll = rng.uniform(-np.pi, np.pi, n)
    pitch = rng.uniform(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3, n)
    yaw = rng.uniform(-np.pi, np.pi, n)
    return roll, pitch, yaw


def test_rotmat_is_a_proper_rotation():
    rot = euler_to_rotmat(*random_angles())
    assert rot.shape == (500, 3, 3)
    np.testing.assert_allclose(rot @ np.swapaxes(rot, 1, 2), np.broadcast_to(np.eye(3), rot.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-12)


def test_rotmat_elementary_rotations():
    """Body → world, ZYX. Yaw 90°: the nose (body x) points north (+y ENU). Pitch +90° in FLU:
    the nose points down. Roll +90°: the left side (body y) points up."""
    np.testing.assert_allclose(euler_to_rotmat(0.0, 0.0, np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(euler_to_rotmat(0.0, np.pi / 2, 0.0) @ [1, 0, 0], [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(euler_to_rotmat(np.pi / 2, 0.0, 0.0) @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    # order: yaw applied last (outermost), so a yawed then pitched nose dips along the yawed heading
    nose = euler_to_rotmat(0.0, 0.3, np.pi / 2) @ [1, 0, 0]
    np.testing.assert_allclose(nose, [0, math.cos(0.3), -math.sin(0.3)], atol=1e-15)


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def test_rotmat_to_euler_inverts_euler_to_rotmat():
    roll, pitch, yaw = random_angles()
    r2, p2, y2 = rotmat_to_euler(euler_to_rotmat(roll, pitch, yaw))
    np.testing.assert_allclose(wrap(r2 - roll), 0, atol=1e-9)
    np.testing.assert_allclose(p2, pitch, atol=1e-9)
    np.testing.assert_allclose(wrap(y2 - yaw), 0, atol=1e-9)


def test_euler_quaternion_round_trip():
    roll, pitch, yaw = random_angles(seed=1)
    q = euler_to_quaternion(roll, pitch, yaw)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
    r2, p2, y2 = quaternion_to_euler(q)
    np.testing.assert_allclose(wrap(r2 - roll), 0, atol=1e-9)
    np.testing.assert_allclose(p2, pitch, atol=1e-9)
    np.testing.assert_allclose(wrap(y2 - yaw), 0, atol=1e-9)


def quat_to_rotmat(q):
    """The textbook rotation matrix of a unit quaternion (w, x, y, z), written independently."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def test_quaternion_and_rotmat_describe_the_same_rotation():
    angles = random_angles(seed=2)
    np.testing.assert_allclose(quat_to_rotmat(euler_to_quaternion(*angles)), euler_to_rotmat(*angles), atol=1e-12)


# --- 10. observation ----------------------------------------------------------------------


def random_states(n, seed=0):
    rng = np.random.default_rng(seed)
    s = rng.uniform(-3, 3, (n, 12))
    s[:, 6:8] = rng.uniform(-1.0, 1.0, (n, 2))
    s[:, 8] = rng.uniform(-np.pi, np.pi, n)
    return s


def test_layouts_are_contiguous_named_tables():
    assert HOVER_LAYOUT.dim == 18 and TRACK_LAYOUT.dim == 21
    assert [f.name for f in TRACK_LAYOUT.fields][: len(HOVER_LAYOUT.fields)] == [f.name for f in HOVER_LAYOUT.fields]
    for layout in LAYOUTS.values():
        sl = list(layout.slices().values())
        assert sl[0].start == 0 and sl[-1].stop == layout.dim
        assert all(a.stop == b.start for a, b in itertools.pairwise(sl))
        assert get_layout(layout.name) is layout
        assert layout.to_json()["name"] == layout.name


def test_hover_observation_layout():
    state = random_states(7)
    target = np.array([0.5, -1.0, 2.0])
    obs = build_observation(state, target)
    assert obs.shape == (7, 18) and obs.dtype == np.float32
    sl = HOVER_LAYOUT.slices()
    rot = euler_to_rotmat(state[:, IDX["roll"]], state[:, IDX["pitch"]], state[:, IDX["yaw"]])
    # position error and velocity in the body frame: Rᵀ·v, so R·obs gives back the world vector
    body_err = np.einsum("nji,nj->ni", rot, state[:, 0:3] - target)
    np.testing.assert_allclose(obs[:, sl["pos_error"]], body_err, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", rot, obs[:, sl["vel"]]), state[:, 3:6], rtol=1e-5, atol=1e-5)
    # lengths survive the rotation
    np.testing.assert_allclose(
        np.linalg.norm(obs[:, sl["pos_error"]], axis=1), np.linalg.norm(state[:, 0:3] - target, axis=1), rtol=1e-5
    )
    np.testing.assert_allclose(obs[:, sl["rot"]].reshape(7, 3, 3), rot, atol=1e-6)  # row-major
    np.testing.assert_allclose(obs[:, sl["rates"]], state[:, 9:12], rtol=1e-6)
    # row-major: element 2 is R13 (x component of body z), element 6 is R31 = −sin(pitch)
    np.testing.assert_allclose(obs[:, sl["rot"]][:, 6], -np.sin(state[:, IDX["pitch"]]), atol=1e-6)


def test_track_observation_layout_and_out_buffer():
    state = random_states(4, seed=3)
    target = np.random.default_rng(1).normal(size=(4, 3))
    tvel = np.random.default_rng(2).normal(size=(4, 3))
    out = np.zeros((4, 21), np.float64)
    obs = build_observation(state, target, tvel, out=out)
    assert obs is out  # written in place, dtype of the buffer kept
    sl = TRACK_LAYOUT.slices()
    rot = euler_to_rotmat(state[:, IDX["roll"]], state[:, IDX["pitch"]], state[:, IDX["yaw"]])
    np.testing.assert_allclose(
        obs[:, sl["pos_error"]], np.einsum("nji,nj->ni", rot, state[:, 0:3] - target), atol=1e-12
    )
    np.testing.assert_allclose(obs[:, sl["target_vel"]], np.einsum("nji,nj->ni", rot, tvel), atol=1e-12)
    np.testing.assert_array_equal(obs[:, sl["rates"]], state[:, 9:12])
    with pytest.raises(ValueError, match="out must have shape"):
        build_observation(state, target, out=np.zeros((4, 21), np.float32))
    with pytest.raises(ValueError, match="state must have shape"):
        build_observation(state[:, :9], target)


def test_observation_is_continuous_across_yaw_wrap():
    state = np.zeros((2, 12))
    state[:, IDX["roll"]], state[:, IDX["pitch"]] = 0.2, -0.1
    state[0, IDX["yaw"]] = np.pi - 1e-6
    state[1, IDX["yaw"]] = -np.pi + 1e-6
    obs = build_observation(state, np.zeros(3))
    # raw yaw differs by 2π − 2e-6; the observation moves by the true rotation, ~2e-6
    assert np.max(np.abs(obs[0] - obs[1])) < 1e-5
    assert abs(state[0, IDX["yaw"]] - state[1, IDX["yaw"]]) > 6


def test_unknown_layout_is_refused():
    with pytest.raises(ValueError, match=r"quadpilot\.obs\.hover/999") as err:
        get_layout("quadpilot.obs.hover/999")
    assert "quadpilot.obs.track/1" in str(err.value)


def test_tilt_penalty_only_beyond_the_soft_limit():
    from quadpilot.core.reward import RewardConfig, hover_reward

    cfg = RewardConfig(tilt_weight=50.0, tilt_soft_deg=40.0)
    state = np.zeros((3, 12))
    state[:, IDX["roll"]] = np.radians([30.0, 39.9, 30.0])
    state[:, IDX["pitch"]] = np.radians([0.0, -20.0, -50.0])  # the larger of |roll|, |pitch| counts
    r = hover_reward(state, np.zeros((3, 3)), np.zeros(3, bool), cfg)
    plain = hover_reward(state, np.zeros((3, 3)), np.zeros(3, bool), RewardConfig())
    assert r[0] == plain[0] and r[1] == plain[1]
    assert r[2] == pytest.approx(plain[2] - 50.0 * math.radians(10.0) ** 2, rel=1e-12)
    assert RewardConfig().tilt_weight == 0.0  # off unless a task asks for it
