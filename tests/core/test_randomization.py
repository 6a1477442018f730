"""Domain randomisation in `core`: ranges respected at every reset, the same plants for the same
seed, external force and moment in the dynamics against the analytic answer, and the derived-
constant cache of a ParamBatch never outliving a resample."""

import dataclasses
import math

import numpy as np
import pytest

from quadpilot.core.dynamics import IDX, step
from quadpilot.core.params import ParamBatch
from quadpilot.core.randomization import PRESETS, RandomizationConfig, Randomizer, preset
from quadpilot.core.vehicle_file import CRAZYFLIE, SEED_VEHICLE

DT = 0.01
G = SEED_VEHICLE.gravity


def level_at(n, z=10.0, dtype=np.float64):
    s = np.zeros((n, 12), dtype)
    s[:, IDX["z"]] = z
    return s


def hover_cmd(n, vehicle=SEED_VEHICLE, dtype=np.float64):
    return np.full((n, 4), vehicle.hover_command, dtype)


# --- external force and moment in the dynamics ---------------------------------------------


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_constant_force_gives_force_over_mass(dtype):
    """Hover thrust cancels gravity; a constant world force F then accelerates at F/m, and the
    model's constant-acceleration update is exact: p = p0 + ½·a·t², v = a·t."""
    params = ParamBatch.from_preset(SEED_VEHICLE, 2).astype(dtype)
    force = np.array([[0.3, -0.2, 0.1], [-1.0, 0.0, 0.5]], dtype)
    s, w, u = level_at(2, dtype=dtype), hover_cmd(2, dtype=dtype), hover_cmd(2, dtype=dtype)
    steps = 50
    for _ in range(steps):
        s, w = step(s, w, u, params, DT, force=force)
    t = steps * DT
    a = force / SEED_VEHICLE.mass
    tol = 1e-9 if dtype == np.float64 else 2e-4
    np.testing.assert_allclose(s[:, 3:6], a * t, atol=tol)
    np.testing.assert_allclose(s[:, 0:3] - level_at(2)[:, 0:3], 0.5 * a * t * t, atol=tol)
    np.testing.assert_allclose(s[:, 6:12], 0.0, atol=1e-12)  # a force at the centre of mass turns nothing


def test_constant_torque_spins_up_at_torque_over_inertia():
    """From rest at hover thrust, a body moment τ about one axis gives ω = τ/I·t on that axis."""
    params = ParamBatch.from_preset(SEED_VEHICLE, 3)
    torque = np.diag([1e-3, -2e-3, 5e-4])  # drone i: about body axis i
    s, w, u = level_at(3), hover_cmd(3), hover_cmd(3)
    for _ in range(10):
        s, w = step(s, w, u, params, DT, torque=torque)
    inertia = np.array([SEED_VEHICLE.ixx, SEED_VEHICLE.iyy, SEED_VEHICLE.izz])
    np.testing.assert_allclose(s[:, 9:12], torque / inertia * 0.1, rtol=1e-9, atol=1e-15)


def test_zero_external_force_is_bit_for_bit_none_and_shapes_are_checked():
    params = ParamBatch.from_preset(SEED_VEHICLE, 4)
    rng = np.random.default_rng(0)
    s = level_at(4) + rng.normal(0, 0.1, (4, 12))
    u = rng.uniform(0.5, 0.8, (4, 4))
    plain = step(s, u, u, params, DT)
    zero = step(s, u, u, params, DT, force=np.zeros((4, 3)), torque=np.zeros((4, 3)))
    for a, b in zip(plain, zero, strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="force must have shape"):
        step(s, u, u, params, DT, force=np.zeros(3))
    with pytest.raises(ValueError, match="torque must have shape"):
        step(s, u, u, params, DT, torque=np.zeros((3, 3)))


def test_wind_through_drag_carries_the_vehicle_to_wind_speed():
    """F = drag·(wind − v): −drag·v from ParamBatch.drag, drag·wind as the external force. A
    hovering vehicle drifts with v(t) = wind·(1 − e^(−t·drag/m))."""
    drag, wind = 0.2, np.array([1.0, -0.5, 0.0])
    params = ParamBatch.from_preset(dataclasses.replace(SEED_VEHICLE, drag=drag), 1)
    s, w, u = level_at(1), hover_cmd(1), hover_cmd(1)
    force = (drag * wind)[None]
    for _ in range(300):
        s, w = step(s, w, u, params, DT, force=force)
    k = drag / SEED_VEHICLE.mass
    expected = wind * (1.0 - math.exp(-3.0 * k))
    np.testing.assert_allclose(s[0, 3:6], expected, rtol=2e-3, atol=1e-6)


# --- the derived-constant cache ---------------------------------------------------------------


