"""A policy flown by `quad-sitl --node-only` in a simulator we did not write: RotorPy's
PX4Multirotor (rotorpy 3.0.0) with PX4's SIH quad-X parameters or RotorPy's Hummingbird, from 5 m up
with its rotors at rest, in two processes of their own (`rotorpy_px4.py`, `quad-sitl`), at 100 Hz
speaking MAVLink 1 and at 250 Hz speaking MAVLink 2.

RotorPy gives each step 10 ms of wall time for the answer and then flies it on zero motors, and takes
the oldest queued answer: a step answered late leaves every later step one answer behind. Whether
each answer comes within the 10 ms depends on the host (on a loaded one RotorPy's own process may
not run within its wait), so the tests fly RotorPy in lockstep (`rotorpy_px4.py --lockstep`: each
step waits for its answer, as PX4's lockstep simulators do) and check on RotorPy's side of the wire
that no step was missed or late: every step flew on its own answer, none on zero motors, none on an
earlier step's, none left over (`every_step_on_its_own_answer`). How long RotorPy waited is printed;
RotorPy's own 10 ms wait, missed steps and all, is measured with the load average by
benchmarks/rotorpy_flights.py, not asserted (tests carry no timing bounds).

The policy, the airframe and the bounds are parameters (`RotorPyFlight`): models/hover_px4_sih (trained for SIH) and
models/hover_hummingbird (trained from a vehicle file of RotorPy's Hummingbird, in RotorPy's own
rotor numbering) fly to a target about 1 m away within 5 cm. Every flight holds its heading: mean
|yaw rate| ≤ 0.2 rad/s and heading within 10° of the start over the last 2 s."""

import dataclasses
import json
import math
import os
import socket
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from quadpilot.link.frames import EARTH_RADIUS_M
from quadpilot.sitl import SHIPPED_HOVER

pytestmark = pytest.mark.sitl
HERE = Path(__file__).parent
ROTORPY_ORIGIN = {"lat_deg": 40.0, "lon_deg": -74.3, "alt_m": 0.0}  # PX4Multirotor.enu_to_geodetic's defaults
ROTORPY_EARTH_RADIUS_M = 6378137.0  # WGS-84 semi-major axis, rotorpy/vehicles/px4_multirotor.py
START_UP_M = 5.0  # rotorpy_px4.py's start height
WINDOW_S = 2.0


@dataclass(frozen=True)
class RotorPyFlight:
    """One flight and what it must achieve."""

    policy: Path
    rate_hz: float
    mavlink: int
    max_error_m: float
    """Mean distance to the target over the last WINDOW_S, RotorPy's ground truth."""
    max_yaw_rate: float = 0.2
    """rad/s, mean |yaw rate| over the last WINDOW_S."""
    max_heading_deg: float | None = 10.0
    """deg, mean |heading error| over the last WINDOW_S against the start heading (the node's
    commanded heading); None: not judged (a policy trained before the yaw rule)."""
    vehicle: str = "sih"
    """RotorPy's airframe: "sih" (its PX4 SIH quad-X) or "hummingbird" (`rotorpy_px4.py --vehicle`), or a
    vehicle file flown with RotorPy's dynamics (`rotorpy_px4.py --vehicle-file`)."""
    duration_s: float = 5.0
    target: tuple[float, float, float] | None = None
    """--target E,N,U from home (the start position); None: hold the start."""
    node_flags: tuple[str, ...] = ()
    """More quad-sitl flags (--maneuver, --vehicle for a contract policy's rotor order)."""
    sim_flags: tuple[str, ...] = ()
    """More rotorpy_px4.py flags (--wind, --gust, --impulse)."""

    @property
    def id(self) -> str:
        return f"{self.policy.parent.name}-{self.vehicle}-{self.rate_hz:g}Hz-mavlink{self.mavlink}"


