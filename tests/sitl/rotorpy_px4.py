"""RotorPy's PX4 simulator, driven the way RotorPy's own users drive it, in a process of its own (its
10 ms wait for the autopilot's answer must not share a GIL with anything):

    python rotorpy_px4.py PORT RATE_HZ STEPS OUT.json [--mavlink 1|2] [--seed N] [--vehicle sih|hummingbird]
                          [--vehicle-file FILE.toml] [--wind E,N,U] [--gust M/S] [--impulse DV@T] [--lockstep]

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

`--mavlink 2` sets MAVLINK20 before pymavlink is imported: RotorPy's connection then speaks MAVLink 2
(pymavlink's mavutil picks its dialect at import; without it, MAVLink 1 until a MAVLink 2 byte
arrives first).
"""

import argparse
import json
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

np.random.seed(args.seed)  # noqa: NPY002 - RotorPy's IMU noise draws from NumPy's global generator
START = {
    "x": np.array([0.0, 0.0, 5.0]),
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
dt = 1.0 / args.rate_hz
GUST_HZ = (0.5, 0.37, 0.29)  # east, north, up: periods of 2 to 3.4 s, none a multiple of another
steady = ConstantWind(*(float(v) for v in args.wind.split(",")))
gusts = SinusoidWind(amplitudes=np.full(3, np.sqrt(2.0) * args.gust), frequencies=np.array(GUST_HZ))
hit_dv, hit_step = 0.0, -1
if args.impulse:  # quad-sitl's --impulse, read and bounded as quad-sitl reads it, at the same step
    from quadpilot.firmware_sim.cli import _impulse

    hit_dv, at = _impulse(args.impulse)
    hit_step = max(1, round(at * args.rate_hz))
state = {k: v.copy() for k, v in START.items()}
control = {"cmd_motor_speeds": np.zeros(4)}  # unused: the autopilot's command replaces it
rows = []
wall0 = time.perf_counter()
for i in range(args.steps):
    t_us = int(vehicle.t * 1e6)  # what PX4Multirotor.step stamps this step's messages with
    got.clear()
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
            "wait_s": got.get("wait_s"),
            "sensor_sent_s": got.get("sent_s"),
        }
    )
wall = time.perf_counter() - wall0
time.sleep(0.3)  # anything still on its way
extra = 0
while recv_match(type="HIL_ACTUATOR_CONTROLS", blocking=False) is not None:
    extra += 1
with open(args.out, "w", encoding="utf-8") as f:
    record = {"dt": dt, "start": START["x"].tolist(), "lockstep": args.lockstep, "wall_s": wall, "extra_replies": extra}
    json.dump({**record, "steps": rows}, f)
