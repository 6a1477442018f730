"""Faults a flight meets, flown against our own simulator process (`quadpilot.simulator`), in
lockstep: bad states (a zero quaternion, spoiled in flight by `state_faults.StateFaultProxy`) are
flown blind and the policy gets the vehicle back (`runtime.safety`: hand-over, hand-back); and a
simulator that stalls for 2 s mid-flight is waited for, because in lockstep time is the simulator's
(`autopilot.node`). Each flight is `quad-sitl --node-only`'s: it must exit 0, and its --trace must meet
the hover rule (`core.mission.judge`, the training evaluation's)."""

import csv
import itertools
import json
import os
import signal
import subprocess
import sys
import threading

import numpy as np
import pytest
from state_faults import StateFaultProxy

from quadpilot.autopilot.node import Node, NodeConfig
from quadpilot.core.mission import judge
from quadpilot.link.frames import Home
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.sitl import SHIPPED_HOVER, main
from quadpilot.sitl.simulator_process import start_simulator

pytestmark = pytest.mark.sitl
H = Home()
HOME = f"{H.lat_deg},{H.lon_deg},{H.alt_m}"  # our simulator's: the node's frame is the simulator's
HIL_STATE_QUATERNION = 115  # its MAVLink message id
DURATION_S = 5.0  # the hover episode: the rule judges its last 2 s
STEPS = 500


@pytest.fixture
def simulator(tmp_path):
    stats = tmp_path / "sim.json"
    cmd = [sys.executable, "-m", "quadpilot.simulator", "--sim-only", "--listen", "tcp:127.0.0.1:0"]
    proc, address = start_simulator([*cmd, "--episodes", "1", "--json", str(stats)])
    assert proc is not None, address
    yield proc, int(address.rsplit(":", 1)[1]), stats
    stop(proc)