MODELS = SHIPPED_HOVER.parents[1]
SIH = MODELS / "hover_px4_sih" / "policy.onnx"  # trained for PX4's SIH quad-X (vehicles/px4_sih_quadx.toml)
# trained from a vehicle file only: tests/data/vehicles/rotorpy_hummingbird.toml
HUMMINGBIRD = MODELS / "hover_hummingbird" / "policy.onnx"
RAPTOR_SIH = MODELS / "hover_px4_raptor_sih" / "policy.tar"  # quad-train --contract px4-raptor
RAPTOR_HUMMINGBIRD = MODELS / "hover_px4_raptor_hummingbird" / "policy.tar"
# The shipped hover policy was trained for another vehicle: its hover command (0.677 of 2000 rad/s)
# gives SIH's rotors 677 of the 700 rad/s they need, and it has no integral action to take up the
# difference, so it hovers some centimetres low (bound 10 cm). The policies trained for the vehicle
# they fly fly to a target about 1 m away (0.95 m and 0.91 m) within 5 cm.
FLIGHTS = [
    # models/hover is not flown here: trained for the seed quad (no motor lag) through delay, it leaves the
    # envelope on SIH's 50 ms rotor lag and 1 kg (15.6 % of a 500-step flight fell back when it was tried);
    # the policy before it held its point 4 cm low (docs/airframes.md)
    RotorPyFlight(SIH, 100, 1, max_error_m=0.05, target=(0.6, -0.5, 0.55)),
    RotorPyFlight(SIH, 250, 2, max_error_m=0.05, target=(0.6, -0.5, 0.55)),
    RotorPyFlight(HUMMINGBIRD, 100, 1, max_error_m=0.05, vehicle="hummingbird", target=(-0.5, 0.7, 0.3)),
    # the policies of PX4 mc_raptor's contract trained here, flown from their policy.tar (the GRU advancing
    # at 100 Hz; the Hummingbird's rotors numbered as RotorPy numbers them, from its vehicle.toml)
    RotorPyFlight(RAPTOR_SIH, 100, 1, max_error_m=0.05, target=(0.6, -0.5, 0.55)),
    RotorPyFlight(RAPTOR_HUMMINGBIRD, 100, 1, max_error_m=0.05, vehicle="hummingbird", target=(-0.5, 0.7, 0.3)),
]


def rotorpy_target(target: tuple[float, float, float] | None) -> np.ndarray:
    """The node's --target (E, N, U metres from home, the start), or the start itself, in RotorPy's
    world ENU: RotorPy turns metres into longitude and latitude on its own Earth radius."""
    scale = ROTORPY_EARTH_RADIUS_M / EARTH_RADIUS_M
    return np.array([0.0, 0.0, START_UP_M]) + np.array(target or (0.0, 0.0, 0.0)) * np.array([scale, scale, 1.0])


