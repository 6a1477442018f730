"""The node against a scripted simulator: state and sensor timestamps that go backwards, repeat or
jump are dropped and counted, a HIL_SENSOR whose state has not come is flown on the node's estimate
(`autopilot.state_loss`), and every answer is one finite HIL_ACTUATOR_CONTROLS stamped with its
step's time."""

import threading
import time

import numpy as np
import pytest

from quadpilot.autopilot.node import Node, NodeConfig
from quadpilot.link import transport, wire
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.sitl import SHIPPED_HOVER

pytestmark = pytest.mark.sitl
HOVER = np.array([0.0, 0.0, 2.0] + [0.0] * 9)


def _script(link, t_us, answers, sensor_time=None):
    link.mav.hil_state_quaternion_send(**wire.hil_state_quaternion_fields(HOVER, wire.Home(), t_us))
    z3 = np.zeros(3)
    fields = wire.hil_sensor_fields(sensor_time or t_us, z3, np.array([0, 0, 9.81]), z3, 1000.0, 490.0)
    link.mav.hil_sensor_send(**fields)
    link.flush()
    deadline = time.monotonic() + 0.5
    while time.monotonic() < deadline:  # collect what the node answers (10 ms: dropped steps must
        m = link.recv(0.01)  # not add up to the node's 100 ms link-loss failsafe)
        if m is None:
            break
        if m.get_type() == "HIL_ACTUATOR_CONTROLS":
            answers.append(m)


def test_bad_timestamps_are_dropped_and_counted():
    listener = transport.Listener("tcp:127.0.0.1:0")
    port = listener.bind().port
    answers, sent = [], []

    def simulator():
        link, _ = listener.accept(0.05, lambda: False)
        base = 1_000_000
        for t, sensor in [
            (base, None),  # answered
            (base + 10_000, None),  # answered
            (base + 5_000, None),  # backwards: dropped, state and sensor
            (base + 10_000, None),  # repeated: dropped, state and sensor
            (base + 3_000_000, None),  # a 3 s jump: dropped, state and sensor
            (base + 20_000, base + 30_000),  # a sensor whose state has not come: flown on the estimate
            (base + 40_000, None),  # answered
        ]:
            sent.append(t)
            _script(link, t, answers, sensor)
        time.sleep(0.3)  # then silence: the node's failsafe ends the episode
        link.close()

    thread = threading.Thread(target=simulator, daemon=True)
    thread.start()
    try:
        log = Node(NodeConfig(connect=f"tcp:127.0.0.1:{port}", duration_s=10.0, gcs=None)).fly(
            SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy"))
        )
    finally:
        thread.join(5)
        listener.close()
    assert log.dropped["time_backwards"] == 1 and log.dropped["time_repeated"] == 1
    assert log.dropped["time_jump"] == 1 and log.dropped["sensor_time_jump"] == 1
    assert log.dropped["sensor_out_of_order"] == 2 and log.state_lost_steps == 1
    stamps = [a.time_usec for a in answers if a.mode & wire.ARMED]
    assert stamps == [1_000_000, 1_010_000, 1_030_000, 1_040_000]
    assert log.failsafe is not None
    for a in answers:
        assert all(np.isfinite(a.controls)) and all(0.0 <= c <= 1.0 for c in a.controls)