def test_resampled_batch_is_a_new_object_and_the_dynamics_sees_the_new_values():
    """`core.dynamics` caches per-drone constants on the ParamBatch. A resample must give a new
    batch (fresh cache) and leave the old one, and its cache, as they were."""
    pb = ParamBatch.from_preset(SEED_VEHICLE, 2)
    s, w, u = level_at(2), hover_cmd(2), hover_cmd(2)
    s1, _ = step(s, w, u, pb, DT)  # fills pb's cache
    assert "_derived_cache" in pb.__dict__
    np.testing.assert_allclose(s1[:, IDX["vz"]], 0.0, atol=1e-12)  # hover holds

    heavy = pb.with_entries(np.array([0]), mass=2.0 * SEED_VEHICLE.mass)
    assert heavy is not pb and "_derived_cache" not in heavy.__dict__
    s2, _ = step(s, w, u, heavy, DT)
    assert s2[0, IDX["vz"]] == pytest.approx(-0.5 * G * DT, rel=1e-12)  # half the thrust it needs
    assert s2[1, IDX["vz"]] == pytest.approx(0.0, abs=1e-12)  # the other drone keeps its plant
    s3, _ = step(s, w, u, pb, DT)  # the old batch and its cache are untouched
    np.testing.assert_array_equal(s3, s1)
    assert pb.mass[0] == SEED_VEHICLE.mass


def test_a_batch_cannot_be_changed_in_place():
    """In-place writes would leave stale cached constants: the arrays are read-only."""
    pb = ParamBatch.from_preset(SEED_VEHICLE, 3)
    with pytest.raises(ValueError, match="read-only"):
        pb.mass[0] = 1.0
    mine = np.full(3, 0.5)
    pb2 = dataclasses.replace(pb, mass=mine)
    mine[0] = 9.0  # the caller's array stays the caller's: the batch holds a copy
    assert pb2.mass[0] == 0.5
    with pytest.raises(ValueError, match="no per-drone field"):
        pb.with_entries([0], gravity=1.0)


def test_randomizer_resample_changes_the_dynamics_of_reset_drones_only():
    cfg = RandomizationConfig.fixed(mass=1.25, k_f=1.0)
    r = Randomizer(cfg, SEED_VEHICLE, 3, DT, np.float64)
    pb = ParamBatch.from_preset(SEED_VEHICLE, 3)
    step(level_at(3), hover_cmd(3), hover_cmd(3), pb, DT)
    pb2 = r.resample(pb, np.array([1]), np.random.default_rng(0), 500)
    s, _ = step(level_at(3), hover_cmd(3), hover_cmd(3), pb2, DT)
    # the nominal hover command on a vehicle 25 % heavier: a = g·(1/1.25 − 1)
    assert s[1, IDX["vz"]] == pytest.approx(G * (1 / 1.25 - 1) * DT, rel=1e-12)
    np.testing.assert_allclose(s[[0, 2], IDX["vz"]], 0.0, atol=1e-12)


# --- sampling ---------------------------------------------------------------------------------


def draw(cfg, n=4000, seed=0, vehicle=SEED_VEHICLE):
    r = Randomizer(cfg, vehicle, n, DT, np.float64)
    pb = r.resample(ParamBatch.from_preset(vehicle, n), np.arange(n), np.random.default_rng(seed), 500)
    return r, pb


def test_every_draw_is_within_its_range_and_covers_it():
    cfg = PRESETS["pushes"]
    r, pb = draw(cfg)
    nom = SEED_VEHICLE
    checks = {
        "mass": (pb.mass / nom.mass, cfg.mass),
        "ixx": (pb.ixx / nom.ixx, cfg.inertia),
        "iyy": (pb.iyy / nom.iyy, cfg.inertia),
        "izz": (pb.izz / nom.izz, cfg.inertia),
        "k_f": (pb.k_f / nom.k_f, cfg.k_f),
        "k_m": (pb.k_m / nom.k_m, cfg.k_m),
        "motor_tau": (pb.motor_tau, cfg.motor_tau),
        "drag": (pb.drag, cfg.drag),
        "wind speed": (np.linalg.norm(r.wind, axis=1), cfg.wind_speed),
        "push force": (np.linalg.norm(r.push_force, axis=1), cfg.push_force),
        "push torque": (np.linalg.norm(r.push_torque, axis=1), cfg.push_torque),
    }
    for name, (x, (lo, hi)) in checks.items():
        assert x.min() >= lo - 1e-12 * hi and x.max() <= hi * (1 + 1e-12), name
        assert x.min() < lo + 0.01 * (hi - lo) and x.max() > hi - 0.01 * (hi - lo), name  # uniform: reaches both ends
    np.testing.assert_array_equal(r.wind[:, 2], 0.0)  # horizontal
    np.testing.assert_allclose(r.wind_force, pb.drag[:, None] * r.wind)
    np.testing.assert_array_equal(pb.arm, nom.arm)  # not randomised
    np.testing.assert_array_equal(pb.omega_max, nom.omega_max)
    pushed = r.push_end > r.push_start
    assert 0.45 < pushed.mean() < 0.55  # push_prob 0.5
    length = (r.push_end - r.push_start)[pushed] * DT
    assert length.min() >= cfg.push_duration[0] - DT / 2 and length.max() <= cfg.push_duration[1] + DT / 2
    assert r.push_start.min() >= 0 and r.push_start.max() < 500


