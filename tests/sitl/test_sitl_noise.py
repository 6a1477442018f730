"""With --estimator-noise the node flies on the simulator's ODOMETRY estimate (what an EKF would
output) and is judged on the exact HIL_STATE_QUATERNION: the observations the policy saw differ
from the truth by the estimator's centimetres, the logged states do not."""

import threading

import numpy as np
import pytest

from quadpilot.autopilot.node import Node, NodeConfig, heading_within_reach
from quadpilot.core.observation import build_observation
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.simulator import SimConfig, Simulator
from quadpilot.sitl import SHIPPED_HOVER

pytestmark = pytest.mark.sitl

START = (0.3, -0.2, 2.2, 0.0, 0.0, 0.0, 0.05, -0.05, 1.0, 0.0, 0.0, 0.0)
STEPS = 200


class Spy(SafetyMonitor):
    def __init__(self, policy):
        super().__init__(policy)
        self.seen = []

    def act(self, obs):
        self.seen.append(np.array(obs))
        return super().act(obs)


def fly(**noise):
    sim = Simulator(SimConfig(listen="tcp:127.0.0.1:0", episodes=1, initial_state=START, seed=2, **noise))
    port = sim.bind().port
    thread = threading.Thread(target=sim.serve, daemon=True)
    thread.start()
    try:
        monitor = Spy(load_policy(SHIPPED_HOVER, "numpy"))
        node = Node(NodeConfig(connect=f"tcp:127.0.0.1:{port}", duration_s=STEPS * 0.01, gcs=None))
        log = node.fly(monitor)
    finally:
        sim.stop()
        thread.join(5.0)
    return log, np.array(monitor.seen)


def test_the_node_flies_on_the_estimate_and_is_judged_on_the_truth():
    log, seen = fly(estimator_noise=True, imu_noise=True)
    assert log.failsafe is None and log.steps == STEPS and not log.dropped
    truth = np.array(log.states)
    from_truth = build_observation(truth, np.array([0.0, 0.0, 2.0]))
    pos_gap = np.abs(seen[:, 0:3] - from_truth[:, 0:3]).max()
    assert 0.005 < pos_gap < 0.1, pos_gap  # the estimator's centimetres, not the wire's quantisation
    assert np.linalg.norm(truth[-1, 0:3] - [0.0, 0.0, 2.0]) < 0.1  # the hover policy still holds


def test_without_estimator_noise_the_observation_is_the_decoded_truth():
    log, seen = fly()
    truth = np.array(log.states)
    truth[:, 9:12] = np.float32(truth[:, 9:12])  # rates come from HIL_SENSOR's float32 gyro
    # the heading the node holds: the first state's, given at most HEADING_REACH_RAD ahead
    heading = [heading_within_reach(float(yaw), float(truth[0, 8])) for yaw in truth[:, 8]]
    expected = build_observation(truth, np.array([0.0, 0.0, 2.0]), heading=np.array(heading))
    np.testing.assert_allclose(seen, expected, atol=1e-5)
