"""SITL closed-loop speed and real-time loop timing, each with its baseline in the same run.

Lockstep (the simulator advances one step per actuator message, as fast as the two processes go):
the shipped hover ONNX file flown by the node (this process) against the simulator (its own
process, `python -m quadpilot.simulator`) over loopback TCP, one 20 s episode (2,000 control
steps) per round, on each runtime backend. Baselines in the same run: real time (100 steps/s at
the 100 Hz control rate) and the same policy stepping `core.dynamics` in this process with no wire
at all (what the two processes and MAVLink cost).

Against commit bb5efb7 (`test_lockstep_vs_baseline`): that commit's node flying against that
commit's simulator, and today's against today's, each in a child process of its own (the node
there, its simulator a grandchild: `python -m quadpilot.sitl --sim-only` of the same source, by
`baseline.py`'s PYTHONPATH rule), one 20 s episode (2,000 steps) per round, rounds alternating
between them so that the load of a shared machine falls on all alike. A third child flies today's
code with the lockstep spin off on both sides (`transport.Link.spin_s`): what the spin adds. Each
is run on an otherwise idle machine ("idle") and with one more process keeping a CPU busy
("busy"), where a spinning side competes with its peer for what is left. All fly one file:
bb5efb7's own models/hover/policy.onnx (`git show bb5efb7:models/hover/policy.onnx`), because
bb5efb7's runtime refuses today's shipped hover policy (its observation layout quadpilot.obs.hover/2
came later) and today's runtime still flies the old one. Each child times its own rounds; the
benchmark's statistics are today's rounds as this process sees them, and `extra_info` holds every
child's round times, their steps/s, the ratios and the load average around the run.

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
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from baseline import BASELINE_COMMIT, REPO, BaselineUnavailable, baseline_src
from quadpilot.autopilot.node import Node, NodeConfig
from quadpilot.core import dynamics
from quadpilot.core.observation import build_observation
from quadpilot.core.params import ParamBatch
from quadpilot.core.vehicle_file import get_preset
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.sitl import SHIPPED_HOVER
from quadpilot.sitl.simulator_process import start_simulator

LOCKSTEP_S = 20.0
REALTIME_S = 5.0


def _simulator(*flags):
    cmd = [sys.executable, "-m", "quadpilot.simulator", "--sim-only", "--listen", "tcp:127.0.0.1:0", *flags]
    proc, address = start_simulator(cmd)
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


# One child per version: flies `steps` lockstep steps per "fly" line read from stdin against its own
# simulator process and answers with one JSON line. Only names both versions have: the simulator
# process as `python -m quadpilot.sitl --sim-only` starts it, the function that starts it
# (bb5efb7's quadpilot.sitl._start_simulator, today's quadpilot.sitl.simulator_process), the node
# (autopilot.node; runtime.node before it), SafetyMonitor, load_policy.
FLYER = r"""
import json, sys, time
import numpy as np
from quadpilot.runtime import SafetyMonitor, load_policy
try:
    from quadpilot.autopilot.node import Node, NodeConfig
except ImportError:  # a baseline from before the vehicle stack had its own package
    from quadpilot.runtime.node import Node, NodeConfig
try:
    from quadpilot.sitl.simulator_process import start_simulator
except ImportError:  # a baseline from before quad-sitl was a package
    from quadpilot.sitl import _start_simulator as start_simulator

policy, backend, duration = sys.argv[1], sys.argv[2], float(sys.argv[3])
no_spin = sys.argv[4:] == ["no-spin"]  # today's only: both sides sleep at once, as before the spin
steps = round(duration * 100)
cmd = [sys.executable, "-m", "quadpilot.sitl", "--sim-only", "--listen", "tcp:127.0.0.1:0"]
proc, address = start_simulator(cmd + ["--max-steps", str(steps + 10)] + (["--spin-us=0"] if no_spin else []))
if proc is None:
    raise SystemExit(f"simulator did not start: {address}")
