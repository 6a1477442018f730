"""RotorPy's PX4 simulator, driven the way RotorPy's own users drive it, in a process of its own (its
10 ms wait for the autopilot's answer must not share a GIL with anything):

    python rotorpy_px4.py PORT RATE_HZ STEPS OUT.json [--mavlink 1|2] [--seed N] [--vehicle sih|hummingbird]
                          [--vehicle-file FILE.toml] [--wind E,N,U] [--gust M/S] [--impulse DV@T] [--lockstep]
                          [--state-dropout START+DURATION] [--height M] [--baro]

`rotorpy.vehicles.px4_multirotor.PX4Multirotor` with RotorPy's PX4 SIH quad-X parameters
(`px4_sihsim_quadx_params`, PX4's 10040_sihsim_quadx airframe) or its AscTec Hummingbird
(`hummingbird_params`, rotors numbered RotorPy's way, not PX4's), 5 m up, level, at rest, rotors at
rest; or any vehicle file, as RotorPy parameters (`quadpilot.core.rotorpy_vehicle.rotorpy_params`:
rotors in the file's output order, so a policy's outputs reach the rotors they were trained for).
It listens on tcp 127.0.0.1:PORT, waits (in its constructor) for the autopilot's HEARTBEAT,
then loops `state = vehicle.step(state, control, 1 / RATE_HZ)` STEPS times: each step sends
HIL_STATE_QUATERNION and HIL_SENSOR and waits up to 10 ms for one HIL_ACTUATOR_CONTROLS, else flies
the step on zero motors. The wind is RotorPy's own, set into the state before each step as RotorPy's
`simulate` does (`wind_profile.update(t, x)`, here at the step's start): `--wind` a constant (`ConstantWind`), plus with
`--gust G` RotorPy's `SinusoidWind` on each axis, amplitude √2·G (a standard deviation of G, as
quad-sitl's --gust gives its gusts) at `GUST_HZ`. (RotorPy's `DrydenGust`, stepped at 100 Hz at
these heights, moves the wind by millimetres per second over a flight of seconds: no gust.)
`--impulse DV@T`: at T s the velocity jumps by DV m/s east (world x), a hit.
`--state-dropout START+DURATION` (seconds, e.g. `2+0.5`, `2+inf`): the steps that start in
[START, START + DURATION) send no HIL_STATE_QUATERNION (the vehicle's `_send_hil_state_quaternion`
is wrapped on the instance to do nothing then), HIL_SENSOR goes out as always: quad-sitl's
`state-dropout` fault. `--height M`: the start height (5 m by default; 0: on the ground).
`--baro`: RotorPy 3.0.0's HIL_SENSOR carries no barometer (zeros, not flagged as updated); with this
flag its `hil_sensor_send` call gets one, RotorPy's height through the ISA (exact, no noise; RotorPy's
world origin at sea level), flagged as updated, as every PX4 vehicle has.

`--lockstep`: each step waits for its answer (up to `LOCKSTEP_GUARD_S`, a hang guard) instead of
RotorPy's 10 ms, as PX4's lockstep simulators wait for the autopilot: the host's load then cannot make
a step fly on zero motors or on the step before's answer, so every step flies on its own answer, and
a step that does not is the node's fault. Without it, RotorPy waits as its users run it (what
benchmarks/rotorpy_flights.py measures).

What it measures, without touching RotorPy's code path: the connection's `recv_match` is wrapped to
record what RotorPy's step got back and how long it waited (and, with --lockstep, to wait longer).
OUT.json holds per step the time_usec RotorPy stamped the step's messages with, the ground truth
after the step (RotorPy's world ENU, body FLU: position, velocity, quaternion x, y, z, w, body
rates, rotor speeds, the wind it flew), the reply's time_usec (None: no reply within the wait, the
step flew on zero motors), the wait, and when the step's HIL_SENSOR left (time.perf_counter(), the
host's CLOCK_MONOTONIC on Linux: the node's --trace `host_time_s` is on the same clock); then how
many HIL_ACTUATOR_CONTROLS were still queued after the last step (a second reply to some step).

For a landing, judged on RotorPy's ground truth: per step whether the state was withheld
(`state_withheld`), the reply's motor commands (`reply_controls`, ω/ω_max; None: no reply, RotorPy flew
the step on zero motors), whether the vehicle started the step in the air (`airborne_before`: above
RotorPy's ground test, z > 1 mm), and `contact`: RotorPy's ground (`enable_ground`, z = 0) is a
kinematic clamp applied after the step's integration (`Multirotor._handle_vehicle_on_ground`: z set to
0, downward velocity zeroed, attitude flattened and rates zeroed, every step the vehicle is at or below
1 mm), so the recorded state after a contact step is already clamped; the wrapper records what the step
ended with before the clamp (`{"v": ..., "q": ...}`, None: no clamp this step); and `imu`, the
accelerometer and gyro the step's HIL_SENSOR carried (body FRD, m/s², rad/s), to replay the node's
estimate (`autopilot.dead_reckoning`) against the truth. OUT.json's `landing` sums it up: the first
contact (`touchdown`: step, time, the velocity and tilt before the clamp; None: never touched down),
the fastest descent (of all steps, and of those withheld: `max_descent_speed_withheld`), the most
tilted step, the steps in the air after the first contact and the highest of them, and the steps
started in the air with every motor commanded zero by a reply, and those with no reply in time (RotorPy
flew them on zero motors: a missed step, not a command), and how many steps were withheld.

`--mavlink 2` sets MAVLINK20 before pymavlink is imported: RotorPy's connection then speaks MAVLink 2
(pymavlink's mavutil picks its dialect at import; without it, MAVLink 1 until a MAVLink 2 byte
arrives first).
"""