def stop(proc) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGCONT)  # in case a test left it stopped
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def fly_node_only(port: int, tmp_path, capsys) -> tuple[int, dict, dict, str]:
    """quad-sitl --node-only against tcp:127.0.0.1:port: exit code, --json summary, the hover rule's
    verdict on the --trace, and what it printed."""
    out, trace = tmp_path / "summary.json", tmp_path / "trace.csv"
    code = main(
        [
            *(str(SHIPPED_HOVER), "--node-only", "--connect", f"tcp:127.0.0.1:{port}", "--gcs", "none"),
            *("--home", HOME, "--target", "0,0,2", "--duration", str(DURATION_S)),
            *("--json", str(out), "--trace", str(trace)),
        ]
    )
    printed = capsys.readouterr()
    s = json.loads(out.read_text())
    with open(trace, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    cols = ["x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps", "roll_rad", "pitch_rad", "yaw_rad"]
    states = np.array([[float(r[c]) for c in [*cols, "p_radps", "q_radps", "r_radps"]] for r in rows])
    targets = np.array([[float(r[c]) for c in ("target_x_m", "target_y_m", "target_z_m")] for r in rows])
    verdict = judge("hover", states, targets, s["step_s"])
    return code, s, verdict, printed.out + printed.err


@pytest.mark.parametrize(
    ("name", "bad_steps"),
    [
        ("one bad state", [150]),
        ("a burst of ten", range(150, 160)),
        ("one in every fifty", range(25, STEPS, 50)),
    ],
)
def test_bad_states_are_flown_blind_and_the_policy_flies_again(simulator, tmp_path, capsys, name, bad_steps):
    _, sim_port, _ = simulator
    bad = list(bad_steps)
    proxy = StateFaultProxy(sim_port, bad)
    code, s, verdict, printed = fly_node_only(proxy.port, tmp_path, capsys)
    proxy.join()
    print(f"{name}: {printed.strip()}")
    assert proxy.spoiled == len(bad)
    assert code == 0, printed
    assert s["failsafe"] is None and s["packets_dropped"] == {"state_quaternion_not_unit": len(bad)}
    # one hand-over per run of bad states, each handed back (the last one too: a whole hold fits after it)
    runs = 1 + sum(1 for a, b in itertools.pairwise(bad) if b != a + 1)
    assert s["hand_overs"] == runs and s["hand_backs"] == runs and not s["latched"], s["handovers"]
    assert [h[1] for h in s["handovers"]] == ["hand-over", "hand-back"] * runs
    assert s["fallback_reasons"] == {"state_dropped": len(bad)}
    hold = round(0.2 / s["step_s"])
    assert s["recovering_steps"] == runs * hold
    assert s["fallback_steps"] == len(bad) + runs * hold
    assert verdict["success"], verdict  # the hover rule, on the simulator's ground truth


def test_before_the_hand_back_one_bad_state_latched_the_fallback(simulator, tmp_path, capsys, monkeypatch):
    """The same single bad state with the hand-back switched off (a hold longer than the flight): the
    fallback keeps the vehicle to the end and the run fails, as it did before the hand-back. This is
    what the test above guards."""
    from quadpilot.runtime import safety

    monkeypatch.setattr(safety, "HAND_BACK_HOLD_S", 1e9)
    _, sim_port, _ = simulator
    proxy = StateFaultProxy(sim_port, [150])
    code, s, _, printed = fly_node_only(proxy.port, tmp_path, capsys)
    proxy.join()
    assert code == 1 and s["hand_backs"] == 0 and s["policy_fraction"] < 0.5, printed


@pytest.mark.parametrize("via", ["quad-sitl --node-only", "Node over UDP"])
def test_a_simulator_stalled_for_two_seconds_in_lockstep_is_waited_for(tmp_path, capsys, via):
    """The simulator process is stopped (SIGSTOP) for 2 s after 200 steps and continued: in lockstep
    nothing happens to the vehicle meanwhile, so the node waits and the flight completes, exit 0, and
    meets the hover rule. (Before: 'state stream silent' after 1 s of host time with quad-sitl, 0.1 s with
    NodeConfig's default, and the flight failed.)"""
    proto = "tcp" if via.startswith("quad-sitl") else "udp"
    cmd = [sys.executable, "-m", "quadpilot.simulator", "--sim-only", "--listen", f"{proto}:127.0.0.1:0"]
    proc, address = start_simulator([*cmd, "--episodes", "1", "--lockstep-timeout", "30"])
    assert proc is not None, address
    port = int(address.rsplit(":", 1)[1])
    stalled = threading.Event()

    def stall() -> None:
        os.kill(proc.pid, signal.SIGSTOP)
        stalled.wait(2.0)  # 2 s, unless the test is already over
        os.kill(proc.pid, signal.SIGCONT)

    staller = None

    def on_state(k: int) -> None:
        nonlocal staller
        if k == 200:
            staller = threading.Thread(target=stall, daemon=True)
            staller.start()

    try:
        if proto == "tcp":
            proxy = StateFaultProxy(port, (), on_state)
            code, s, verdict, printed = fly_node_only(proxy.port, tmp_path, capsys)
            proxy.join()
            assert code == 0, printed
            wall = s["wall_s"]
        else:
            seen = [0]

            def tap(direction: str, raw: bytes) -> None:  # every message in, one at a time
                if direction == "in" and raw[0] == 0xFD and int.from_bytes(raw[7:10], "little") == HIL_STATE_QUATERNION:
                    on_state(seen[0])
                    seen[0] += 1

            cfg = NodeConfig(connect=address, duration_s=DURATION_S, gcs=None)
            log = Node(cfg).fly(SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy")), tap=tap)
            assert log.failsafe is None, log.failsafe
            verdict = judge("hover", np.asarray(log.states), np.asarray(log.targets), log.step_s)
            wall = log.wall_s
    finally:
        stalled.set()
        if staller is not None:
            staller.join(5)
        stop(proc)
    assert staller is not None, "the flight never reached step 200"
    assert wall >= 2.0, "the simulator was not stopped for 2 s during the flight"
    assert verdict["success"], verdict


def test_valid_states_that_stop_in_lockstep_end_the_flight_on_simulated_time(simulator, tmp_path, capsys):
    """From step 100 on every state is bad: in lockstep the node does not wait on the host's clock;
    `link_timeout_s` of simulated time after the last valid state (quad-sitl's `LINK_TIMEOUT_S`, 1 s)
    is the failsafe, in one line, exit 1."""
    _, sim_port, _ = simulator
    proxy = StateFaultProxy(sim_port, range(100, STEPS))
    code, s, _, printed = fly_node_only(proxy.port, tmp_path, capsys)
    proxy.join()
    assert code == 1 and s["failsafe"] == "no valid state", (s["steps"], printed)
    # steps 0-99 valid, 100-199 flown blind; state 200 is 1.01 s after state 99: the failsafe
    assert s["steps"] == 200 and s["packets_dropped"]["state_quaternion_not_unit"] == 100
    assert printed.splitlines()[-1] == "quad-sitl: the flight ended early after 200 steps: failsafe: no valid state"


def test_a_simulator_killed_in_lockstep_ends_the_flight_at_once_in_one_line(simulator, tmp_path, capsys):
    proc, sim_port, _ = simulator
    proxy = StateFaultProxy(sim_port, (), lambda k: k == 200 and proc.kill())
    code, s, _, printed = fly_node_only(proxy.port, tmp_path, capsys)
    proxy.join()
    assert code == 1 and s["failsafe"] == "simulator closed the link"
    assert printed.splitlines()[-1].startswith("quad-sitl: the flight ended early after ")


def test_each_hand_over_and_hand_back_is_a_statustext_and_in_the_flight_log(simulator):
    """A ground station listening where the node sends telemetry hears both changes of who flies,
    and the flight log holds them with their simulated time."""
    import socket

    from pymavlink.dialects.v20 import common as mavlink2

    _, sim_port, _ = simulator
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.5)
    proxy = StateFaultProxy(sim_port, [150])
    cfg = NodeConfig(connect=f"tcp:127.0.0.1:{proxy.port}", duration_s=3.0, gcs=f"udp:127.0.0.1:{gcs.getsockname()[1]}")
    log = Node(cfg).fly(SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy")))
    proxy.join()
    parser, texts = mavlink2.MAVLink(None), []
    try:
        while data := gcs.recv(65536):
            texts += [m.text for m in parser.parse_buffer(data) or [] if m.get_type() == "STATUSTEXT"]
    except TimeoutError:
        pass
    finally:
        gcs.close()
    assert texts == ["safety: fallback flying (state_dropped)", "safety: policy flying (0.2 s in recovery envelope)"]
    (over_t, over, _), (back_t, back, _) = log.handovers
    assert (over, back) == ("hand-over", "hand-back") and over_t - log.t[0] == pytest.approx(1.5)  # state 150
    assert back_t - over_t == pytest.approx(0.01 + 0.2)  # the blind step, then the 0.2 s hold
