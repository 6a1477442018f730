"""Sensor faults (`simulator.faults`, `--sensor-fault`) against a real node flying the shipped hover
policy, in lockstep (the same flight every run): that the fault reached the wire, what the node did
(flew on, flew blind, handed over to the fallback, failed safe) and how the flight ended.

After a blind step the fallback flies until valid states have kept the vehicle inside the recovery
envelope for `runtime.safety.HAND_BACK_HOLD_S`; then the policy flies again (the hand-back)."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.autopilot.flight_log import episode_summary
from quadpilot.autopilot.node import Node, NodeConfig
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.runtime.safety import HAND_BACK_HOLD_S
from quadpilot.simulator import SimConfig, Simulator
from quadpilot.simulator.faults import FaultSpecError, SensorFault, parse_faults
from quadpilot.sitl import SHIPPED_HOVER
from quadpilot.sitl import main as quad_sitl

pytestmark = pytest.mark.sitl
DT = 0.01
AT = 2.0  # s, when every fault here starts
STEP = round(AT / DT)
HOLD = round(HAND_BACK_HOLD_S / DT)


def handed_back(log, events) -> bool:
    """The fallback flew from the fault's step for the hold and no longer; the policy flew the rest."""
    src = log.sources
    back = STEP + 1 + src[STEP + 1 :].index("policy")
    return (
        events["fallback_engaged"] == 1
        and events["handed_back"] == 1
        and HOLD <= back - STEP <= HOLD + 2
        and set(src[back:]) == {"policy"}
    )


def fly(faults: str | None, seed: int = 0):
    """One 5 s lockstep hover; (node log, monitor events, its judgement, HIL_SENSOR and
    HIL_STATE_QUATERNION messages the node received, steps each fault was active)."""
    cfg = SimConfig(
        listen="tcp:127.0.0.1:0",
        episodes=1,
        seed=seed,
        lockstep_timeout_s=2.0,
        sensor_faults=parse_faults(faults) if faults else (),
    )
    sim = Simulator(cfg)
    port = sim.bind().port
    thread = threading.Thread(target=sim.serve, daemon=True)
    thread.start()
    parser = mavlink2.MAVLink(None)
    seen: dict[str, list] = {"HIL_SENSOR": [], "HIL_STATE_QUATERNION": []}

    def tap(direction, raw):
        if direction == "in":
            for m in parser.parse_buffer(raw) or ():
                seen.get(m.get_type(), []).append(m)

    monitor = SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy"))
    try:
        log = Node(NodeConfig(connect=f"tcp:127.0.0.1:{port}", duration_s=5.0, gcs=None)).fly(monitor, tap=tap)
        fired = dict(sim._io.faults.fired) if sim._io.faults is not None else {}
    finally:
        sim.stop()
        thread.join(10)
    return log, dict(monitor.events), episode_summary(log, DT), seen, fired


@pytest.fixture(scope="module")
def clean():
    return fly(None)


def test_without_faults_the_policy_flies_every_step(clean):
    log, events, judged, _, fired = clean
    assert judged["success"] and not events and fired == {} and set(log.sources) == {"policy"}


def test_gyro_spike_reaches_the_node_and_the_policy_flies_through_it(clean):
    log, events, judged, seen, fired = fly("gyro-spike@2s")
    x = [m.xgyro for m in seen["HIL_SENSOR"]]
    x0 = [m.xgyro for m in clean[3]["HIL_SENSOR"]]
    assert fired == {"gyro-spike": 1}
    assert x[:STEP] == x0[:STEP] and x[STEP] == pytest.approx(x0[STEP] + 20.0)  # 20 rad/s at 2 s
    assert abs(x[STEP + 1]) < 5.0  # for one step (the vehicle's own reaction to it is what remains)
    # 20 rad/s is within what the monitor believes (70 rad/s): the policy flies it, and recovers
    assert not events and set(log.sources) == {"policy"} and judged["success"]


def test_gyro_spike_beyond_any_gyro_is_flown_blind_then_handed_back_to_the_policy():
    log, events, judged, _, _ = fly("gyro-spike@2s:100")
    assert events["obs_out_of_range"] == 1 and events["blind_steps"] == 1
    assert log.sources[:STEP] == ["policy"] * STEP and handed_back(log, events)
    assert judged["success"] and not judged["crashed"] and log.failsafe is None


def test_stuck_accelerometer_changes_nothing_the_node_flies_on(clean):
    log, events, judged, seen, fired = fly("accel-stuck@2s")
    acc = np.array([(m.xacc, m.yacc, m.zacc) for m in seen["HIL_SENSOR"]])
    assert fired["accel-stuck"] >= len(acc) - STEP and np.all(acc[STEP:] == acc[STEP])  # stuck from 2 s on
    assert not np.all(acc[:STEP] == acc[STEP])
    # the node flies on HIL_STATE_QUATERNION and the gyro: the same flight, bit for bit
    assert np.array_equal(np.asarray(log.states), np.asarray(clean[0].states)) and not events and judged["success"]


