"""The reference policies shipped in models/ still meet their success bars:
hover success ≥ 95 %; waypoint at the 2 m stage success ≥ 95 % with mean final distance ≤ 5 cm;
circle radial RMS ≤ 5 cm and speed error ≤ 0.1 m/s after the first lap. The randomised hover
policy ≥ 95 % on the nominal plant and on the perturbed grid's hardest corners. The
recurrent hover policy ≥ 95 % under the sensor noise and motor lag it was trained with,
flown in quad-sitl with the noise on, and its ONNX file runs with explicit LSTM state. The hover
policies trained for other airframes (PX4's SIH quad-X, RotorPy's Hummingbird from a vehicle file)
≥ 95 % on their own vehicle, started with their rotors anywhere from rest to hover. Success includes
the held heading everywhere (`core.mission`: mean |yaw rate| ≤ 0.2 rad/s and heading within 10°
over the last 2 s), and each model's eval.json says so.

Short evaluations (fewer episodes than the 100 of eval.json, other start seeds) so the default test
run stays fast; each shipped eval.json holds the full 100-episode figures."""

import dataclasses
import json
from pathlib import Path

import pytest

from quadpilot.core.timing import TimingConfig
from quadpilot.train.algorithms import load_policy
from quadpilot.train.envs.evaluate import evaluate

MODELS = Path(__file__).parents[2] / "models"
EPISODES = 50


def shipped(task: str):
    path = MODELS / task / "policy.pt"
    assert path.is_file(), f"{path} is missing: the reference policies ship with the repository"
    return load_policy(path), json.loads((MODELS / task / "eval.json").read_text())


LINKS = (None, TimingConfig.fixed(20.0, 10.0))
"""The timings a hover policy trained through delay is judged at here: none, and 20 ms each way with
±10 ms of jitter (quad-sitl --link-impair delay=20ms,jitter=10ms)."""


@pytest.mark.parametrize("timing", LINKS, ids=["no_delay", "delay_20ms_jitter_10ms"])
def test_hover_policy_holds_the_target(timing):
    policy, stored = shipped("hover")
    assert policy.env_config.task == "hover" and policy.env_config.timing.name == "link"
    r = evaluate(policy, dataclasses.replace(policy.env_config, timing=timing), episodes=EPISODES, seed=2024)
    assert r["success_rate"] >= 0.95, r
    assert r["mean_error_last_window_m"] <= 0.05, r
    assert stored["episodes"] == 100


def test_waypoint_policy_reaches_targets_two_metres_away():
    policy, stored = shipped("waypoint")
    cfg = dataclasses.replace(policy.env_config, target_radius=2.0)  # the last curriculum stage
    r = evaluate(policy, cfg, episodes=EPISODES, seed=2024)
    assert r["success_rate"] >= 0.95, r
    assert r["mean_final_distance_m"] <= 0.05, r
    assert stored["target_radius"] == 2.0 and stored["success_rate"] >= 0.95


