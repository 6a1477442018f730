"""The simulator's side of the wire (`Protocol`): the messages of each step out, and the one receive
point for what comes in, with the check that turns an actuator message into a motor command.

Out, each step, in this order (PX4's Simulator MAVLink API; `link.wire` encodes them):

1. HIL_GPS, every `gps_every` steps (step 0 included);
2. HIL_STATE_QUATERNION, the ground truth (with the body specific force as its acceleration);
3. ODOMETRY, with `estimator_noise` only: the state estimate, "what an EKF would output" (the
   truth plus `core.sensor_noise`'s estimator errors; the node flies on it, and is judged on 2);
4. HIL_SENSOR, last, because a PX4 peer steps on it: gyro (body rates), accelerometer (specific
   force), magnetometer, barometer (with `imu_noise`: `core.sensor_noise`'s IMU model).

With `sensor_faults`, 1, 2 and 4 are faulted (or withheld) as `faults` says before they go out.

In: one receive point (`receive`) dispatching on the message type. HIL_ACTUATOR_CONTROLS is handed
to the server loop; HEARTBEAT is counted (the server loop starts an episode on the first one, in
either MAVLink version: the link parses both); BAD_DATA (pymavlink's type for garbage and bad CRCs) and
unknown message ids are dropped and counted by reason; other known messages are counted as
ignored; a parser failure is counted as `parser_error`. Nothing that arrives raises, except the
peer closing the link (`PeerClosed`).

Out goes MAVLink 2, as the simulator's own system (`link.transport.SIM_SYSTEM_ID`, not the
autopilot's).

Commands (`command`): `controls[0..3]` is ω/ω_max per rotor in PX4 quad-X order. While the peer is
disarmed (mode bit 128 clear) the motors get 0 whatever it sends. An armed message with a
non-finite or out-of-range (outside [0, 1]) value in controls[0..3] is dropped and counted: the
server loop keeps the previous command.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.core import dynamics
from quadpilot.link import wire
from quadpilot.link.transport import Link, PeerClosed, bad_data_reason

from .config import SimConfig
from .faults import FaultPlayer
from .plant import Plant
from .records import EpisodeTally, SimStats
from .sensors import Sensors
from .sensors import rotation as body_to_world

log = logging.getLogger(__name__)

_HIL_GPS = mavlink2.MAVLink_hil_gps_message
_HIL_STATE_QUATERNION = mavlink2.MAVLink_hil_state_quaternion_message
_HIL_SENSOR = mavlink2.MAVLink_hil_sensor_message

TIME_ORIGIN_US = 1_000_000
"""µs, time_usec of an episode's first messages; it then grows by dt per step. Not zero, because
some autopilots treat a zero timestamp as 'not set'."""


def _codec_sender(mav):
    """`Link.send_message` for a link that is not a `transport.Link` (any object with a pymavlink codec
    as `mav`, e.g. a test's scripted peer): the codec's own `<message>_send`."""
    return lambda cls, args: getattr(mav, cls.msgname.lower() + "_send")(*args)


class Protocol:
    """Messages in and out for the simulator configured by `cfg`; drops and counts go into `stats`
    (and into the episode's tally when there is one)."""

    def __init__(self, cfg: SimConfig, stats: SimStats) -> None:
        self.cfg = cfg
        self.stats = stats
        self.faults: FaultPlayer | None = None
        """The episode's sensor faults (`faults`), set by the server loop per episode; None: none."""

    def send_step(self, link, plant: Plant, n: int, sensors: Sensors) -> None:
        """The messages of step `n` (see the module doc), then one flush. Each goes to pymavlink as
        one positional call (`link.wire`'s `*_args`: the fields in the message's order)."""
        cfg = self.cfg
        send = link.send_message if isinstance(link, Link) else _codec_sender(link.mav)
        t_us = TIME_ORIGIN_US + round(n * cfg.dt * 1e6)
        state = plant.state
        values = state.tolist()  # plain floats for the scalar field arithmetic
        gps = wire.hil_gps_args(values, cfg.home, t_us) if n % cfg.gps_every == 0 else None
        rot = body_to_world(state)  # once for the accelerometer and the magnetometer
        accel = plant.specific_force_flu(rot)
        hil_state = wire.hil_state_quaternion_args(values, cfg.home, t_us, accel.tolist())
        r = sensors.read(state, accel, n, rot)
        sensor = wire.hil_sensor_args(t_us, r.gyro, r.accel, r.mag, r.pressure_hpa, r.alt_m, r.temperature_c)
        if self.faults is not None:  # `faults`: this episode's injected sensor faults
            gps, hil_state = self.faults.apply(n, gps, hil_state, sensor)
        if gps is not None:
            send(_HIL_GPS, gps)
        if hil_state is not None:
            send(_HIL_STATE_QUATERNION, hil_state)
        if r.estimate is not None:
            link.mav.odometry_send(**wire.odometry_fields(r.estimate, t_us, *sensors.variances))
        send(_HIL_SENSOR, sensor)
        link.flush()

    def receive(self, link, timeout: float, ep: EpisodeTally | None):
        """The one receive point: the next message, dispatched; returns it if it is a
        HIL_ACTUATOR_CONTROLS, else None. PeerClosed propagates."""
        try:
            msg = link.recv(timeout)
        except PeerClosed:
            raise
        except Exception as e:  # a parser failure on hostile bytes must not end the simulator
            log.debug("parser error: %r", e)
            self.drop("parser_error", ep)
            return None
        return None if msg is None else self.dispatch(msg, ep)

    def dispatch(self, msg, ep: EpisodeTally | None):
        """`msg` if it is a HIL_ACTUATOR_CONTROLS, else None after counting it (module doc)."""
        kind = msg.get_type()
        if kind == "HIL_ACTUATOR_CONTROLS":
            return msg
        if kind == "HEARTBEAT":
            self.stats.heartbeats += 1
        elif kind == "BAD_DATA":
            self.drop(bad_data_reason(msg), ep)
        elif kind.startswith("UNKNOWN_"):
            self.drop("unknown_message_id", ep)
        else:
            self.stats.ignored[kind] = self.stats.ignored.get(kind, 0) + 1
        return None

    def command(self, msg, ep: EpisodeTally) -> np.ndarray | None:
        """Motor command (4,) from an actuator message; None if it must be dropped."""
        try:
            values, armed, _ = wire.motor_values_from_actuator_controls(msg)  # plain floats: cheap comparisons
        except (TypeError, IndexError, ValueError):
            self.drop("bad_data", ep)
            return None
        if not armed:
            ep.commands += 1
            return np.zeros(dynamics.NUM_MOTORS)
        a, b, c, d = values
        if not (0.0 <= a <= 1.0 and 0.0 <= b <= 1.0 and 0.0 <= c <= 1.0 and 0.0 <= d <= 1.0):  # False for NaN too
            self.drop("out_of_range_control" if all(math.isfinite(v) for v in values) else "non_finite_control", ep)
            return None
        ep.commands += 1
        return np.array(values)

    def drop(self, reason: str, ep: EpisodeTally | None) -> None:
        self.count(reason, 1, ep)

    def count(self, reason: str, k: int, ep: EpisodeTally | None = None) -> None:
        """`k` packets dropped for `reason`, in the stats and the episode's tally."""
        if k:
            self.stats.dropped[reason] = self.stats.dropped.get(reason, 0) + k
            if ep is not None:
                ep.dropped[reason] = ep.dropped.get(reason, 0) + k
