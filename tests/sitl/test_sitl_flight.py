"""Closed loop over real loopback TCP: the simulator (simulator) in a thread or its own process,
the node (runtime) flying the shipped hover ONNX file through the safety monitor.

Parity (lockstep, noise off): the SITL trajectory equals an in-process loop of the same policy on
`core.dynamics.step` (the function the training environment steps) whose observations pass through
the same wire encoding, to float rounding; and it stays within a stated bound of the loop that
sees the exact state, the difference being the wire's quantisation (1.1 cm latitude, 0.75 cm
longitude, 1 mm altitude, 1 cm/s) fed back through the policy."""

import json
import threading

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from quadpilot.autopilot.node import Node, NodeConfig, heading_within_reach
from quadpilot.core import dynamics
from quadpilot.core.observation import build_observation
from quadpilot.core.params import ParamBatch
from quadpilot.core.vehicle_file import get_preset
from quadpilot.link import wire
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.simulator import SimConfig, Simulator
from quadpilot.sitl import SHIPPED_HOVER, main

pytestmark = pytest.mark.sitl

START = np.array([0.6, -0.4, 2.5, 0.3, -0.2, 0.1, 0.2, -0.15, 2.0, 0.0, 0.0, 0.0])
TARGET = np.array([0.0, 0.0, 2.0])
STEPS = 300


def fly_sitl(start, steps=STEPS):
    sim = Simulator(SimConfig(listen="tcp:127.0.0.1:0", episodes=1, initial_state=tuple(start)))
    port = sim.bind().port
    thread = threading.Thread(target=sim.serve, daemon=True)
    thread.start()
    try:
        monitor = SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy"))
        node = Node(NodeConfig(connect=f"tcp:127.0.0.1:{port}", duration_s=steps * 0.01, connect_timeout_s=5.0))
        log = node.fly(monitor)
    finally:
        sim.stop()
        thread.join(5.0)
    return log, monitor


def fly_in_process(start, steps=STEPS, through_wire=True):
    """The same policy on core.dynamics.step; optionally observations through the wire encoding."""
    policy = load_policy(SHIPPED_HOVER, "numpy")
    params = ParamBatch.from_preset(get_preset("seed"), 1)
    state, rotor = start[None].copy(), np.full((1, 4), get_preset("seed").hover_command)
    out = []
    mav = mavlink.MAVLink(None)
    held = None  # the heading the node holds: that of the first state it saw
    for _ in range(steps):
        seen = state[0]
        if through_wire:
            fields = wire.hil_state_quaternion_fields(state[0], wire.Home(), 1)
            (msg,) = mavlink.MAVLink(None).parse_buffer(
                mavlink.MAVLink_hil_state_quaternion_message(**fields).pack(mav)
            )
            seen = wire.state_from_hil_state_quaternion(msg, wire.Home())
            seen[9:12] = np.float32(state[0, 9:12])  # HIL_SENSOR gyro: float32 on the wire
        out.append(state[0].copy())
        held = float(seen[8]) if held is None else held
        heading = heading_within_reach(float(seen[8]), held)
        cmd = policy.act(build_observation(seen[None], TARGET, heading=heading)[0])
        state, rotor = dynamics.step(state, rotor, cmd[None].astype(np.float64), params, 0.01)
    return np.array(out)


def test_sitl_follows_the_in_process_trajectory():
    log, monitor = fly_sitl(START)
    assert log.failsafe is None and log.steps == STEPS
    sitl = np.array(log.states)[:, 0:3]
    # every command sent was finite and in [0, 1], and the policy flew every step
    cmds = np.array(log.commands)
    assert np.all(np.isfinite(cmds)) and np.all((cmds >= 0) & (cmds <= 1))
    assert set(log.sources) == {"policy"} and not monitor.events
    same_wire = fly_in_process(START)[:, 0:3]
    # what the node saw went through the same integer encoding: identical up to float rounding
    # (the node's positions are the decoded ones, hence the quantum as the comparison floor)
    quantum = np.array(wire.Home().position_quantum_m) / 2 + 1e-9
    assert np.all(np.abs(sitl - same_wire) <= quantum), np.abs(sitl - same_wire).max(axis=0)
    exact = fly_in_process(START, through_wire=False)[:, 0:3]
    dev = np.abs(sitl - exact).max()
    # Bound: quantisation noise (≤ 0.56 cm position, 0.5 cm/s velocity) through the closed loop.
    # Measured 2026-11 on this policy and start: see the assertion message if it moves.
    assert dev <= 0.02, f"SITL left the exact-state trajectory by {dev * 100:.2f} cm"
    final = np.linalg.norm(sitl[-1] - TARGET)
    assert final < 0.05


def test_quad_sitl_command_flies_and_summarises(tmp_path, capsys):
    out = tmp_path / "summary.json"
    assert main(["--episodes", "2", "--duration", "4", "--seed", "3", "--json", str(out), "--min-success", "1"]) == 0
    text = capsys.readouterr().out
    assert "success rate" in text and "control-loop latency" in text
    s = json.loads(out.read_text())
    assert s["episodes"] == 2 and s["steps"] == 800 and s["crashes"] == 0
    assert s["success_rate"] == 1.0 and s["failsafe_events"] == 0
    assert s["control_latency_p99_us"] < 5_000 and s["steps_per_s"] > 200


