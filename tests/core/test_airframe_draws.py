"""Drawn airframes (`--randomize airframes`): every draw inside `AIRFRAMES`' ranges and physical, the
motor map's hover command that of each drone's drawn file, the true plant off that file by the
preset's scales, the set's airframes inside the ranges, and a resumed run keeping the commands."""

import math
from pathlib import Path

import numpy as np
import pytest

from quadpilot.core.params import ParamBatch
from quadpilot.core.randomization import AIRFRAMES, PRESETS, Randomizer, draw_airframes, preset
from quadpilot.core.vehicle_file import SEED_VEHICLE, load_vehicle_file
from quadpilot.train.envs import make_config
from quadpilot.train.envs.batch import QuadBatch

N = 4000


def test_draws_stay_in_their_ranges_and_cover_them():
    rng = np.random.default_rng(1)
    d = draw_airframes(rng, N)
    r = AIRFRAMES
    assert r.mass[0] <= d["mass"].min() < 1.2 * r.mass[0] and 0.8 * r.mass[1] < d["mass"].max() <= r.mass[1]
    # log-uniform: as many draws below the geometric middle as above it
    middle = math.sqrt(r.mass[0] * r.mass[1])
    assert abs((d["mass"] < middle).mean() - 0.5) < 0.03
    c = d["ixx"] / (d["mass"] * d["arm"] ** 2)
    assert r.inertia[0] <= c.min() and c.max() <= r.inertia[1]
    assert np.all(d["iyy"] == d["ixx"])
    ratio = d["izz"] / d["ixx"]
    assert r.yaw_inertia[0] <= ratio.min() and ratio.max() <= r.yaw_inertia[1]
    twr = 4 * d["k_f"] * d["omega_max"] ** 2 / (d["mass"] * 9.81)
    assert r.thrust_to_weight[0] - 1e-9 <= twr.min() and twr.max() <= r.thrust_to_weight[1] + 1e-9
    assert r.k_m[0] <= d["k_m"].min() and d["k_m"].max() <= r.k_m[1]


def authority(mass, arm, ixx):
    """rad/s² of roll acceleration per unit of differential action (a quad-X's two left rotors at
    +a, its two right ones at −a: torque 4·(weight/4)·a·arm/√2)."""
    return arm * mass * 9.81 / 4 / ixx / math.sqrt(2)


def test_the_set_lies_inside_the_ranges():
    """Flying the benchmark's airframes is interpolation: each one's mass, inertia shape, yaw
    inertia and yaw torque lie in what the generalist was drawn from, and so does the angular
    acceleration its arm gives (between the 1st and 99th percentile of the draws; the arm itself
    of PX4 SIH's quad-X lies outside `AIRFRAMES.arm`, as its docstring says)."""
    r = AIRFRAMES
    d = draw_airframes(np.random.default_rng(0), 100_000)
    low, high = np.percentile(authority(d["mass"], d["arm"], d["ixx"]), [1, 99])
    files = sorted((Path(__file__).resolve().parents[2] / "benchmarks" / "airframes").glob("*.toml"))
    assert len(files) >= 8  # the set, not an empty loop
    for path in files:
        v = load_vehicle_file(path)
        assert r.mass[0] <= v.mass <= r.mass[1], path
        assert low <= authority(v.mass, v.arm, v.ixx) <= high, path
        assert r.inertia[0] <= v.ixx / (v.mass * v.arm**2) <= r.inertia[1], path
        assert r.yaw_inertia[0] <= v.izz / v.ixx <= r.yaw_inertia[1], path
        assert r.k_m[0] <= v.k_m <= r.k_m[1], path


def test_motor_map_uses_each_drawn_files_hover_command_and_the_plant_is_off_by_the_scales():
    cfg = preset("airframes")
    rz = Randomizer(cfg, SEED_VEHICLE, N, 0.01)
    params = rz.resample(ParamBatch.from_preset(SEED_VEHICLE, N), np.arange(N), np.random.default_rng(3), 500)
    # the file's hover command from its own (drawn) numbers, recomputed from the plant and the scales
    rng = np.random.default_rng(3)
    file = draw_airframes(rng, N)
    expect = np.sqrt(file["mass"] * 9.81 / 4 / file["k_f"]) / file["omega_max"]
    np.testing.assert_allclose(rz.u_hover, expect, rtol=1e-6)
    mass_scale, kf_scale = params.mass / file["mass"], params.k_f / file["k_f"]
    assert cfg.mass[0] <= mass_scale.min() < 0.72 and 1.28 < mass_scale.max() <= cfg.mass[1]
    assert cfg.k_f[0] <= kf_scale.min() < 0.82 and 1.18 < kf_scale.max() <= cfg.k_f[1]
    np.testing.assert_array_equal(params.arm, file["arm"])
    np.testing.assert_array_equal(params.omega_max, file["omega_max"])
    # drag and pushes are per kilogram of the drawn mass
    per_kg = params.drag / file["mass"]
    assert cfg.drag[0] <= per_kg.min() and per_kg.max() <= cfg.drag[1]
    pushes = np.linalg.norm(rz.push_force, axis=1) / file["mass"]
    assert pushes.max() <= cfg.push_force[1] + 1e-9 and pushes.max() > 0.9 * cfg.push_force[1]