import argparse
import json
import math
import os
import time

args = argparse.ArgumentParser()
args.add_argument("port", type=int)
args.add_argument("rate_hz", type=float)
args.add_argument("steps", type=int)
args.add_argument("out")
args.add_argument("--mavlink", type=int, choices=(1, 2), default=1)
args.add_argument("--seed", type=int, default=0)
args.add_argument("--vehicle", choices=("sih", "hummingbird"), default="sih")
args.add_argument("--vehicle-file", help="a vehicle file, flown with RotorPy's dynamics (instead of --vehicle)")
args.add_argument("--wind", default="0,0,0", help="mean wind, m/s, world ENU: E,N,U")
args.add_argument("--gust", type=float, default=0.0, help="gusts' standard deviation per axis, m/s")
args.add_argument("--impulse", help="DV@T: at T s the velocity jumps by DV m/s east")
args.add_argument("--lockstep", action="store_true", help="each step waits for its answer (not RotorPy's 10 ms)")
args.add_argument("--state-dropout", help="START+DURATION, s: no HIL_STATE_QUATERNION in that window")
args.add_argument("--height", type=float, default=5.0, help="start height, m (default 5)")
args.add_argument("--baro", action="store_true", help="give HIL_SENSOR a barometer: RotorPy's height, ISA")
args = args.parse_args()
if args.mavlink == 2:
    os.environ["MAVLINK20"] = "1"
else:
    os.environ.pop("MAVLINK20", None)

import numpy as np  # noqa: E402
from rotorpy.vehicles.px4_multirotor import PX4Multirotor  # noqa: E402
from rotorpy.wind.default_winds import ConstantWind, SinusoidWind  # noqa: E402

if args.vehicle_file:
    from quadpilot.core.rotorpy_vehicle import rotorpy_params
    from quadpilot.core.vehicle_file import load_vehicle_file

    quad_params = rotorpy_params(load_vehicle_file(args.vehicle_file))
elif args.vehicle == "sih":
    from rotorpy.vehicles.px4_sihsim_quadx_params import quad_params
else:
    from rotorpy.vehicles.hummingbird_params import quad_params


def _dropout(text: str | None) -> tuple[float, float]:
    """START+DURATION seconds (DURATION may be inf); no dropout: an empty window."""
    if text is None:
        return 0.0, 0.0
    start, _, duration = text.partition("+")
    start, duration = float(start), float(duration)
    if not (start >= 0.0 and duration >= 0.0):  # NaN fails too
        raise SystemExit(f"rotorpy_px4.py: --state-dropout {text!r}: expected START+DURATION seconds, e.g. 2+0.5")
    return start, start + duration


drop_from, drop_until = _dropout(args.state_dropout)
if not (args.height >= 0.0):  # 0: on the ground (RotorPy's ground is z = 0)
    raise SystemExit(f"rotorpy_px4.py: --height {args.height!r}: expected metres above the ground")