def test_barometer_step_changes_nothing_the_node_flies_on(clean):
    log, events, judged, seen, _ = fly("baro-step@2s:5")
    alt = np.array([m.pressure_alt for m in seen["HIL_SENSOR"]])
    alt0 = np.array([m.pressure_alt for m in clean[3]["HIL_SENSOR"]])
    assert np.allclose(alt[STEP:] - alt0[STEP:], 5.0, atol=1e-3) and np.array_equal(alt[:STEP], alt0[:STEP])
    assert np.array_equal(np.asarray(log.states), np.asarray(clean[0].states)) and not events and judged["success"]


def test_frozen_position_for_half_a_second_is_flown_by_the_policy_on_the_stale_position():
    log, events, judged, seen, fired = fly("pos-freeze@2s+0.5s")
    lat = np.array([(m.lat, m.lon, m.alt) for m in seen["HIL_STATE_QUATERNION"]])
    assert fired == {"pos-freeze": 50}
    assert np.all(lat[STEP : STEP + 50] == lat[STEP - 1]) and not np.all(lat[STEP + 50] == lat[STEP - 1])
    # a frozen position is a valid state: the policy flies on it, and holds once it moves again
    assert not events and set(log.sources) == {"policy"} and judged["success"]


def test_state_dropout_is_flown_on_the_estimate_and_the_hover_holds():
    log, events, judged, seen, fired = fly("state-dropout@2s+0.5s")
    assert fired["state-dropout"] == 50 and len(seen["HIL_STATE_QUATERNION"]) == 450  # none for 0.5 s
    # every step is answered: the half second without a state is flown by the policy on the node's
    # estimate from HIL_SENSOR, and the policy flies on when the states come back
    assert log.state_lost_steps == 50 and log.replies == 500 and "sensor_without_state" not in log.dropped
    assert log.sources[:STEP] == ["policy"] * STEP and log.sources[STEP : STEP + 50] == ["estimate"] * 50
    assert set(log.sources[STEP + 50 :]) == {"policy"} and not events
    assert [h[2].split(":")[0] for h in log.handovers] == ["state lost", "state back"]
    assert judged["success"] and log.failsafe is None


def test_nan_in_the_state_is_dropped_flown_blind_then_handed_back_to_the_policy():
    log, events, judged, _, fired = fly("nan@2s:state")
    assert fired == {"nan": 1} and log.dropped["state_non_finite"] == 1 and log.blind_replies == 1
    assert events["state_dropped"] == 1
    assert log.sources[:STEP] == ["policy"] * STEP and handed_back(log, events)
    assert judged["success"] and log.failsafe is None


def test_nan_in_the_gyro_is_refused_by_the_monitor_and_flown_blind():
    log, events, judged, _, _ = fly("nan@2s:gyro")
    assert events["obs_nonfinite"] == 1 and events["blind_steps"] == 1 and handed_back(log, events)
    assert judged["success"] and np.all(np.isfinite(np.asarray(log.commands)))


# --- the spec ---------------------------------------------------------------------------------
def test_a_fault_spec_reads_kinds_times_durations_and_sizes():
    assert parse_faults("gyro-spike@2s,pos-freeze@1500ms+0.5s,baro-step@1:5,nan@3s:gyro") == (
        SensorFault("gyro-spike", 2.0, None),
        SensorFault("pos-freeze", 1.5, 0.5),
        SensorFault("baro-step", 1.0, None, 5.0),
        SensorFault("nan", 3.0, None, "gyro"),
    )
    f = parse_faults("baro-step@1s+2s:-3")
    assert parse_faults(",".join(map(str, f))) == f


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ("", "empty spec"),
        ("gyro-spike", "has no @START"),
        ("wobble@2s", "unknown fault 'wobble'"),
        ("gyro-spike@soon", "is not a time"),
        ("pos-freeze@2s+0s", "must be > 0"),
        ("nan@2s:motor", "names no field"),
        ("accel-stuck@2s:3", "takes no :SIZE"),
        ("baro-step@2s:nan", "is not a number"),
    ],
)
def test_a_bad_fault_spec_is_one_line(spec, says):
    with pytest.raises(FaultSpecError) as e:
        parse_faults(spec)
    assert "\n" not in str(e.value) and says in str(e.value) and "expected KIND@START" in str(e.value)


def test_quad_sitl_refuses_a_bad_fault_in_one_line(capsys):
    assert quad_sitl(["--sensor-fault", "gyro-spike@later"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--sensor-fault" in err and "is not a time" in err and "Traceback" not in err
