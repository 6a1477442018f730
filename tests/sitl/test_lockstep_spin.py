"""In lockstep both sides of the simulator link poll before they sleep (`spin.LOCKSTEP_SPIN_S`,
or the configured `spin_s`; 0 turns it off), and in realtime neither does: the node and the
simulator each set their link's window from their config. The flight itself is the same either way
(tests/sitl/test_lockstep_identity.py pins its bytes)."""

from __future__ import annotations

import threading

import pytest

from quadpilot.autopilot.node import NODE_SYSTEM_ID, Node, NodeConfig
from quadpilot.link import spin, transport
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.simulator import SimConfig, Simulator
from quadpilot.sitl import SHIPPED_HOVER


def _fly(monkeypatch, lockstep: bool, sim_spin: float | None, node_spin: float | None, cpus=(0, 1)) -> dict:
    """The windows each side's waits had during the flight's 20 steps (the simulator's wait for the
    node's first HEARTBEAT, before its steps, is a plain wait)."""
    windows: dict[int, list] = {}
    real_recv = transport.Link.recv

    def recording(self, timeout=0.0):
        if timeout > 0:
            windows.setdefault(self.system, []).append(self.spin_s)
        return real_recv(self, timeout)

    monkeypatch.setattr(transport.Link, "recv", recording)
    monkeypatch.setattr(spin.os, "sched_getaffinity", lambda pid: set(cpus), raising=False)  # not this machine's
    sim_kw = {} if sim_spin is None else {"spin_s": sim_spin}
    sim = Simulator(SimConfig(listen="tcp:127.0.0.1:0", episodes=1, lockstep=lockstep, **sim_kw))
    port = sim.bind().port
    thread = threading.Thread(target=sim.serve, daemon=True)
    thread.start()
    try:
        node_kw = {} if node_spin is None else {"spin_s": node_spin}
        cfg = NodeConfig(connect=f"tcp:127.0.0.1:{port}", duration_s=0.2, lockstep=lockstep, gcs=None, **node_kw)
        log = Node(cfg).fly(SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy")))
        assert log.failsafe is None
    finally:
        sim.stop()
        thread.join(5.0)
    return {"node": set(windows[NODE_SYSTEM_ID]), "simulator": set(windows[transport.SIM_SYSTEM_ID][-15:])}


def test_both_sides_poll_in_lockstep(monkeypatch):
    w = _fly(monkeypatch, True, None, None)
    assert w == {"node": {spin.LOCKSTEP_SPIN_S}, "simulator": {spin.LOCKSTEP_SPIN_S}}


def test_the_configured_window_is_used_and_zero_turns_it_off(monkeypatch):
    assert _fly(monkeypatch, True, 0.0, 0.002) == {"node": {0.002}, "simulator": {0.0}}


def test_neither_side_polls_with_one_usable_cpu(monkeypatch):
    assert _fly(monkeypatch, True, None, None, cpus=(0,)) == {"node": {0.0}, "simulator": {0.0}}


def test_neither_side_polls_in_realtime(monkeypatch):
    w = _fly(monkeypatch, False, None, None)
    assert w == {"node": {0.0}, "simulator": {0.0}}


@pytest.mark.parametrize("bad", [float("nan"), -1.0, 2.0, 10**400, True, "x", None])
def test_a_bad_window_is_refused_in_one_line(bad):
    for config in (NodeConfig, SimConfig):
        with pytest.raises(ValueError, match="spin_s must be a number of seconds from 0 to 1"):
            config(spin_s=bad)


def _node_windows(monkeypatch) -> set:
    """The windows of the node's waits from here on (two usable CPUs, whatever this machine has)."""
    windows = set()
    real_recv = transport.Link.recv

    def recording(self, timeout=0.0):
        if timeout > 0 and self.system == NODE_SYSTEM_ID:
            windows.add(self.spin_s)
        return real_recv(self, timeout)

    monkeypatch.setattr(transport.Link, "recv", recording)
    monkeypatch.setattr(spin.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    return windows


def test_spin_us_sets_both_sides_windows(monkeypatch, tmp_path):
    from quadpilot import sitl
    from quadpilot.simulator import build_sim_parser, config_from_args
    from quadpilot.sitl import simulator_process

    assert config_from_args(build_sim_parser().parse_args(["--spin-us", "250"])).spin_s == pytest.approx(250e-6)
    assert config_from_args(build_sim_parser().parse_args([])).spin_s == spin.LOCKSTEP_SPIN_S
    commands = []
    real_simulator = simulator_process.SimulatorProcess
    monkeypatch.setattr(simulator_process, "SimulatorProcess", lambda cmd: commands.append(cmd) or real_simulator(cmd))
    windows = _node_windows(monkeypatch)
    fly = ["--episodes", "1", "--duration", "0.2", "--gcs", "none", "--json", str(tmp_path / "s.json")]
    assert sitl.main(["--spin-us", "250", *fly]) == 0
    assert len(windows) == 1 and windows.pop() == pytest.approx(250e-6)
    assert "--spin-us=250.0" in commands[0]  # the simulator's, checked by its parser above
    assert sitl.main(fly) == 0
    assert windows == {spin.LOCKSTEP_SPIN_S}
    assert f"--spin-us={spin.LOCKSTEP_SPIN_S * 1e6}" in commands[1]


def test_node_only_takes_spin_us(monkeypatch, tmp_path):
    from quadpilot import sitl

    sim = Simulator(SimConfig(listen="tcp:127.0.0.1:0", episodes=1))
    port = sim.bind().port
    thread = threading.Thread(target=sim.serve, daemon=True)
    thread.start()
    windows = _node_windows(monkeypatch)
    try:
        argv = ["--node-only", "--connect", f"tcp:127.0.0.1:{port}", "--spin-us", "0", "--duration", "0.2"]
        assert sitl.main([*argv, "--gcs", "none", "--json", str(tmp_path / "n.json")]) == 0
    finally:
        sim.stop()
        thread.join(5.0)
    assert windows == {0.0}