def rotorpy_yaw(q: np.ndarray) -> np.ndarray:
    """Yaw (rad, ENU, wrapped) of RotorPy's quaternions (..., 4) stored x, y, z, w."""
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def above_best_effort() -> None:
    """In a child before it runs: nice −10, where the OS allows it (root or CAP_SYS_NICE, as in CI).
    RotorPy waits 10 ms of wall time for each answer: both processes must run when woken, as a flight
    stack runs above best-effort work (PX4 on Linux: real-time priorities), or another process keeping
    the cores busy decides the flight. Elsewhere they run as they are, and on a loaded host may miss."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, -10)
    except OSError:
        pass


def fly(
    case: RotorPyFlight, tmp_path: Path, lockstep: bool = False
) -> tuple[dict, dict, np.ndarray, subprocess.CompletedProcess]:
    """(RotorPy's record, the node's --json summary, its --trace, the node's process). `lockstep`:
    RotorPy waits for each step's answer (`rotorpy_px4.py --lockstep`); else its own 10 ms."""
    port = _free_port()
    steps = round(case.duration_s * case.rate_hz)
    record = tmp_path / "rotorpy.json"
    summary = tmp_path / "node.json"
    sim = subprocess.Popen(
        [
            sys.executable,
            HERE / "rotorpy_px4.py",
            str(port),
            str(case.rate_hz),
            str(steps),
            record,
            "--mavlink",
            str(case.mavlink),
            *(["--vehicle-file", case.vehicle] if case.vehicle.endswith(".toml") else ["--vehicle", case.vehicle]),
            *case.sim_flags,
            *(["--lockstep"] if lockstep else []),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=above_best_effort,
    )
    # RotorPy listens only once it has imported (scipy, its own modules: over 10 s on a loaded host,
    # longer than the node's connect timeout); it says so on stdout, then blocks for a HEARTBEAT
    for line in sim.stdout:
        if "Initializing MAVLink connection" in line:
            break
    threading.Thread(target=sim.stdout.read, daemon=True).start()  # the rest: never a full pipe
    node_cmd = [sys.executable, "-m", "quadpilot.sitl", str(case.policy), "--node-only"]
    node_cmd += ["--connect", f"tcp:127.0.0.1:{port}", "--duration", str(case.duration_s), "--gcs", "none"]
    node_cmd += ["--json", str(summary), "--trace", str(tmp_path / "node.csv")]
    if case.target is not None:
        node_cmd.append("--target=" + ",".join(f"{v:g}" for v in case.target))
    node_cmd += case.node_flags
    try:
        # hang guards, not timing bounds: on a loaded host RotorPy's Radau steps take several times longer
        node = subprocess.run(node_cmd, capture_output=True, text=True, timeout=900, preexec_fn=above_best_effort)
        try:  # a node that ended early leaves RotorPy stepping without answers, or waiting for one
            sim.wait(timeout=600 if node.returncode == 0 else 30)
        except subprocess.TimeoutExpired:
            pytest.fail(f"RotorPy did not finish; quad-sitl exited {node.returncode}: {node.stderr.strip()[-600:]}")
    finally:
        sim.kill()
        _, err = sim.communicate()
    assert sim.returncode == 0, err
    # one row reads as a 0-d array: at least 1-d, so that a short flight fails with its message below
    trace = np.atleast_1d(np.genfromtxt(tmp_path / "node.csv", delimiter=",", names=True, dtype=None, encoding="utf-8"))
    return json.loads(record.read_text()), json.loads(summary.read_text()), trace, node


def every_step_on_its_own_answer(rotorpy: dict, steps: int) -> None:
    """RotorPy, in lockstep, flew every step on that step's answer: none missed (no answer, zero motors),
    none late (flown on an earlier step's answer), none consumed twice, none left over at the end."""
    rows = rotorpy["steps"]
    assert rotorpy["lockstep"] and len(rows) == steps, (rotorpy["lockstep"], len(rows), steps)
    missed = [k for k, r in enumerate(rows) if r["reply_t_us"] is None]
    late = [k for k, r in enumerate(rows) if r["reply_t_us"] is not None and r["reply_t_us"] != r["t_us"]]
    assert not missed and not late and rotorpy["extra_replies"] == 0, (
        f"{len(missed)} steps missed (first {missed[:3]}), {len(late)} flown on an earlier step's answer "
        f"(first {late[:3]}), {rotorpy['extra_replies']} answers left over"
    )


@pytest.mark.parametrize("case", FLIGHTS, ids=lambda c: c.id)
def test_the_node_flies_rotorpys_px4_simulator(case: RotorPyFlight, tmp_path):
    rotorpy, s, trace, node = fly(case, tmp_path, lockstep=True)
    rows = rotorpy["steps"]
    steps = round(case.duration_s * case.rate_hz)
    waits_ms = np.array([r["wait_s"] for r in rows]) * 1e3
    missed = sum(r["reply_t_us"] is None for r in rows)
    stale = sum(r["reply_t_us"] is not None and r["reply_t_us"] != r["t_us"] for r in rows)
    # when each answer left the node, after the step's HIL_SENSOR left RotorPy (one host clock)
    assert len(trace) == len(rows), "the node logs every step RotorPy sent"
    left_ms = (trace["host_time_s"] + trace["reply_latency_us"] * 1e-6 - [r["sensor_sent_s"] for r in rows]) * 1e3
    # the ground truth, RotorPy's world ENU; the node's target is in its own metres, RotorPy's
    # longitude and latitude scale is its own Earth radius
    x = np.array([r["x"] for r in rows])
    target = rotorpy_target(case.target)
    k = round(WINDOW_S * case.rate_hz)
    error = np.linalg.norm(x[-k:] - target, axis=1).mean()
    yaw_rate = np.abs(np.array([r["w"] for r in rows])[-k:, 2]).mean()
    heading_deg = np.degrees(np.abs(rotorpy_yaw(np.array([r["q"] for r in rows])[-k:]))).mean()
    print(
        f"{case.id}: {len(rows)} steps, missed {missed}, stale {stale}, extra {rotorpy['extra_replies']}; "
        f"error last {WINDOW_S:g} s {error * 100:.2f} cm (height {np.mean(x[-k:, 2] - target[2]) * 100:+.2f} cm), "
        f"mean |yaw rate| {yaw_rate:.3f} rad/s, heading error {heading_deg:.2f} deg; "
        f"RotorPy waited p50 {np.percentile(waits_ms, 50):.2f} ms "
        f"p99 {np.percentile(waits_ms, 99):.2f} ms max {waits_ms.max():.2f} ms; answers left the node "
        f"p50 {np.percentile(left_ms, 50):.2f} ms p99 {np.percentile(left_ms, 99):.2f} ms max {left_ms.max():.2f} ms "
        f"after the HIL_SENSOR (node's handling p50 {s['reply_latency_p50_us']:.0f} µs p99 "
        f"{s['reply_latency_p99_us']:.0f} µs); RotorPy wall {rotorpy['wall_s']:.1f} s, node wall {s['wall_s']:.1f} s"
    )
    assert node.returncode == 0, node.stderr
    # RotorPy, in lockstep, flew every step on exactly its own answer of ours: no step missed or late
    every_step_on_its_own_answer(rotorpy, steps)
    assert {r["reply_version"] for r in rows} == {case.mavlink} and all(r["reply_armed"] for r in rows)
    assert s["steps"] == steps and s["mavlink_version"] == case.mavlink
    assert s["policy_steps"] == pytest.approx(case.duration_s * 100, abs=1)
    # home from the first fix: RotorPy's origin, START_UP_M up
    assert s["home"] == pytest.approx({**ROTORPY_ORIGIN, "alt_m": START_UP_M})
    assert s["home_source"] == "first valid position"
    assert s["fallback_steps"] == 0 and s["failsafe"] is None
    # it hovers
    assert error <= case.max_error_m and yaw_rate <= case.max_yaw_rate
    if case.max_heading_deg is not None:  # it holds the heading it started with (RotorPy's start: yaw 0)
        assert heading_deg <= case.max_heading_deg
    assert math.isclose(s["error_last_2s_m"], error, abs_tol=0.01)  # the node saw what RotorPy did


def test_rotorpys_wind_and_a_hit_reach_the_flight(tmp_path):
    """rotorpy_px4.py --wind/--gust/--impulse: RotorPy's own wind sets the state's wind before every
    step and acts on the vehicle (it leans into a strong wind), the hit adds its velocity once, and the
    policy still flies to its target against both."""
    still = RotorPyFlight(SIH, 100, 1, 0.05, target=(0.6, -0.5, 0.55), duration_s=5.0)
    hit = dataclasses.replace(still, sim_flags=("--wind", "8,0,0", "--impulse", "1@2"))  # SIH: 0.64 N of drag
    gust = dataclasses.replace(still, sim_flags=("--wind", "2,0,0", "--gust", "1"))
    runs = {}
    for name, case in (("still", still), ("hit", hit), ("gust", gust)):
        (tmp_path / name).mkdir()
        runs[name] = fly(case, tmp_path / name, lockstep=True)
        every_step_on_its_own_answer(runs[name][0], round(case.duration_s * case.rate_hz))
    rows = {name: r[0]["steps"] for name, r in runs.items()}
    assert all(r["wind"] == [0.0, 0.0, 0.0] for r in rows["still"])
    assert all(r["wind"] == [8.0, 0.0, 0.0] for r in rows["hit"])  # ConstantWind, east
    gusts = np.array([r["wind"] for r in rows["gust"]])  # about the mean, a standard deviation of about 1 m/s
    assert np.all((gusts.std(axis=0) > 0.7) & (gusts.std(axis=0) < 1.3)) and abs(gusts[:, 0].mean() - 2.0) < 0.5
    # the hit: step 200's velocity jumps east by about 1 m/s more than the step before's change
    v = np.array([r["v"] for r in rows["hit"]])
    jump = (v[200, 0] - v[199, 0]) - (v[199, 0] - v[198, 0])
    assert 0.8 < jump < 1.2, jump
    change = np.abs(np.diff(v, 2, axis=0))  # no other step changes the velocity so suddenly: one hit
    change[198:200, 0] = 0.0  # the hit's own two second differences
    assert change.max() < 0.3, np.unravel_index(change.argmax(), change.shape)

    def lean_east_deg(name: str) -> float:  # the body z axis's east component over the last second, deg
        x, y, z, w = np.array([r["q"] for r in rows[name][-100:]]).T
        return float(np.degrees(np.arcsin(2.0 * (x * z + w * y))).mean())

    # against 8 m/s from the west SIH's drag (c_D 0.01 N/(m/s)^2) needs a lean of about 3.7° into it
    assert lean_east_deg("hit") - lean_east_deg("still") < -2.0, (lean_east_deg("hit"), lean_east_deg("still"))
    for name, (record, _, _, node) in runs.items():
        assert node.returncode == 0, (name, node.stderr)
        x = np.array([r["x"] for r in record["steps"][-100:]])
        error = np.linalg.norm(x - rotorpy_target(still.target), axis=1).mean()
        # over the last second: held in the wind, back after the hit (in 8 m/s, with no integral action, a
        # steady offset downwind)
        assert error < (0.2 if name == "hit" else 0.1), (name, error)


def test_in_lockstep_a_slow_answer_is_waited_for(tmp_path):
    """Answers that reach RotorPy 30 ms after their step's HIL_SENSOR left (a 15 ms link each way, the
    node in real time through quad-sitl's impairment proxy), three times RotorPy's own wait: in
    lockstep every step still flies on its own answer, none missed, none late. (The node is given a
    longer flight than RotorPy's 100 steps, so that its last answer is not lost in the proxy when it
    exits; it ends when RotorPy hangs up.)"""
    slow = ("--realtime", "--link-impair", "delay=15ms", "--duration", "30")
    case = RotorPyFlight(SIH, 100, 1, max_error_m=0.05, duration_s=1.0, node_flags=slow)
    rotorpy, _, _, node = fly(case, tmp_path, lockstep=True)
    assert "Traceback" not in node.stderr, node.stderr
    assert min(r["wait_s"] for r in rotorpy["steps"]) > 0.02  # every answer came long after RotorPy's 10 ms
    every_step_on_its_own_answer(rotorpy, round(case.duration_s * case.rate_hz))
