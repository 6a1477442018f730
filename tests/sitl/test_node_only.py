"""quad-sitl --node-only against a simulator written here with pymavlink alone (MAVLink 1 or 2, as a
PX4-API simulator speaks it): one HIL_ACTUATOR_CONTROLS per step in the simulator's version, the
policy at its own rate on simulated time, home from the first fix, the flags and the exit codes.

The simulator holds the vehicle still at one position (no physics): what is checked is the node's
protocol and bookkeeping; flying is `test_rotorpy.py`'s."""

import json
import math
import socket
import threading
import time

import numpy as np
import pytest
from pymavlink.dialects.v10 import common as mavlink1
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.link import wire
from quadpilot.sitl import SHIPPED_HOVER, main

pytestmark = pytest.mark.sitl
HOME = wire.Home(-33.8688, 151.2093, 58.0)  # somewhere our simulator never is
HOVER = np.array([0.3, -0.2, 4.0] + [0.0] * 9)  # ENU from HOME, level, still


class Sink:
    def __init__(self):
        self.out = bytearray()

    def write(self, buf):
        self.out += buf


class ScriptedSimulator:
    """Listens on loopback TCP, waits for the autopilot's HEARTBEAT, then sends `steps` steps of
    HIL_STATE_QUATERNION + HIL_SENSOR `dt_us` apart in MAVLink `version` and waits up to 2 s for the
    answer to each (a lockstep simulator that never misses one); records every message that came
    back, with its MAVLink version and the step it arrived in."""

    def __init__(self, version: int, dt_us: int, steps: int, state=HOVER, t0_us: int = 0):
        self.version, self.dt_us, self.steps, self.state, self.t0_us = version, dt_us, steps, state, t0_us
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.received: list = []  # (step index or None before the first step, message, version)
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        try:
            self._serve()
        except BaseException as e:  # surfaced by the test
            self.error = e
        finally:
            self.server.close()

    def _serve(self):
        conn, _ = self.server.accept()
        conn.settimeout(2.0)
        out = Sink()
        codec = (mavlink1 if self.version == 1 else mavlink2).MAVLink(out, srcSystem=200, srcComponent=200)
        parser = mavlink2.MAVLink(None)  # reads both versions
        step = None

        def read_until(kind):
            """Read until a message of `kind` arrives; every message of the same read is recorded
            in this step (a second answer sent right behind the first counts here, not later)."""
            while True:
                batch = parser.parse_buffer(conn.recv(4096)) or []
                for m in batch:
                    if m.get_type() == "BAD_DATA":
                        raise AssertionError(f"the node sent bad data: {m}")
                    self.received.append((step, m, 1 if m.get_msgbuf()[0] == 0xFE else 2))
                if any(m.get_type() == kind for m in batch):
                    return

        with conn:
            read_until("HEARTBEAT")
            z3 = np.zeros(3)
            for k in range(self.steps):
                step = k
                t = self.t0_us + k * self.dt_us
                codec.hil_state_quaternion_send(**wire.hil_state_quaternion_fields(self.state, HOME, t))
                sensor = wire.hil_sensor_fields(t, z3, np.array([0.0, 0.0, 9.81]), z3, 1000.0, 60.0)
                if self.version == 1:
                    sensor.pop("id")  # an extension field: not in MAVLink 1
                codec.hil_sensor_send(**sensor)
                conn.sendall(out.out)
                out.out.clear()
                read_until("HIL_ACTUATOR_CONTROLS")
            step = "after"
            conn.settimeout(0.3)
            try:  # anything still coming (a second answer to a step)
                while data := conn.recv(4096):
                    for m in parser.parse_buffer(data) or []:
                        self.received.append((step, m, 1 if m.get_msgbuf()[0] == 0xFE else 2))
            except (TimeoutError, ConnectionError):
                pass

    def join(self):
        self.thread.join(10)
        assert not self.thread.is_alive(), "the scripted simulator did not finish"
        if self.error is not None:
            raise self.error

    def replies(self):
        return [(k, m, v) for k, m, v in self.received if m.get_type() == "HIL_ACTUATOR_CONTROLS"]


def node_only(port: int, *flags: str) -> list[str]:
    return [str(SHIPPED_HOVER), "--node-only", "--connect", f"tcp:127.0.0.1:{port}", "--gcs", "none", *flags]