np.random.seed(args.seed)  # noqa: NPY002 - RotorPy's IMU noise draws from NumPy's global generator
START = {
    "x": np.array([0.0, 0.0, args.height]),
    "v": np.zeros(3),
    "q": np.array([0.0, 0.0, 0.0, 1.0]),
    "w": np.zeros(3),
    "wind": np.zeros(3),
    "rotor_speeds": np.zeros(4),
}
vehicle = PX4Multirotor(quad_params, initial_state=START, mavlink_url=f"tcpin:127.0.0.1:{args.port}")
got: dict = {}
recv_match = vehicle.conn.recv_match
LOCKSTEP_GUARD_S = 30.0
"""s, --lockstep: the longest a step waits for its answer (a node that died), not a timing bound."""


def watched_recv_match(*a, **kw):
    if args.lockstep:  # RotorPy's step asks with timeout=0.01
        kw["timeout"] = LOCKSTEP_GUARD_S
    t0 = time.perf_counter()  # the step's HIL_SENSOR has just been sent
    msg = recv_match(*a, **kw)
    got["wait_s"], got["msg"], got["sent_s"] = time.perf_counter() - t0, msg, t0
    return msg


vehicle.conn.recv_match = watched_recv_match
send_state = vehicle._send_hil_state_quaternion
handle_ground = vehicle._handle_vehicle_on_ground


def withheld() -> bool:
    """The step under way starts in the dropout: by its index, not by RotorPy's clock, which adds up
    the step (200 steps of 0.01 s make 1.99999999999998 s)."""
    return drop_steps[0] <= step_i < drop_steps[1]


def dropping_send_state(state, statedot):
    if withheld():
        return None
    return send_state(state, statedot)


def watched_handle_ground(state):
    got["contact"] = {"v": state["v"].tolist(), "q": state["q"].tolist()}  # before the clamp
    return handle_ground(state)


imu = vehicle._imu


def watched_imu(state, statedot):
    got["imu"] = imu(state, statedot)  # what the step's HIL_SENSOR carries (FRD)
    got["height"] = float(state["x"][2])
    return got["imu"]


sensor_send = vehicle.conn.mav.hil_sensor_send
BARO_FIELDS = 512 | 2048 | 4096  # HIL_SENSOR_UPDATED_ABS_PRESSURE, _PRESSURE_ALT, _TEMPERATURE


def sensor_send_with_baro(*a, **kw):
    """RotorPy's HIL_SENSOR (time, acc, gyro, mag, abs_pressure, diff_pressure, pressure_alt,
    temperature, fields_updated=...), its barometer fields filled from the step's height."""
    from quadpilot.simulator.sensors import isa_pressure_hpa, isa_temperature_c

    a = list(a)
    alt = got["height"]
    a[10], a[12], a[13] = isa_pressure_hpa(alt), alt, isa_temperature_c(alt)
    kw["fields_updated"] = int(kw.get("fields_updated", 0)) | BARO_FIELDS
    return sensor_send(*a, **kw)


if args.baro:
    vehicle.conn.mav.hil_sensor_send = sensor_send_with_baro


vehicle._imu = watched_imu
vehicle._send_hil_state_quaternion = dropping_send_state
vehicle._handle_vehicle_on_ground = watched_handle_ground
dt = 1.0 / args.rate_hz
drop_steps = [math.ceil(t * args.rate_hz - 1e-6) if math.isfinite(t) else math.inf for t in (drop_from, drop_until)]
GUST_HZ = (0.5, 0.37, 0.29)  # east, north, up: periods of 2 to 3.4 s, none a multiple of another
steady = ConstantWind(*(float(v) for v in args.wind.split(",")))
gusts = SinusoidWind(amplitudes=np.full(3, np.sqrt(2.0) * args.gust), frequencies=np.array(GUST_HZ))
hit_dv, hit_step = 0.0, -1
if args.impulse:  # quad-sitl's --impulse, read and bounded as quad-sitl reads it, at the same step
    from quadpilot.simulator.cli import _impulse

    hit_dv, at = _impulse(args.impulse)
    hit_step = max(1, round(at * args.rate_hz))