def test_circle_policy_follows_the_circle():
    policy, stored = shipped("circle")
    r = evaluate(policy, policy.env_config, episodes=EPISODES // 2, seed=2024)
    assert r["crash_rate"] == 0.0, r
    assert r["radial_rms_m"] <= 0.05 and r["speed_error_mps"] <= 0.1, r
    assert r["circle_success_rate"] >= 0.95, r
    assert stored["circle_success_rate"] >= 0.95


@pytest.mark.parametrize(
    ("folder", "vehicle"),
    [
        ("hover_px4_sih", "px4_sih_quadx"),
        ("hover_hummingbird", "rotorpy_hummingbird"),
        ("hover_crazyflie", "crazyflie"),
    ],
)
def test_airframe_policies_hold_the_target_on_their_own_vehicle(folder, vehicle):
    policy, stored = shipped(folder)
    cfg = policy.env_config
    assert cfg.params.name == vehicle and cfg.init_rotor == "random"
    # a policy trained through delay is judged without it and through quad-sitl's delay=20ms,jitter=10ms
    for timing in LINKS if cfg.timing is not None else (None,):
        r = evaluate(policy, dataclasses.replace(cfg, timing=timing), episodes=EPISODES, seed=2024)
        assert r["success_rate"] >= 0.95, (timing, r)
        assert r["mean_error_last_window_m"] <= 0.05, (timing, r)
    assert stored["episodes"] == 100 and (cfg.timing is not None or stored["success_rate"] >= 0.95)


@pytest.mark.parametrize(
    "folder",
    ["hover", "waypoint", "circle", "hover_dr", "hover_lstm", "hover_px4_sih", "hover_hummingbird", "hover_crazyflie"],
)
def test_each_shipped_model_holds_its_heading_under_the_yaw_rule(folder):
    """Every shipped model was trained and judged with the heading held: its observation is the
    version-2 layout (attitude relative to the commanded heading) and its eval.json's worst episode
    is within the yaw rule."""
    from quadpilot.core.mission import HEADING_TOLERANCE_DEG, YAW_RATE_TOLERANCE_RAD_S

    policy, stored = shipped(folder)
    assert policy.layout.heading_frame and policy.env_config.obs_version == 2
    # trained through delay: judged without it and at delay=20ms,jitter=10ms (the draws it trained on
    # reach 60 ms, past what it is asked to hold)
    judged = list(stored["timings"].values()) if policy.env_config.timing is not None else [stored]
    for r in judged:
        assert r["max_mean_abs_yaw_rate_last_window_rad_s"] <= YAW_RATE_TOLERANCE_RAD_S
        assert r["max_mean_heading_error_last_window_deg"] <= HEADING_TOLERANCE_DEG


@pytest.mark.parametrize(
    "folder", ["hover", "waypoint", "circle", "hover_dr", "hover_px4_sih", "hover_hummingbird", "hover_crazyflie"]
)
def test_each_model_folder_says_how_it_was_made(folder):
    config = json.loads((MODELS / folder / "config.json").read_text())
    assert config["command"].startswith(f"quad-train --task {config['task']}")
    assert (MODELS / folder / "policy.pt").stat().st_size < 512 * 1024  # small, deliberate files


# --- the randomised hover policy -----------------------------------------------------


@pytest.mark.parametrize(
    "plant",
    [(1.0, 1.0, 0.0), (1.15, 0.92, 1.0), (0.85, 1.08, 1.0)],
    ids=["nominal", "heavy-weak-1mps-wind", "light-strong-1mps-wind"],
)
def test_randomised_hover_policy_holds_on_perturbed_plants(plant):
    """Mass ×{0.85, 1.15}, k_f ×{1.08, 0.92} and 1 m/s of wind: the grid's corners, where the
    nominal policy fails (docs/robustness.md); the policy still maps through the nominal hover
    command."""
    from quadpilot.core.randomization import RandomizationConfig

    policy, stored = shipped("hover_dr")
    assert policy.env_config.randomization is not None and policy.env_config.randomization.name == "default"
    mass, k_f, wind = plant
    cell = RandomizationConfig.fixed(mass=mass, k_f=k_f, wind=wind, drag=0.2 if wind else None)
    cfg = dataclasses.replace(policy.env_config, randomization=cell)
    r = evaluate(policy, cfg, episodes=EPISODES, seed=2024)
    assert r["success_rate"] >= 0.95, r
    if plant == (1.0, 1.0, 0.0):
        assert r["mean_error_last_window_m"] <= 0.015, r  # within 1 cm of the nominal policy's accuracy
    assert stored["nominal"]["success_rate"] >= 0.95 and stored["sitl"]["grid"]


def test_recurrent_hover_policy_holds_the_target_under_noise_and_motor_lag():
    policy, stored = shipped("hover_lstm")
    cfg = policy.env_config
    assert policy.recurrent and cfg.task == "hover"
    assert cfg.noise is not None and cfg.noise.name == "seed" and cfg.params.motor_tau == 0.03
    r = evaluate(policy, cfg, episodes=EPISODES, seed=2024)
    assert r["success_rate"] >= 0.95, r
    assert r["mean_error_last_window_m"] <= 0.05, r
    assert stored["success_rate"] >= 0.95 and stored["episodes"] == 100
    # the stored SITL record says what was flown; the flight itself is repeated below
    assert "--imu-noise --estimator-noise --motor-tau 0.03" in stored["sitl"]["command"]


@pytest.mark.sitl
def test_recurrent_hover_policy_flies_in_quad_sitl_with_noise_and_motor_lag(tmp_path, capsys):
    """The ONNX file of the recurrent policy, flown over MAVLink with the simulator's IMU noise,
    estimator noise and 30 ms motor lag on: every episode reaches the hover bar (--min-success 1)
    and no failsafe fires. Three episodes (the shipped sitl.json holds 100)."""
    from quadpilot.sitl import main

    out = tmp_path / "sitl.json"
    noise = ["--imu-noise", "--estimator-noise", "--motor-tau", "0.03"]
    flags = ["--episodes", "3", "--seed", "5", "--gcs", "none", "--json", str(out), "--min-success", "1"]
    assert main([str(MODELS / "hover_lstm" / "policy.onnx"), *flags, *noise]) == 0
    s = json.loads(out.read_text())
    assert s["success_rate"] == 1.0 and s["failsafe_events"] == 0 and s["mean_error_last_2s_m"] <= 0.05, s


def test_recurrent_hover_onnx_file_runs_with_explicit_state():
    import numpy as np

    from quadpilot.runtime import load_policy as load_runtime

    runtime = load_runtime(MODELS / "hover_lstm" / "policy.onnx", "numpy")  # checks contract and golden vectors
    assert runtime.info.recurrent
    config = json.loads((MODELS / "hover_lstm" / "config.json").read_text())
    assert config["command"].startswith("quad-train --task hover --arch lstm")
    # shipped as quad-train wrote it (resumable: LSTM weights, Adam state, LSTM states in flight): larger
    # than the MLPs' files, still small
    assert (MODELS / "hover_lstm" / "policy.pt").stat().st_size < 1024 * 1024
    obs = np.zeros(18, np.float32)
    assert np.all(np.isfinite(runtime.act(obs)))


# --- the policies of PX4 mc_raptor's contract ------------------------------------------


@pytest.mark.parametrize(
    ("folder", "vehicle"),
    [("hover_px4_raptor_sih", "px4_sih_quadx"), ("hover_px4_raptor_hummingbird", "rotorpy_hummingbird")],
)
def test_px4_raptor_policies_fly_from_their_policy_tar_within_the_hover_rule(folder, vehicle):
    """The file mc_raptor loads, run by the runtime's NumPy step through the contract, in the batched
    simulator from seeded starts (other than eval.json's); eval.json holds the 100-episode figures."""
    import numpy as np

    from quadpilot.core.mission import HEADING_TOLERANCE_DEG, YAW_RATE_TOLERANCE_RAD_S
    from quadpilot.runtime.gru import GruStep
    from quadpilot.runtime.rltools_tar import read_policy_tar
    from quadpilot.train.envs import EnvConfig
    from quadpilot.train.raptor.distill import fly, load_student, numpy_policy

    _, ckpt = load_student(MODELS / folder / "policy.pt")
    cfg = EnvConfig.from_json(ckpt["env_config"])
    assert cfg.params.name == vehicle
    tar = read_policy_tar(MODELS / folder / "policy.tar")  # checks it whole, and its SHA-256 beside it
    r = fly(numpy_policy(GruStep(tar.weights)), cfg, 20, np.random.default_rng(2024))["figures"]
    assert r["success_rate"] >= 0.95 and r["mean_error_last_window_m"] <= 0.05, r
    stored = json.loads((MODELS / folder / "eval.json").read_text())
    assert stored["success_rate"] >= 0.95 and stored["episodes"] == 100 and stored["contract"] == "px4-raptor"
    assert stored["max_mean_abs_yaw_rate_last_window_rad_s"] <= YAW_RATE_TOLERANCE_RAD_S
    assert stored["max_mean_heading_error_last_window_deg"] <= HEADING_TOLERANCE_DEG
    config = json.loads((MODELS / folder / "config.json").read_text())
    assert config["command"].startswith("quad-train --task hover --contract px4-raptor --vehicle ")