@pytest.mark.parametrize(("version", "rate_hz"), [(1, 100), (2, 250)])
def test_one_reply_per_step_in_the_simulators_version_and_the_policy_at_its_own_rate(
    version, rate_hz, tmp_path, capsys
):
    duration = 1.0
    steps = round(duration * rate_hz)
    sim = ScriptedSimulator(version, round(1e6 / rate_hz), steps)
    out = tmp_path / "summary.json"
    trace = tmp_path / "trace.csv"
    code = main(node_only(sim.port, "--duration", str(duration), "--json", str(out), "--trace", str(trace)))
    sim.join()
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert len(printed.out.strip().splitlines()) == 1 and printed.err == ""  # one line, nothing else
    first_step, first, first_version = sim.received[0]
    assert first_step is None and first.get_type() == "HEARTBEAT" and first_version == 1  # before any step
    replies = sim.replies()
    assert [k for k, _, _ in replies] == list(range(steps))  # exactly one per step, none after the last
    assert [m.time_usec for _, m, _ in replies] == [k * round(1e6 / rate_hz) for k in range(steps)]
    assert {v for _, _, v in replies} == {version}  # the simulator's version
    assert all(m.mode & wire.ARMED for _, m, _ in replies)
    s = json.loads(out.read_text())
    assert s["steps"] == steps and s["fallback_steps"] == 0 and s["mavlink_version"] == version
    assert s["policy_steps"] == round(duration * 100)  # the policy's 100 Hz on simulated time
    # the command changes only where the policy ran, and is held in between
    commands = np.array([m.controls[:4] for _, m, _ in replies])
    ticks = np.loadtxt(trace, delimiter=",", skiprows=1, usecols=21, dtype=int)
    changed = np.r_[True, np.any(np.diff(commands, axis=0) != 0, axis=1)]
    assert not np.any(changed & (ticks == 0)) and ticks.sum() == s["policy_steps"]
    gaps = np.diff(np.flatnonzero(ticks)) * (1e3 / rate_hz)
    assert np.all((gaps >= 10.0 - 4.0 - 1e-9) & (gaps <= 10.0 + 4.0 + 1e-9)) and abs(gaps.mean() - 10.0) < 0.3
    # home from the first fix, target the start: still, so no error at all
    lat, lon, alt = wire.local_to_geodetic(HOVER[0:3], HOME)
    assert s["home"] == pytest.approx({"lat_deg": lat * 1e-7, "lon_deg": lon * 1e-7, "alt_m": alt * 1e-3})
    assert s["target_enu_m"] == [0.0, 0.0, 0.0] and s["error_last_2s_m"] == 0.0


@pytest.mark.parametrize("spelling", ["separate", "joined"])
def test_home_and_target_flags_with_negative_values(spelling, tmp_path):
    home = f"{HOME.lat_deg},{HOME.lon_deg},{HOME.alt_m}"
    target = "-0.5,0.7,0.3"
    flags = ["--home", home, "--target", target] if spelling == "separate" else [f"--home={home}", f"--target={target}"]
    sim = ScriptedSimulator(2, 10_000, 50, t0_us=1_000_000)
    out = tmp_path / "summary.json"
    code = main(node_only(sim.port, *flags, "--duration", "0.5", "--json", str(out)))
    sim.join()
    s = json.loads(out.read_text())
    assert code == 0
    assert s["home"] == {"lat_deg": HOME.lat_deg, "lon_deg": HOME.lon_deg, "alt_m": HOME.alt_m}
    assert s["target_enu_m"] == [-0.5, 0.7, 0.3]
    # the vehicle sits at HOVER in HOME's frame, up to the wire's quantisation
    want = math.dist(HOVER[0:3], (-0.5, 0.7, 0.3))
    assert s["final_error_m"] == pytest.approx(want, abs=0.01)


def test_more_than_ten_percent_of_steps_on_the_fallback_exits_1_with_one_line(tmp_path, capsys):
    """A target 10 m away is outside the envelope the policy was trained in (5 m): the fallback
    flies every step, and the run says so and fails."""
    sim = ScriptedSimulator(2, 10_000, 30)
    code = main(node_only(sim.port, "--target", "0,0,10", "--duration", "0.3"))
    sim.join()
    printed = capsys.readouterr()
    assert code == 1
    assert len(printed.out.strip().splitlines()) == 1 and "fallback 30 steps (out_of_envelope 1)" in printed.out
    (line,) = printed.err.strip().splitlines()
    assert line == "quad-sitl: 30 of 30 steps (100.0%) fell back (out_of_envelope 1): more than 10%"
    assert len(sim.replies()) == 30  # still answered, once each