monitor = SafetyMonitor(load_policy(policy, backend))
node = Node(NodeConfig(connect=address, duration_s=duration, gcs=None, **({"spin_s": 0.0} if no_spin else {})))
print("ready", flush=True)
try:
    for line in sys.stdin:
        if line.strip() != "fly":
            break
        t0 = time.perf_counter()
        log = node.fly(monitor)
        wall = time.perf_counter() - t0
        lat = np.asarray(log.latency_s) * 1e6
        print(json.dumps({"steps": log.steps, "wall_s": wall, "failsafe": log.failsafe,
                          "latency_p50_us": float(np.percentile(lat, 50)) if lat.size else None}), flush=True)
finally:
    proc.terminate()
    proc.wait(5)
"""


class _Flyer:
    """A FLYER child on `src` (None: today's installed package), flying `policy`."""

    def __init__(self, src: Path | None, policy: Path, backend: str, duration_s: float, *flags: str) -> None:
        env = dict(os.environ)
        if src is not None:  # baseline.run_python's rule: the baseline's source first on the import path
            env["PYTHONPATH"] = os.pathsep.join([str(src), *filter(None, [env.get("PYTHONPATH")])])
        self.proc = subprocess.Popen(
            [sys.executable, "-c", FLYER, str(policy), backend, str(duration_s), *flags],
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        line = self.proc.stdout.readline().strip()
        assert line == "ready", f"flyer on {src or 'today'} did not start: {line!r}"
        self.rounds: list[dict] = []

    def fly(self) -> dict:
        self.proc.stdin.write("fly\n")
        self.proc.stdin.flush()
        out = json.loads(self.proc.stdout.readline())
        assert out["failsafe"] is None, out
        self.rounds.append(out)
        return out

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write("quit\n")
                self.proc.stdin.close()
                self.proc.wait(10)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()

    def steps_per_s(self, rounds: list[dict]) -> float:
        return sum(r["steps"] for r in rounds) / sum(r["wall_s"] for r in rounds)


@pytest.fixture(scope="module")
def baseline_policy(tmp_path_factory) -> Path:
    """bb5efb7's shipped hover policy, which both versions can fly (see the module docstring)."""
    out = tmp_path_factory.mktemp("baseline") / "hover_policy.onnx"
    try:
        data = subprocess.run(
            ["git", "-C", str(REPO), "show", f"{BASELINE_COMMIT}:models/hover/policy.onnx"],
            capture_output=True,
            check=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError) as e:
        pytest.skip(f"no {BASELINE_COMMIT} in this checkout's history: {e}")
    out.write_bytes(data)
    return out


BUSY = "import time\nend = time.monotonic() + 600\nwhile time.monotonic() < end:\n    pass\n"
"""A process that keeps one CPU busy (at most 10 minutes): the load of `load="busy"`."""


@pytest.mark.parametrize("load", ["idle", "busy"])
def test_lockstep_vs_baseline(benchmark, load, baseline_policy):
    """Lockstep steps/s of today's node and simulator against bb5efb7's, side by side, alternating;
    with them, today's with the lockstep spin off (`--spin-us 0`, `NodeConfig.spin_s=0`). "busy":
    another process keeps one of the CPUs busy throughout, so the spinning side and its peer share
    what is left."""
    try:
        src = baseline_src()
    except BaselineUnavailable as e:
        pytest.skip(str(e))
    backend = "numpy"
    hog = subprocess.Popen([sys.executable, "-c", BUSY]) if load == "busy" else None
    flyers = []
    try:
        load_avg = [os.getloadavg()]
        old = _Flyer(src, baseline_policy, backend, LOCKSTEP_S)
        flyers.append(old)
        new = _Flyer(None, baseline_policy, backend, LOCKSTEP_S)
        flyers.append(new)
        still = _Flyer(None, baseline_policy, backend, LOCKSTEP_S, "no-spin")
        flyers.append(still)
        warm = 0 if benchmark.disabled else 1
        for _ in range(warm):  # one round each first: imports, caches, the simulator's first episode
            for f in flyers:
                f.fly()
        for f in flyers:
            f.rounds.clear()
        # the other two rounds run as the (untimed) setup of each of today's rounds: they alternate
        benchmark.pedantic(new.fly, setup=lambda: (old.fly(), still.fly()) and None, rounds=5, iterations=1)
    finally:
        for f in flyers:
            f.close()
        if hog is not None:
            hog.kill()
            hog.wait()
    load_avg.append(os.getloadavg())
    steps = round(LOCKSTEP_S * 100)
    assert all(r["steps"] == steps for f in flyers for r in f.rounds)
    rate_old, rate_new, rate_still = (f.steps_per_s(f.rounds) for f in flyers)
    benchmark.extra_info.update(
        load=load,
        baseline_commit=BASELINE_COMMIT,
        policy=f"{BASELINE_COMMIT}:models/hover/policy.onnx",
        backend=backend,
        steps_per_round=steps,
        baseline_round_s=[r["wall_s"] for r in old.rounds],
        today_round_s=[r["wall_s"] for r in new.rounds],
        today_no_spin_round_s=[r["wall_s"] for r in still.rounds],
        baseline_steps_per_s=rate_old,
        today_steps_per_s=rate_new,
        today_no_spin_steps_per_s=rate_still,
        vs_baseline=rate_new / rate_old,
        no_spin_vs_baseline=rate_still / rate_old,
        baseline_latency_p50_us=old.rounds[-1]["latency_p50_us"],
        today_latency_p50_us=new.rounds[-1]["latency_p50_us"],
        today_no_spin_latency_p50_us=still.rounds[-1]["latency_p50_us"],
        load_average_1_5_15=[list(x) for x in load_avg],
    )


ECHO = r"""
import socket, sys, select
poll = sys.argv[2] == "poll"
s = socket.create_connection(("127.0.0.1", int(sys.argv[1])))
s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
s.setblocking(False)
while True:
    if not poll:
        select.select([s], [], [])
    try:
        data = s.recv(4096)
    except BlockingIOError:
        continue
    if not data:
        break
    s.send(b"a" * 60)
"""
"""The other side of `test_tcp_round_trip`: answers each read with 60 bytes (about one
HIL_ACTUATOR_CONTROLS), sleeping in select or polling the socket between messages."""
ROUND_TRIPS = 5000


@pytest.mark.parametrize("wait", ["sleep", "poll"])
def test_tcp_round_trip(benchmark, wait):
    """What the lockstep spin is for: a plain TCP ping-pong between two processes on loopback, 200
    bytes out (about one step's messages) and 60 back, both sides sleeping in select between
    messages, or both polling. No MAVLink, no policy: the cost of the handover alone."""
    import select
    import socket

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    child = subprocess.Popen([sys.executable, "-c", ECHO, str(server.getsockname()[1]), wait])
    conn, _ = server.accept()
    server.close()
    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    conn.setblocking(False)
    poll = wait == "poll"

    def trips():
        for _ in range(ROUND_TRIPS):
            conn.send(b"s" * 200)
            got = 0
            while got < 60:
                if not poll:
                    select.select([conn], [], [], 5.0)
                try:
                    got += len(conn.recv(4096))
                except BlockingIOError:
                    pass

    try:
        rounds = 5 if not benchmark.disabled else 1
        benchmark.pedantic(trips, rounds=rounds, iterations=1, warmup_rounds=1 if rounds > 1 else 0)
    finally:
        conn.close()
        child.wait(10)
    benchmark.extra_info.update(
        round_trips_per_round=ROUND_TRIPS,
        round_trip_us=benchmark.stats.stats.min / ROUND_TRIPS * 1e6 if benchmark.stats else None,
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