state = {k: v.copy() for k, v in START.items()}
control = {"cmd_motor_speeds": np.zeros(4)}  # unused: the autopilot's command replaces it
rows = []
wall0 = time.perf_counter()
step_i = 0
for i in range(args.steps):
    step_i = i
    t_us = int(vehicle.t * 1e6)  # what PX4Multirotor.step stamps this step's messages with
    got.clear()
    airborne = bool(state["x"][2] > 0.001)  # RotorPy's Multirotor._on_ground is z <= 1 mm
    dropped = withheld()
    state["wind"] = np.asarray(steady.update(vehicle.t, state["x"]) + gusts.update(vehicle.t, state["x"]), dtype=float)
    if i == hit_step:
        state["v"] = state["v"] + np.array([hit_dv, 0.0, 0.0])
    state = vehicle.step(state, control, dt)
    msg = got.get("msg")
    rows.append(
        {
            "t_us": t_us,
            "x": state["x"].tolist(),
            "v": state["v"].tolist(),
            "q": state["q"].tolist(),
            "w": state["w"].tolist(),
            "rotor_speeds": state["rotor_speeds"].tolist(),
            "wind": state["wind"].tolist(),
            "reply_t_us": None if msg is None else int(msg.time_usec),
            "reply_version": None if msg is None else (1 if msg.get_msgbuf()[0] == 0xFE else 2),
            "reply_armed": None if msg is None else bool(msg.mode & 128),
            "reply_controls": None if msg is None else [float(c) for c in msg.controls[:4]],
            "state_withheld": dropped,
            "airborne_before": airborne,
            "contact": got.get("contact"),
            "imu": [v.tolist() for v in got["imu"]],
            "wait_s": got.get("wait_s"),
            "sensor_sent_s": got.get("sent_s"),
        }
    )
wall = time.perf_counter() - wall0
time.sleep(0.3)  # anything still on its way
extra = 0
while recv_match(type="HIL_ACTUATOR_CONTROLS", blocking=False) is not None:
    extra += 1


def tilt_deg(q) -> float:
    """The angle between the body's z axis and the world's up, of a quaternion x, y, z, w."""
    x, y = q[0], q[1]
    return float(np.degrees(np.arccos(np.clip(1.0 - 2.0 * (x * x + y * y), -1.0, 1.0))))


touchdown = None
for i, r in enumerate(rows):
    if r["contact"] is not None and r["airborne_before"]:
        v = r["contact"]["v"]
        touchdown = {
            "step": i,
            "t_s": r["t_us"] * 1e-6 + dt,  # the end of the step
            "vz": v[2],
            "speed": float(np.linalg.norm(v)),
            "tilt_deg": tilt_deg(r["contact"]["q"]),
        }
        break
airborne_rows = [r for r in rows if r["airborne_before"]]
landing = {
    "touchdown": touchdown,
    "max_descent_speed": max((-r["v"][2] for r in rows), default=0.0),
    "max_descent_speed_withheld": max((-r["v"][2] for r in rows if r["state_withheld"]), default=0.0),
    "max_tilt_deg": max((tilt_deg(r["q"]) for r in rows), default=0.0),
    "motors_off_airborne_steps": sum(
        r["reply_controls"] is not None and not any(r["reply_controls"]) for r in airborne_rows
    ),
    "missed_airborne_steps": sum(r["reply_controls"] is None for r in airborne_rows),
    "withheld_steps": sum(r["state_withheld"] for r in rows),
}
if touchdown is not None:  # after the first contact: in the air again (a bounce, or a lift-off)
    after = rows[touchdown["step"] + 1 :]
    landing["airborne_after_touchdown_steps"] = sum(r["x"][2] > 0.001 for r in after)
    landing["max_height_after_touchdown"] = max((r["x"][2] for r in after), default=0.0)
if touchdown is not None:  # before the clamp zeroes it: the contact step's own downward speed counts
    landing["max_descent_speed"] = max(landing["max_descent_speed"], -touchdown["vz"])
    if rows[touchdown["step"]]["state_withheld"]:
        landing["max_descent_speed_withheld"] = max(landing["max_descent_speed_withheld"], -touchdown["vz"])
with open(args.out, "w", encoding="utf-8") as f:
    record = {"dt": dt, "start": START["x"].tolist(), "lockstep": args.lockstep, "wall_s": wall, "extra_replies": extra}
    record.update(
        state_dropout=[drop_from, drop_until if np.isfinite(drop_until) else None], landing=landing, steps=rows
    )
    json.dump(record, f)
