"""In lockstep both sides of the simulator link poll before they sleep (`transport.LOCKSTEP_SPIN_S`,
or the configured `spin_s`; 0 turns it off), and in realtime neither does: the node and the
simulator each set their link's window from their config. The flight itself is the same either way
(tests/sitl/test_lockstep_identity.py pins its bytes)."""

from __future__ import annotations

import threading

import pytest

from quadpilot.firmware_sim.sim import SimConfig, Simulator
from quadpilot.link import transport
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.runtime.node import NODE_SYSTEM_ID, Node, NodeConfig
from quadpilot.sitl import SHIPPED_HOVER


def _fly(monkeypatch, lockstep: bool, sim_spin: float | None, node_spin: float | None) -> dict:
    """The windows each side's waits had during the flight's 20 steps (the simulator's wait for the
    node's first HEARTBEAT, before its steps, is a plain wait)."""
    windows: dict[int, list] = {}
    real_recv = transport.Link.recv

    def recording(self, timeout=0.0):
        if timeout > 0:
            windows.setdefault(self.system, []).append(self.spin_s)
        return real_recv(self, timeout)

    monkeypatch.setattr(transport.Link, "recv", recording)
    monkeypatch.setattr(transport, "spin_window", lambda s: s)  # whatever this machine's CPU count
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
    assert w == {"node": {transport.LOCKSTEP_SPIN_S}, "simulator": {transport.LOCKSTEP_SPIN_S}}


def test_the_configured_window_is_used_and_zero_turns_it_off(monkeypatch):
    assert _fly(monkeypatch, True, 0.0, 0.002) == {"node": {0.002}, "simulator": {0.0}}


def test_neither_side_polls_in_realtime(monkeypatch):
    w = _fly(monkeypatch, False, None, None)
    assert w == {"node": {0.0}, "simulator": {0.0}}


def test_a_bad_window_is_refused():
    with pytest.raises(ValueError, match="spin_s"):
        NodeConfig(spin_s=float("nan"))
    with pytest.raises(ValueError, match="spin_s"):
        SimConfig(spin_s=-1.0)


def test_spin_us_sets_both_sides_windows(monkeypatch, tmp_path):
    from quadpilot import sitl
    from quadpilot.firmware_sim.sim import build_sim_parser, config_from_args

    assert config_from_args(build_sim_parser().parse_args(["--spin-us", "250"])).spin_s == pytest.approx(250e-6)
    assert config_from_args(build_sim_parser().parse_args([])).spin_s == transport.LOCKSTEP_SPIN_S
    assert sitl._sim_args(sitl.build_parser().parse_args(["--spin-us", "250"])) == ["--spin-us=250"]
    node_windows = set()
    real_recv = transport.Link.recv

    def recording(self, timeout=0.0):
        if timeout > 0 and self.system == NODE_SYSTEM_ID:
            node_windows.add(self.spin_s)
        return real_recv(self, timeout)

    monkeypatch.setattr(transport.Link, "recv", recording)
    monkeypatch.setattr(transport, "spin_window", lambda s: s)
    argv = [
        "--spin-us",
        "250",
        "--episodes",
        "1",
        "--duration",
        "0.2",
        "--gcs",
        "none",
        "--json",
        str(tmp_path / "s.json"),
    ]
    assert sitl.main(argv) == 0
    assert len(node_windows) == 1 and node_windows.pop() == pytest.approx(250e-6)