@pytest.mark.parametrize(
    "flags",
    [
        ["--home", "47.4,8.5"],
        ["--home", "91,8.5,488"],
        ["--home", "-90,8.5,488"],
        ["--home", "47.4,181,488"],
        ["--home", "a,b,c"],
        ["--home", "nan,8.5,488"],
        ["--home", "47.4,8.5,inf"],
        ["--home", "47.4,8.5,1e9"],
        ["--target", "1,2"],
        ["--target", "1,2,3,4"],
        ["--target=-1e4,0,0"],
        ["--target", "0,inf,0"],
        ["--target", "x,0,0"],
        ["--duration", "0"],
        ["--duration", "-1"],
        ["--duration", "nan"],
        ["--duration", "1e9"],
        ["--episodes", "3"],
        ["--min-success", "0.9"],
        ["--listen", "tcp:127.0.0.1:4560"],
        ["--wind", "1,0,0"],
    ],
)
def test_bad_node_only_flags_are_refused_in_one_line(flags, capsys):
    code = main(node_only(9, *flags))  # nothing listens on port 9: it must not get that far
    printed = capsys.readouterr()
    assert code == 2 and printed.out == ""
    (line,) = printed.err.strip().splitlines()
    assert line.startswith("quad-sitl: error: ")


@pytest.mark.parametrize(
    ("flags", "says"),
    [
        (["--vehicle", "x500", "--wind", "1,0,0"], "--wind=1,0,0: simulator flags, but --node-only runs no simulator"),
        (["--vehicle", "px4_sih_quadx"], "--vehicle with --node-only maps a contract policy's outputs"),
        (["--vehicle", "no_such_vehicle"], "unknown vehicle 'no_such_vehicle'"),
        (["--maneuver", "figure8"], "expected step, step:METRES"),
        (["--maneuver", "step", "--target", "0,0,1"], "flown from where the vehicle starts"),
        (["--maneuver", "step", "--home", "47.4,8.5,488"], "flown from where the vehicle starts"),
    ],
)
def test_node_only_vehicle_and_maneuver_flags_it_cannot_use_say_why(flags, says, capsys):
    """--vehicle reaches the node only for a contract policy (RAPTOR's rotor order); a maneuver is
    flown from where the vehicle starts."""
    assert main(node_only(9, *flags)) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert says in line


@pytest.mark.parametrize("flags", [["--home", "47.4,8.5,488"], ["--target", "0,0,1"], ["--trace", "t.csv"]])
def test_node_only_flags_without_node_only_are_refused(flags, capsys):
    assert main([str(SHIPPED_HOVER), *flags]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == f"quad-sitl: error: {flags[0]}: for --node-only"


def test_no_simulator_step_is_one_line_and_exit_1(capsys):
    """A simulator that accepts the connection and never steps: the node gives up after its first-
    state wait, says so in one line, exits 1."""
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def hang_up_later():
        conn, _ = server.accept()
        time.sleep(0.5)
        conn.close()

    thread = threading.Thread(target=hang_up_later, daemon=True)
    thread.start()
    try:
        code = main(node_only(port, "--duration", "1"))
    finally:
        thread.join(5)
        server.close()
    printed = capsys.readouterr()
    assert code == 1
    (line,) = printed.err.strip().splitlines()
    assert line == "quad-sitl: nothing flown: simulator closed the link"


def test_a_simulator_that_stops_before_the_duration_is_named_as_the_reason(capsys):
    """A simulator script of fewer steps than --duration closes the link after its last step: the
    flight ended early (exit 1), and the line says the simulator stopped first, after how much sim
    time, and what to change, not only that the link closed."""
    sim = ScriptedSimulator(1, 10_000, 50)  # 0.5 s of 10 ms steps
    code = main(node_only(sim.port, "--duration", "1"))
    sim.join()
    assert code == 1
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith("quad-sitl: the flight ended early after 50 steps: failsafe: simulator closed the link")
    assert "after 0.50 s of sim time, before --duration 1 s: the simulator stopped stepping first" in line
    assert "or give --duration 0.50" in line
