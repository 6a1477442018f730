"""quad-sitl --link-impair end to end: the node's link to the simulator goes through the impairment
proxy (TCP, and UDP), the summary and --json say what it did, and the hover still holds at 5 % frame
loss (real time: in lockstep, where a lost frame would stall both sides, it is refused)."""

from __future__ import annotations

import json
import threading

import pytest

from quadpilot.simulator import SimConfig, Simulator
from quadpilot.sitl import main as quad_sitl

pytestmark = pytest.mark.sitl


@pytest.mark.parametrize("proto", ["tcp", "udp"])
def test_quad_sitl_flies_through_the_proxy_and_says_what_it_did(proto, tmp_path, capsys):
    out = tmp_path / "s.json"
    argv = ["--realtime", "--episodes", "1", "--gcs", "none", "--listen", f"{proto}:127.0.0.1:0"]
    assert quad_sitl([*argv, "--link-impair", "loss=5%,duplicate=2%,seed=1", "--json", str(out)]) == 0
    s = json.loads(out.read_text())
    li = s["link_impair"]
    assert li["spec"] == "loss=5%,duplicate=2%,seed=1" and li["connections"] == 1
    for way in ("up", "down"):  # whole frames both ways, some lost, some twice
        c = li[way]
        assert c["frames"] > 400 and 0 < c["lost"] < 0.15 * c["frames"] and c["duplicated"] > 0
        due = c["frames"] - c["lost"] - c["lost_burst"] + c["duplicated"]
        assert 0 <= due - c["relayed"] <= 3  # what was still in flight when the episode ended is not relayed
    assert s["success_rate"] == 1.0 and s["failsafe_events"] == 0
    # a lost state's step is flown on the node's estimate; a duplicate is refused as a repeated timestamp
    assert s["state_lost_steps"] > 0 and s["packets_dropped"]["time_repeated"] > 0
    assert "link impaired (loss=5%,duplicate=2%,seed=1)" in capsys.readouterr().out


def test_node_only_flies_through_the_proxy_to_a_simulator_it_did_not_start(tmp_path, capsys):
    sim = Simulator(SimConfig(listen="tcp:127.0.0.1:0", episodes=1, lockstep=False, lockstep_timeout_s=2.0))
    port = sim.bind().port
    thread = threading.Thread(target=sim.serve, daemon=True)
    thread.start()
    out = tmp_path / "n.json"
    try:
        argv = ["--node-only", "--connect", f"tcp:127.0.0.1:{port}", "--realtime", "--duration", "2", "--gcs", "none"]
        assert quad_sitl([*argv, "--link-impair", "delay=5ms", "--json", str(out)]) == 0
    finally:
        sim.stop()
        thread.join(10)
    li = json.loads(out.read_text())["link_impair"]
    assert li["up"]["delayed"] == li["up"]["frames"] > 150 and li["down"]["delayed"] == li["down"]["frames"]
    assert "link impaired (delay=5ms,seed=0)" in capsys.readouterr().out


@pytest.mark.parametrize("spec", ["loss=5%", "delay=5ms", "duplicate=5%", "burst=1%", "reorder=1%"])
@pytest.mark.parametrize("node_only", [False, True])
def test_an_impaired_link_in_lockstep_is_refused_in_one_line(spec, node_only, capsys):
    # in lockstep a lost frame stalls both sides and a duplicated command steps the simulator twice:
    # refused before anything starts, not flown into a timeout or a desynchronised flight
    where = ["--node-only", "--connect", "tcp:127.0.0.1:9"] if node_only else []
    code = quad_sitl([*where, "--episodes", "1", "--gcs", "none", "--link-impair", spec])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "--link-impair needs --realtime" in err and "add --realtime" in err, err