def test_only_the_reset_drones_get_new_plants():
    n = 6
    r = Randomizer(PRESETS["default"], SEED_VEHICLE, n, DT, np.float64)
    rng = np.random.default_rng(1)
    pb = r.resample(ParamBatch.from_preset(SEED_VEHICLE, n), np.arange(n), rng, 500)
    wind = r.wind.copy()
    idx = np.array([1, 4])
    pb2 = r.resample(pb, idx, rng, 500)
    keep = np.setdiff1d(np.arange(n), idx)
    for f in ("mass", "ixx", "k_f", "k_m", "motor_tau", "drag"):
        np.testing.assert_array_equal(getattr(pb2, f)[keep], getattr(pb, f)[keep])
        assert np.all(getattr(pb2, f)[idx] != getattr(pb, f)[idx]), f
    np.testing.assert_array_equal(r.wind[keep], wind[keep])


def test_same_seed_same_plants_other_seed_other_plants():
    cfg = PRESETS["pushes"]
    (ra, a), (rb, b), (_, c) = draw(cfg, 50, 3), draw(cfg, 50, 3), draw(cfg, 50, 4)
    for f in ("mass", "ixx", "k_f", "k_m", "motor_tau", "drag"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
        assert not np.array_equal(getattr(a, f), getattr(c, f))
    for k in Randomizer.STATE:
        np.testing.assert_array_equal(getattr(ra, k), getattr(rb, k))


def test_fixed_plant_and_fixed_wind_direction():
    r, pb = draw(RandomizationConfig.fixed(mass=1.15, k_f=0.92, wind=1.0, wind_direction_deg=0.0, drag=0.2), 5)
    np.testing.assert_array_equal(pb.mass, 1.15 * SEED_VEHICLE.mass)
    np.testing.assert_array_equal(pb.k_f, 0.92 * SEED_VEHICLE.k_f)
    np.testing.assert_array_equal(pb.ixx, SEED_VEHICLE.ixx)
    np.testing.assert_allclose(r.wind, np.tile([1.0, 0.0, 0.0], (5, 1)), atol=1e-15)  # quad-sitl --wind 1,0,0
    np.testing.assert_allclose(r.wind_force, np.tile([0.2, 0.0, 0.0], (5, 1)), atol=1e-15)


def test_external_force_is_none_without_wind_or_pushes_and_a_push_acts_only_in_its_window():
    r, _ = draw(PRESETS["params"], 3)
    assert r.external(np.zeros(3, np.int64)) == (None, None)
    cfg = dataclasses.replace(PRESETS["params"], push_prob=1.0, push_force=(1.0, 1.0), push_torque=(0.01, 0.01))
    r, _ = draw(cfg, 3)
    for k in range(500):
        steps = np.full(3, k)
        force, torque = r.external(steps)
        active = (r.push_start <= k) & (k < r.push_end)
        if not active.any():
            assert force is None and torque is None
            continue
        np.testing.assert_allclose(np.linalg.norm(force, axis=1), np.where(active, 1.0, 0.0), atol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(torque, axis=1), np.where(active, 0.01, 0.0), atol=1e-12)


def test_config_checks_and_json_round_trip():
    cfg = PRESETS["pushes"]
    assert RandomizationConfig.from_json(cfg.to_json()) == cfg
    import json

    assert RandomizationConfig.from_json(json.loads(json.dumps(cfg.to_json()))) == cfg
    with pytest.raises(ValueError, match=r"low 1\.2 > high 0\.8"):
        RandomizationConfig(mass=(1.2, 0.8))
    with pytest.raises(ValueError, match="scales must be > 0"):
        RandomizationConfig(k_f=(0.0, 1.0))
    with pytest.raises(ValueError, match="push_prob"):
        RandomizationConfig(push_prob=1.5)
    with pytest.raises(ValueError, match="unknown randomization field"):
        RandomizationConfig.from_json({"mass_range": [1, 2]})
    with pytest.raises(ValueError, match="wind acts through linear drag"):
        Randomizer(RandomizationConfig(drag=None), SEED_VEHICLE, 2, DT)
    with pytest.raises(ValueError, match="unknown randomization preset"):
        preset("nope")


def test_presets_scale_absolute_forces_to_the_vehicle():
    assert preset("default") is PRESETS["default"]
    cf = preset("pushes", CRAZYFLIE)
    m = CRAZYFLIE.mass / SEED_VEHICLE.mass
    assert cf.push_force == pytest.approx((0.0, 1.5 * m))
    assert cf.drag == pytest.approx((0.1 * m, 0.3 * m))
    assert cf.mass == PRESETS["pushes"].mass  # relative ranges as they are
