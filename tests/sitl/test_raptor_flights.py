"""RAPTOR's foundation policy, the policy PX4's mc_raptor flies, flown through our px4-raptor contract
code (`core.px4_raptor`, `runtime.raptor`) by `quad-sitl raptor:foundation`: in our simulator at
100 Hz (random starts, the project's success rule: within 5 cm and holding the heading) and at
250 Hz (the GRU advancing on every second step, as mc_raptor does at IMU_GYRO_RATEMAX 250), and in
RotorPy's PX4 simulator with PX4's SIH quad-X airframe at 250 Hz. Short flights; the figures of longer ones
are benchmarks/raptor_flights.py's (docs/bench/raptor_flights.json)."""

import json
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from quadpilot.sitl import main

pytestmark = pytest.mark.sitl
HERE = Path(__file__).parent
HOVER_BAR_M = 0.10
YAW_RATE_RAD_S = 0.2  # core.mission.YAW_RATE_TOLERANCE_RAD_S
HEADING_DEG = 10.0
SIM = [sys.executable, "-m", "quadpilot.simulator", "--sim-only"]
NODE = ["raptor:foundation", "--node-only", "--duration", "3", "--gcs", "none"]


@pytest.fixture(autouse=True)
def _package():
    try:
        import foundation_policy  # noqa: F401
    except ImportError:
        import os

        if os.environ.get("CI"):
            pytest.fail('foundation-policy is not installed: the dev extra installs it (pip install -e ".[dev]")')
        pytest.skip("needs the foundation-policy package: pip install foundation-policy")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_our_simulator_at_100_hz_from_random_starts(tmp_path):
    out = tmp_path / "s.json"
    assert main(["raptor:foundation", "--episodes", "2", "--duration", "4", "--gcs", "none", "--json", str(out)]) == 0
    s = json.loads(out.read_text())
    assert s["success_rate"] == 1.0 and s["crashes"] == 0 and s["fallback_steps"] == 0
    assert s["mean_error_last_2s_m"] <= HOVER_BAR_M
    assert s["max_abs_yaw_rate_last_2s_radps"] <= YAW_RATE_RAD_S and s["max_heading_error_last_2s_deg"] <= HEADING_DEG


def test_our_simulator_at_250_hz_runs_it_every_step(tmp_path):
    port = _free_port()
    sim = subprocess.Popen(
        [*SIM, "--rate", "250", "--episodes", "1", "--listen", f"tcp:127.0.0.1:{port}", "--vehicle", "px4_sih_quadx"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    out = tmp_path / "n.json"
    try:
        code = main([*NODE, "--connect", f"tcp:127.0.0.1:{port}", "--target=0.5,-0.3,0.4", "--json", str(out)])
        sim.wait(timeout=60)
    finally:
        sim.kill()
        sim.communicate()
    assert code == 0
    s = json.loads(out.read_text())
    assert s["steps"] == 750 and s["policy_steps"] == 750  # every gyro update, as mc_raptor
    assert s["error_last_2s_m"] <= HOVER_BAR_M and s["mean_abs_yaw_rate_last_2s_radps"] <= YAW_RATE_RAD_S
    assert abs(s["yaw_change_deg"]) <= HEADING_DEG and s["fallback_steps"] == 0


def test_rotorpys_px4_simulator_with_sih_quad_x(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("rotorpy_flight", HERE / "test_rotorpy.py")
    t = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(t)
    # 250 Hz, in lockstep: RotorPy waits for each step's answer (with its own 10 ms wait, on a loaded host
    # it may fly a step on the previous answer, a lag of 4 ms here: benchmarks/raptor_flights.py records it)
    case = t.RotorPyFlight(
        Path("raptor:foundation"), 250, 2, max_error_m=HOVER_BAR_M, duration_s=4.0, target=(0.4, -0.3, 0.3)
    )
    rotorpy, _, _, node = t.fly(case, tmp_path, lockstep=True)
    assert node.returncode == 0, node.stderr
    t.every_step_on_its_own_answer(rotorpy, 1000)  # no step missed or late
    rows = rotorpy["steps"]
    k = round(t.WINDOW_S * case.rate_hz)
    target = t.rotorpy_target(case.target)
    error = np.linalg.norm(np.array([r["x"] for r in rows])[-k:] - target, axis=1).mean()
    yaw_rate = np.abs(np.array([r["w"] for r in rows])[-k:, 2]).mean()
    heading = np.degrees(np.abs(t.rotorpy_yaw(np.array([r["q"] for r in rows])[-k:]))).mean()
    assert error <= HOVER_BAR_M and yaw_rate <= YAW_RATE_RAD_S and heading <= HEADING_DEG


def test_a_bad_name_or_backend_is_one_line(capsys):
    assert main(["raptor:nonesuch", "--episodes", "1", "--gcs", "none"]) == 1
    err = capsys.readouterr().err
    assert "unknown RAPTOR policy name" in err and len(err.strip().splitlines()) == 1


def test_the_c_backend_flies_it_like_numpy(tmp_path):
    out = tmp_path / "c.json"
    assert (
        main(
            [
                "raptor:foundation",
                "--backend",
                "c",
                "--episodes",
                "2",
                "--duration",
                "4",
                "--gcs",
                "none",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    s = json.loads(out.read_text())
    assert s["success_rate"] == 1.0 and s["mean_error_last_2s_m"] <= HOVER_BAR_M and s["fallback_steps"] == 0
