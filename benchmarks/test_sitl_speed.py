"""SITL closed-loop speed and real-time loop timing, each with its baseline in the same run.

Lockstep (the simulator advances one step per actuator message, as fast as the two processes go):
the shipped hover ONNX file flown by the node (this process) against the simulator (its own
process, `python -m quadpilot.firmware_sim`) over loopback TCP, one 20 s episode (2,000 control
steps) per round, on each runtime backend. Baselines in the same run: real time (100 steps/s at
the 100 Hz control rate) and the same policy stepping `core.dynamics` in this process with no wire
at all (what the two processes and MAVLink cost).

Real time at 100 Hz and 250 Hz: one 5 s flight per rate; the loop period jitter is |period − dt|
between consecutive HIL_SENSOR arrivals at the node (what the control loop sees) and between
consecutive simulator steps; p50/p99/max go into `extra_info`. At 250 Hz the 100 Hz policy is flown
at 4 ms steps: this is a timing measurement, not a flight-quality one.

    .venv/bin/python -m pytest benchmarks/test_sitl_speed.py --benchmark-enable --benchmark-only \\
        --benchmark-json=docs/bench/sitl_speed.json -p no:cacheprovider
    .venv/bin/python benchmarks/report_sitl.py docs/bench/sitl_speed.json

Without --benchmark-enable each case runs once, a smoke test.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest

from quadpilot.core import dynamics
from quadpilot.core.observation import build_observation
from quadpilot.core.params import ParamBatch, get_preset
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.runtime.node import Node, NodeConfig
from quadpilot.sitl import SHIPPED_HOVER, _start_simulator

LOCKSTEP_S = 20.0
REALTIME_S = 5.0


def _simulator(*flags):
    cmd = [sys.executable, "-m", "quadpilot.firmware_sim", "--sim-only", "--listen", "tcp:127.0.0.1:0", *flags]
    proc, address = _start_simulator(cmd)
    assert proc is not None, address
    return proc, address


def _stop(proc, stats=None):
    proc.terminate()
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        proc.kill()


@pytest.mark.parametrize("backend", ["numpy", "onnxruntime"])
def test_lockstep_closed_loop(benchmark, backend):
    proc, address = _simulator("--max-steps", str(round(LOCKSTEP_S * 100) + 10))
    try:
        monitor = SafetyMonitor(load_policy(SHIPPED_HOVER, backend))
        node = Node(NodeConfig(connect=address, duration_s=LOCKSTEP_S, gcs=None))
        logs = []
        node.fly(monitor)  # warm-up episode
        benchmark.pedantic(lambda: logs.append(node.fly(monitor)), rounds=5, iterations=1)
    finally:
        _stop(proc)
    steps = logs[-1].steps
    assert steps == round(LOCKSTEP_S * 100) and all(log.failsafe is None for log in logs)
    lat = np.concatenate([log.latency_s for log in logs]) * 1e6
    benchmark.extra_info.update(
        steps_per_round=steps,
        node_latency_p50_us=float(np.percentile(lat, 50)),
        node_latency_p99_us=float(np.percentile(lat, 99)),
    )


def test_in_process_baseline(benchmark):
    """The same policy and dynamics with no processes and no wire: the monitor acts on the
    observation of the exact state, `core.dynamics.step` advances one drone."""
    monitor = SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy"))
    p = get_preset("seed")
    params = ParamBatch.from_preset(p, 1)
    target = np.array([0.0, 0.0, 2.0])
    start = np.array([[0.6, -0.4, 2.5, 0.3, -0.2, 0.1, 0.2, -0.15, 2.0, 0.0, 0.0, 0.0]])

    def fly():
        monitor.reset()
        state, rotor = start.copy(), np.full((1, 4), p.hover_command)
        for _ in range(round(LOCKSTEP_S * 100)):
            cmd = monitor.act(build_observation(state, target, heading=start[0, 8])[0])  # its start heading
            state, rotor = dynamics.step(state, rotor, cmd[None].astype(np.float64), params)
        return state

    final = benchmark.pedantic(fly, rounds=5, iterations=1, warmup_rounds=1)
    assert np.linalg.norm(final[0, 0:3] - target) < 0.05
    benchmark.extra_info.update(steps_per_round=round(LOCKSTEP_S * 100))


@pytest.mark.parametrize("rate_hz", [100, 250])
def test_realtime_loop_jitter(benchmark, rate_hz, tmp_path):
    stats = tmp_path / "sim.json"
    proc, address = _simulator("--realtime", "--rate", str(rate_hz), "--episodes", "1", "--json", str(stats))
    dt = 1.0 / rate_hz
    try:
        monitor = SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy"))
        node = Node(NodeConfig(connect=address, duration_s=REALTIME_S, lockstep=False, gcs=None, control_period_s=dt))
        log = benchmark.pedantic(lambda: node.fly(monitor), rounds=1, iterations=1)
        proc.wait(10)  # the simulator ends its episode when the node stops (TCP close) and exits
    finally:
        _stop(proc)
    assert log.failsafe is None and log.steps == round(REALTIME_S * rate_hz)
    skip = round(0.2 / dt)  # start-up: connection, first inference
    dev = np.abs(np.diff(np.asarray(log.wall))[skip:] - dt) * 1e3
    record = json.loads(stats.read_text())["records"][0]
    p50, p99, mx = record["period_jitter_ms"]
    benchmark.extra_info.update(
        rate_hz=rate_hz,
        steps=log.steps,
        node_jitter_p50_ms=float(np.percentile(dev, 50)),
        node_jitter_p99_ms=float(np.percentile(dev, 99)),
        node_jitter_max_ms=float(dev.max()),
        sim_jitter_p50_ms=p50,
        sim_jitter_p99_ms=p99,
        sim_jitter_max_ms=mx,
        sim_overruns=record["overruns"],
        node_latency_p99_us=float(np.percentile(log.latency_s, 99) * 1e6),
    )
    time.sleep(0.1)