@pytest.mark.parametrize(("task", "episodes"), [("waypoint", 3), ("circle", 1)])
def test_quad_sitl_flies_the_waypoint_and_circle_policies(task, episodes, tmp_path, capsys):
    """The shipped waypoint and circle files fly their task in SITL: the simulator starts each
    episode where core.mission puts it, the node draws the same target (waypoint) or moves it
    round the circle, and success is judged as the training evaluation judges it."""
    out, plot = tmp_path / f"{task}.json", tmp_path / f"{task}.png"
    policy = str(SHIPPED_HOVER.parents[1] / task / "policy.onnx")
    flags = ["--gcs", "none", "--json", str(out), "--plot", str(plot), "--min-success", "1"]
    assert main([policy, "--episodes", str(episodes), *flags]) == 0
    s = json.loads(out.read_text())
    print(task, {k: s[k] for k in ("success_rate", "mean_error_last_2s_m", "steps_per_s")}, s.get("radial_rms_m"))
    assert s["task"] == task and s["success_rate"] == 1.0 and s["crashes"] == 0
    if task == "circle":
        assert s["steps"] == 1257 and s["radial_rms_m"] < 0.05 and s["speed_error_mps"] < 0.1
    assert plot.stat().st_size > 10_000
    capsys.readouterr()
    if task == "circle":  # a circle policy observes the target's velocity too: it cannot fly hover
        assert main([policy, "--task", "hover", "--episodes", "1", "--gcs", "none"]) == 2
        err = capsys.readouterr().err
        assert "--task hover needs a hover-layout policy" in err and err.count("\n") == 1


def test_quad_sitl_refuses_a_bad_policy_file(tmp_path, capsys):
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"\x00" * 100)
    assert main([str(bad), "--episodes", "1"]) == 1  # a file that exists but is not a policy: exit 1 (a bad flag is 2)
    err = capsys.readouterr().err
    assert "bad.onnx" in err and "Traceback" not in err


def test_min_success_fails_a_flight_below_the_bar_and_passes_one_above(tmp_path, capsys):
    """--min-success turns the flown success rate into the exit code: the nominal hover policy on a
    plant 30 % heavier with 20 % weaker motors sags far below its target (0 % success), so the
    same command that exits 0 on the nominal plant exits 1, with one line saying why."""
    base = ["--episodes", "2", "--duration", "3", "--gcs", "none", "--min-success", "0.95"]
    assert main(base) == 0
    capsys.readouterr()
    assert main([*base, "--mass-scale", "1.3", "--motor-scale", "0.8"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["quad-sitl: success rate 0% of 2 episodes is below --min-success 0.95"]
    assert main([*base[:-1], "1.5"]) == 2  # a fraction, not a percentage
    assert "--min-success" in capsys.readouterr().err


def test_quad_sitl_passes_perturbations_to_the_simulator(tmp_path, capsys):
    """A heavier vehicle with weaker motors sags below the target: the flags reached the plant (the
    nominal hover policy has no integral action; domain randomisation is docs/robustness.md's subject)."""
    out = tmp_path / "heavy.json"
    assert (
        main(
            ["--episodes", "1", "--duration", "4", "--mass-scale", "1.15", "--motor-scale", "0.92", "--json", str(out)]
        )
        == 0
    )
    heavy = json.loads(out.read_text())
    assert heavy["mean_error_last_2s_m"] > 0.08, heavy
    assert main(["--wind", "1,2"]) == 2
    assert "three comma-separated numbers" in capsys.readouterr().err


@pytest.mark.parametrize("fault", ["kill", "freeze"])
def test_losing_the_simulator_mid_flight_latches_the_failsafe_within_150_ms(fault):
    """The simulator process is killed (SIGKILL: the kernel closes its socket, the node sees the
    link close) or frozen (SIGSTOP: the socket stays open and simply falls silent, the node notices
    on its monotonic clock after 100 ms) while the node flies in real time; either way the node
    latches the failsafe (motors off) within 150 ms."""
    import signal
    import socket
    import subprocess
    import sys
    import time

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    sim = subprocess.Popen(
        [sys.executable, "-m", "quadpilot.simulator", "--listen", f"tcp:127.0.0.1:{port}", "--realtime"],
        stdout=subprocess.DEVNULL,
    )
    try:
        hit = sim.kill if fault == "kill" else lambda: sim.send_signal(signal.SIGSTOP)
        killer = threading.Timer(1.5, hit)  # ~1 s after start-up: mid-flight
        killer.start()
        node = Node(NodeConfig(connect=f"tcp:127.0.0.1:{port}", duration_s=10.0, lockstep=False, connect_timeout_s=10))
        t0 = time.monotonic()
        log = node.fly(SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy")))
        assert time.monotonic() - t0 < 5.0
    finally:
        sim.kill()
        sim.wait(5)
    assert 0 < log.steps < 1000, log.steps
    print(f"{fault}: failsafe '{log.failsafe}' {log.failsafe_latency_s * 1000:.1f} ms after the last state")
    if fault == "freeze":
        assert log.failsafe == "state stream silent"
        assert 0.1 <= log.failsafe_latency_s <= 0.15, log.failsafe_latency_s
    else:
        assert log.failsafe in ("simulator closed the link", "state stream silent")
        assert log.failsafe_latency_s <= 0.15, log.failsafe_latency_s
    cmds = np.array(log.commands)
    assert np.all(np.isfinite(cmds)) and np.all((cmds >= 0) & (cmds <= 1))
