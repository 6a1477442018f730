"""The node through a silent state stream (`autopilot.state_loss`), against our simulator in lockstep:
a long dropout ends in a landing, not a fall, and a flight that never had a state is never armed.
The 0.5 s dropout is in test_sensor_faults.py; the rates and episodes of the goals are
benchmarks/state_loss.py's."""

from __future__ import annotations

import threading

import pytest

from quadpilot.autopilot.node import Node, NodeConfig
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.simulator import SimConfig, Simulator
from quadpilot.simulator.faults import parse_faults
from quadpilot.simulator.records import TOUCHDOWN_MAX_SPEED
from quadpilot.sitl import SHIPPED_HOVER

pytestmark = pytest.mark.sitl


def fly(faults: str, duration_s: float, start: str = "air", rate_hz: int = 100):
    """One lockstep flight of the shipped hover policy; (node log, the simulator's episode record)."""
    cfg = SimConfig(
        listen="tcp:127.0.0.1:0",
        episodes=1,
        seed=0,
        dt=1.0 / rate_hz,
        lockstep_timeout_s=2.0,
        start=start,
        sensor_faults=parse_faults(faults),
    )
    records = []
    sim = Simulator(cfg, on_episode=records.append)
    port = sim.bind().port
    thread = threading.Thread(target=sim.serve, daemon=True)
    thread.start()
    try:
        log = Node(NodeConfig(connect=f"tcp:127.0.0.1:{port}", duration_s=duration_s, gcs=None)).fly(
            SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy"))
        )
    finally:
        sim.stop()
        thread.join(10)
    return log, records[0]


@pytest.mark.parametrize("fault", ["state-dropout@2s+5s", "state-dropout@2s+3600s"])
def test_a_long_state_loss_ends_in_a_landing_with_the_motors_stopped_on_the_ground(fault):
    log, rec = fly(fault, 10.0)
    phases = [h[2].split(":")[0] for h in log.handovers if h[1] == "state-loss"]
    assert phases == ["state lost", "hold", "descend", "landed"]
    # down at most 1 m/s, touching down upright, never a crash, the motors never off in the air
    assert rec.touchdown is not None and not rec.crashed
    step, speed, tilt_deg = rec.touchdown
    assert speed < TOUCHDOWN_MAX_SPEED and rec.max_descent_speed <= 1.0 and tilt_deg < 30.0
    assert rec.motors_off_airborne_steps == 0 and rec.final_state[2] == 0.0
    assert log.sources[-1] == "landed" and log.failsafe == "state lost: landed"
    # the motors stopped after the touchdown: the first zero command comes after the contact step
    first_off = log.sources.index("landed")
    assert first_off >= step


def test_a_flight_without_any_state_is_never_armed():
    log, rec = fly("state-dropout@0s+3600s", 5.0, start="landed")
    assert log.failsafe == "refusing to arm: no state in 1 s of sensor data"
    assert log.replies >= 100 and log.steps == 0 and rec.commands >= 100  # answered, motors off
    assert not rec.crashed and rec.final_state[2] == 0.0


def test_quad_sitl_says_in_one_line_that_it_refuses_to_arm(capsys):
    from quadpilot.sitl import main as quad_sitl

    assert quad_sitl(["--sensor-fault", "state-dropout@0s+3600s", "--episodes", "1", "--gcs", "none"]) == 1
    err = capsys.readouterr().err.strip()
    says = (
        "quad-sitl: refusing to arm: no state in 1 s of sensor data (HIL_SENSOR arrives, HIL_STATE_QUATERNION does not)"
    )
    assert err == says


def test_an_implausible_estimate_lands_at_once():
    # the barometer jumps 5 m while the state is lost: the estimate and the barometer disagree, and
    # the node stops believing either and lands, without waiting for the hold
    log, rec = fly("state-dropout@2s+3600s,baro-step@2.3s:5", 10.0)
    changes = [h[2] for h in log.handovers if h[1] == "state-loss"]
    assert [c.split(":")[0] for c in changes] == ["state lost", "descend", "landed"]
    assert changes[1].startswith("descend: estimate implausible: barometer +5.0 m")
    assert rec.touchdown is not None and not rec.crashed and rec.motors_off_airborne_steps == 0


@pytest.mark.parametrize(
    ("value", "says"),
    [("3,1", "must not exceed descend_s"), ("x", "is not two numbers"), ("1,nan", "descend_s must be")],
)
def test_a_bad_state_loss_flag_is_one_line(value, says, capsys):
    from quadpilot.sitl import main as quad_sitl

    assert quad_sitl(["--state-loss", value]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and says in err and "Traceback" not in err