def test_zero_action_holds_a_drone_whose_file_is_right():
    """With the scales at 1 (a right file) and no wind or pushes, every drawn airframe hovers at a
    zero action: the motor map's hover command is its own, for a 25 g micro and a 3 kg quad alike."""
    import dataclasses

    right = dataclasses.replace(
        PRESETS["airframes"], mass=(1, 1), inertia=(1, 1), k_f=(1, 1), k_m=(1, 1), wind_speed=(0, 0), push_prob=0.0
    )
    still = {"init_vel": 0.0, "init_tilt_deg": 0.0, "init_rate": 0.0}
    batch = QuadBatch(make_config("hover", randomization=right, init_rotor="hover", **still), 256)
    batch.reset(np.ones(256, bool), np.random.default_rng(0))
    assert batch.params.mass.min() < 0.05 and batch.params.mass.max() > 1.5
    start = batch.state.copy()
    for _ in range(50):
        batch.step(np.zeros((256, 4), np.float32))
    np.testing.assert_allclose(batch.state[:, 3:12], start[:, 3:12], atol=1e-3)  # after 0.5 s: still level, at rest


@pytest.mark.parametrize("init_rotor", ["hover", "random"])
def test_rotors_start_at_or_below_each_drones_own_hover_command(init_rotor):
    batch = QuadBatch(make_config("hover", randomization="airframes", init_rotor=init_rotor), 512)
    batch.reset(np.ones(512, bool), np.random.default_rng(0))
    u = batch.u_hover[:, None]
    if init_rotor == "hover":
        np.testing.assert_array_equal(batch.rotor, np.broadcast_to(u, batch.rotor.shape))
    else:
        assert np.all(batch.rotor <= u + 1e-7) and np.all(batch.rotor[:, 0] == batch.rotor[:, 1])


def test_a_restored_randomizer_keeps_the_motor_map_it_is_read_through():
    batch = QuadBatch(make_config("hover", randomization="airframes"), 64)
    batch.reset(np.ones(64, bool), np.random.default_rng(0))
    saved = batch.randomizer.state_dict()
    other = QuadBatch(make_config("hover", randomization="airframes"), 64)
    other.randomizer.load_state_dict(saved)
    assert other.u_hover is other.randomizer.u_hover  # the env reads the restored values
    np.testing.assert_array_equal(other.u_hover, batch.u_hover)


def test_a_checkpoint_from_before_airframes_still_restores_a_plain_randomizer():
    rz = Randomizer(preset("default"), SEED_VEHICLE, 8, 0.01)
    old = rz.state_dict()
    assert "u_hover" not in old  # a plain randomised run's checkpoint holds what it always held
    rz.load_state_dict(old)
    airframes = Randomizer(preset("airframes"), SEED_VEHICLE, 8, 0.01)
    assert "u_hover" in airframes.state_dict()
    with pytest.raises(KeyError):
        airframes.load_state_dict(old)


def test_a_generalist_run_stops_and_resumes(tmp_path):
    """quad-train --randomize airframes: its checkpoint carries each drone's hover command, and the
    run resumes from it (the checkpoint check compares it with a fresh run of the same flags)."""
    from quadpilot.train.algorithms import load_checkpoint
    from quadpilot.train.cli import main

    flags = ["--task", "hover", "--randomize", "airframes", "--num-envs", "8", "--rollout-steps", "16"]
    flags += ["--minibatch-size", "64", "--threads", "1", "--eval-episodes", "0", "--eval-every", "0"]
    run = tmp_path / "run"
    assert main([*flags, "--total-steps", "128", "--out", str(run)]) == 0
    saved = load_checkpoint(run / "checkpoint.pt")["env"]["randomization"]["u_hover"]
    assert saved.shape == (8,) and float(saved.min()) != float(saved.max())  # eight drawn airframes
    assert main([*flags, "--total-steps", "256", "--out", str(run), "--resume"]) == 0
    assert load_checkpoint(run / "checkpoint.pt")["global_step"] == 256


def test_a_generalist_is_not_trained_on_a_vehicle_file(tmp_path, capsys):
    """--vehicle with --randomize airframes: the file's rotor aerodynamics and lowest rotor speed
    would go to every drawn airframe; refused in one line before anything runs."""
    from quadpilot.train.cli import main

    flags = ["--task", "hover", "--randomize", "airframes", "--out", str(tmp_path / "run")]
    assert main([*flags, "--vehicle", str(Path(__file__).resolve().parents[2] / "benchmarks/airframes/x500.toml")]) == 2
    err = capsys.readouterr().err.strip()
    assert "quad-export --vehicle FILE" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "run").exists()
