"""The simulator's ground plane (`simulator.plant`) and `--start landed|air`.

The ground is the plane z = 0 of the simulator's world (ENU); the vehicle touches it with its centre
of mass. A vehicle on it stays there with its motors off, one dropped on it stops on it (never more
than 1 mm below; here never below at all), one with thrust above its weight lifts off, friction
(Coulomb, μ = plant.GROUND_FRICTION) stops a sliding one, and the accelerometer reads the ground's
push: +g up at rest, as a real IMU does. Each test fails when the ground code is taken out."""

import contextlib
import math
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink import mavutil

from quadpilot.link import wire
from quadpilot.link.transport import new_codec
from quadpilot.simulator import (
    SimConfig,
    Simulator,
    UsageError,
    build_sim_parser,
    config_from_args,
    main_sim_only,
)
from quadpilot.simulator.plant import GROUND_FRICTION, Plant, landed_state

G = 9.81
VEHICLE = SimConfig().vehicle_params  # the seed quadrotor, 0.665 kg, no motor lag
OFF = np.zeros(4)


def plant(dt: float = 0.01, vehicle=VEHICLE, **kw) -> Plant:
    return Plant(vehicle, dt, **kw)


# --- at rest -------------------------------------------------------------------------------------


def test_a_landed_vehicle_with_its_motors_off_stays_exactly_where_it_is_for_10_s():
    p = plant()
    p.reset(landed_state(yaw=0.7))
    assert np.all(p.rotor == 0.0) and p.on_ground  # a landed start: rotors at rest
    start = p.state.copy()
    for _ in range(1_000):  # 10 s
        p.step(OFF)
        np.testing.assert_allclose(p.state[0:3], start[0:3], rtol=0, atol=1e-6)  # no sinking, no drift
        np.testing.assert_allclose(p.state[6:9], start[6:9], rtol=0, atol=1e-6)  # level, heading kept
        assert np.all(p.state[3:6] == 0.0) and np.all(p.state[9:12] == 0.0)  # no bounce, no spin
    assert p.on_ground and p.impact_speed == pytest.approx(G * 0.01)  # the ground carries the weight


def test_static_friction_holds_a_landed_vehicle_in_a_side_wind():
    """3 m/s of wind through the default drag pushes with 0.6 N, under μ·m·g = 3.3 N: it stays."""
    cfg = SimConfig(wind=(3.0, -1.0, 0.0))
    p = plant(vehicle=cfg.vehicle_params, wind=cfg.wind)
    p.reset(landed_state())
    for _ in range(500):
        p.step(OFF)
    np.testing.assert_array_equal(p.state, landed_state())
    f = p.specific_force_flu()  # the feet hold it against the wind: the wind's force and friction cancel
    np.testing.assert_allclose(f, [0.0, 0.0, G], atol=1e-9)


def test_the_accelerometer_reads_plus_g_up_on_the_ground():
    p = plant()
    p.reset(landed_state(yaw=-2.0))
    np.testing.assert_allclose(p.specific_force_flu(), [0.0, 0.0, G], atol=1e-12)  # from the first step
    for _ in range(100):
        p.step(OFF)
        np.testing.assert_allclose(p.specific_force_flu(), [0.0, 0.0, G], atol=1e-9)


# --- touchdown -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("dt", "z0", "vz0"),
    [(0.01, 2.0, 0.0), (0.004, 2.0, 0.0), (0.01, 1.0, -5.0), (0.01, 0.03, -4.0), (0.004, 0.5, -8.0)],
    ids=["drop-2m-100Hz", "drop-2m-250Hz", "5mps-from-1m", "4mps-from-3cm", "8mps-250Hz"],
)
def test_a_falling_vehicle_stops_on_the_ground_and_stays(dt, z0, vz0):
    """Motors off, falling at up to 8 m/s: never below the plane (the bound is 1 mm; it is 0), at
    rest from the step it touches, and still there 2 s later; all finite."""
    p = plant(dt)
    p.reset(np.r_[0.0, 0.0, z0, 0.0, 0.0, vz0, np.zeros(6)])
    touchdown, lowest = None, math.inf
    for n in range(1, round(3.0 / dt) + 1):
        p.step(OFF)
        assert np.all(np.isfinite(p.state))
        lowest = min(lowest, p.state[2])
        assert p.state[2] >= -1e-3
        if touchdown is None and p.on_ground:
            touchdown, speed = n * dt, p.impact_speed
        if touchdown is not None:
            assert p.state[2] == 0.0 and np.all(p.state[3:6] == 0.0), f"moved after touchdown at {n * dt:.3f} s"
    assert touchdown is not None and lowest == 0.0
    t_fall = (vz0 + math.sqrt(vz0 * vz0 + 2 * G * z0)) / G  # continuous time to the plane
    assert t_fall <= touchdown < t_fall + dt + 1e-9  # touches down in the step that would cross it
    assert speed == pytest.approx(-vz0 + G * touchdown, abs=1e-9)  # all of the vertical speed, no bounce


def test_a_tilted_touchdown_with_horizontal_speed_is_levelled_and_stopped_by_friction():
    """Tilted 17° and 11°, spinning, moving 3.2 m/s sideways and 2 m/s down: on touchdown it stands
    level with its heading kept, loses μ times the vertical speed of its horizontal speed at the
    impact (Coulomb's law for an impulse), then slides decelerating at μ·g, which the accelerometer
    feels, and stops."""
    dt, mu = 0.01, GROUND_FRICTION
    p = plant(dt)
    p.reset(np.r_[0.0, 0.0, 0.5, 3.0, 1.0, -2.0, 0.3, -0.2, 1.0, 0.5, 0.2, 0.1])
    before, n = p.state.copy(), 0
    while not p.on_ground:
        before = p.state.copy()
        p.step(OFF)
        n += 1
        assert n < 100, "never touched down"
    v_hit = before[3:5]  # no thrust, no drag: the horizontal velocity is constant in the air
    v_down = -before[5] + G * dt
    s = p.state
    assert s[2] == 0.0 and s[5] == 0.0 and s[6] == s[7] == 0.0 and np.all(s[9:12] == 0.0)
    assert abs(s[8] - before[8]) < 0.05  # the heading kept (one step of yaw rate, at most)
    speed = float(np.hypot(*s[3:5]))
    assert speed == pytest.approx(np.hypot(*v_hit) - mu * v_down, abs=1e-9)
    np.testing.assert_allclose(s[3:5] / speed, v_hit / np.hypot(*v_hit), atol=1e-12)  # friction opposes motion
    sliding = 0
    while speed > 0.0:
        p.step(OFF)
        new = float(np.hypot(*p.state[3:5]))
        assert new == pytest.approx(max(speed - mu * G * dt, 0.0), abs=1e-9)  # Coulomb: μ·g
        if new > 0.0:  # the accelerometer feels the friction, against the motion, in the body frame
            yaw = p.state[8]
            v_body = np.array([[math.cos(yaw), math.sin(yaw)], [-math.sin(yaw), math.cos(yaw)]]) @ p.state[3:5]
            np.testing.assert_allclose(p.specific_force_flu()[0:2], -mu * G * v_body / new, atol=1e-9)
        speed, sliding = new, sliding + 1
        assert sliding < 200, "friction did not stop it"
    assert sliding * dt == pytest.approx((np.hypot(*v_hit) - mu * v_down) / (mu * G), abs=dt)
    rest = p.state.copy()
    for _ in range(200):
        p.step(OFF)
    np.testing.assert_array_equal(p.state, rest)


# --- lift-off ------------------------------------------------------------------------------------


def test_the_ground_holds_the_vehicle_until_its_thrust_exceeds_its_weight_then_it_lifts_off():
    """Rotors spinning up from rest (motor lag 50 ms) at full command: on the plane, reading +g, while
    the thrust is below the weight; off it from the first step the thrust exceeds it. The thrust of a
    step is the mean of ω² over it, ω = 1 − e^(−t/τ): ∫ω² dt over the step, over its length."""
    tau = 0.05
    vehicle = SimConfig(motor_tau=tau).vehicle_params
    p = plant(vehicle=vehicle)
    p.reset(landed_state())
    dt = p.dt

    def mean_square(t0: float) -> float:  # of ω = 1 − e^(−t/τ) over [t0, t0 + dt]
        def integral(t):
            return t + 2 * tau * math.exp(-t / tau) - tau / 2 * math.exp(-2 * t / tau)

        return (integral(t0 + dt) - integral(t0)) / dt

    lifted = None
    for n in range(1, 101):
        p.step(np.ones(4))
        above = mean_square((n - 1) * dt) > vehicle.hover_command**2  # thrust ∝ ω²: above the weight
        assert (p.state[2] > 0.0) == above and p.on_ground == (not above)
        if not above:  # held, reading +g; or, in the step the rotors pass the hover speed, their thrust
            reading = max(G, p.thrust_n / vehicle.mass)  # (the ground pushes no more; lift-off next step)
            np.testing.assert_allclose(p.specific_force_flu(), [0.0, 0.0, reading], atol=1e-9)
        elif lifted is None:
            lifted = n
    # ω passes the hover speed 0.677 at t = 0.0565 s, the mean of ω² passes its square within the 7th step
    assert lifted == 7
    assert p.state[2] > 3.0 and np.all(np.isfinite(p.state))


def test_just_below_hover_thrust_stays_down_and_just_above_lifts_off():
    for scale, flies in ((0.99, False), (1.01, True)):
        p = plant()
        p.reset(landed_state())
        for _ in range(100):
            p.step(np.full(4, VEHICLE.hover_command * scale))
        assert (p.state[2] > 0.0) == flies and p.on_ground == (not flies)
        assert p.state[2] >= 0.0 and np.all(p.state[[0, 1, 3, 4, 6, 7]] == 0.0)


# --- any flight stays above the ground --------------------------------------------------------------

_command = st.lists(st.sampled_from([0.0, 0.3, 0.6, 0.7, 1.0]), min_size=4, max_size=4)


@settings(derandomize=True, database=None, deadline=None, max_examples=40)
@given(
    z=st.floats(0.0, 5.0),
    v=st.lists(st.floats(-8.0, 8.0), min_size=3, max_size=3),
    tilt=st.lists(st.floats(-1.2, 1.2), min_size=2, max_size=2),
    rates=st.lists(st.floats(-6.0, 6.0), min_size=3, max_size=3),
    segments=st.lists(st.tuples(_command, st.integers(1, 60)), min_size=1, max_size=6),
)
def test_any_flight_stays_on_or_above_the_ground_and_comes_to_rest_with_the_motors_off(z, v, tilt, rates, segments):
    p = plant()
    p.reset(np.r_[0.0, 0.0, z, v, tilt, 0.0, rates])
    for command, steps in segments:
        for _ in range(steps):
            p.step(np.asarray(command, float))
            assert p.state[2] >= 0.0 and np.all(np.isfinite(p.state))
    for _ in range(800):  # 8 s with the motors off: it falls, lands, slides and stops
        p.step(OFF)
        assert p.state[2] >= 0.0
    assert p.on_ground and p.state[2] == 0.0 and np.all(p.state[3:6] == 0.0)
    assert p.state[6] == p.state[7] == 0.0


# --- --start landed|air ----------------------------------------------------------------------------


def test_start_flag_and_config_field():
    parse = build_sim_parser().parse_args
    assert SimConfig().start == "air" and config_from_args(parse([])).start == "air"
    cfg = config_from_args(parse(["--start", "landed"]))
    assert cfg.start == "landed"
    state, _ = cfg.start_state(0)
    np.testing.assert_array_equal(state, np.zeros(12))  # at home, on the ground, level
    air, _ = SimConfig().start_state(0)
    assert air[2] > 0.9  # today's start: in flight around the 2 m target
    with pytest.raises(ValueError, match="start must be one of"):
        SimConfig(start="sky")
    with pytest.raises(ValueError, match="not both"):
        SimConfig(start="landed", initial_state=(0.0,) * 12)
    with pytest.raises(UsageError, match="invalid choice"):
        parse(["--start", "sky"])


def test_sim_only_cli_refuses_a_bad_start_in_one_line(capsys):
    assert main_sim_only(["--start", "upside-down"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--start" in err and "'landed'" in err


@contextlib.contextmanager
def serving(cfg: SimConfig):
    sim = Simulator(cfg)
    port = sim.bind().port
    result: dict = {}
    thread = threading.Thread(target=lambda: result.setdefault("stats", sim.serve()), daemon=True)
    thread.start()
    try:
        yield port, result
    finally:
        sim.stop()
        thread.join(5.0)
        assert not thread.is_alive(), "simulator did not stop"


def read_step(c, timeout: float = 2.0) -> dict:
    """One step's messages by type, up to and including HIL_SENSOR."""
    msgs, deadline = {}, time.monotonic() + timeout
    while "HIL_SENSOR" not in msgs:
        left = deadline - time.monotonic()
        assert left > 0, f"no HIL_SENSOR within {timeout} s"
        m = c.recv_match(blocking=True, timeout=left)
        if m is not None:
            msgs[m.get_type()] = m
    return msgs


def test_a_landed_start_over_the_wire_rests_on_the_ground_reading_g_then_lifts_off():
    """`--start landed` served to a pymavlink peer: at home on the ground, the accelerometer reading
    −9.81 m/s² on FRD z, for 1 s of disarmed steps; then full thrust lifts it off."""
    cfg = SimConfig(listen="tcp:127.0.0.1:0", episodes=1, lockstep_timeout_s=2.0, start="landed")
    home = cfg.home
    with serving(cfg) as (port, result):
        c = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=1, source_component=1)
        c.mav = new_codec(c, 1, 1)
        c.mav.heartbeat_send(2, 12, 0, 0, 3)  # an autopilot's HEARTBEAT first (quadrotor, PX4)
        for n in range(151):
            m = read_step(c)
            s = wire.state_from_hil_state_quaternion(m["HIL_STATE_QUATERNION"], home)
            acc = m["HIL_SENSOR"]
            if n <= 100:
                np.testing.assert_allclose(s, np.zeros(12), atol=1e-6)
                assert (acc.xacc, acc.yacc) == (0.0, 0.0) and acc.zacc == pytest.approx(-G, abs=1e-5)
            controls = np.zeros(4) if n < 100 else np.ones(4)
            c.mav.hil_actuator_controls_send(**wire.actuator_controls_fields(controls, 0, n >= 100, True))
        assert s[2] > 0.5 and acc.zacc < -20.0  # 0.5 s of full thrust: climbing
        c.close()
        deadline = time.monotonic() + 5.0
        while "stats" not in result:
            assert time.monotonic() < deadline
            time.sleep(0.01)
    (rec,) = result["stats"].records
    np.testing.assert_array_equal(rec.initial_state, np.zeros(12))
    assert not rec.crashed and rec.steps == 151


def fly_held(start: str, z0: float, controls: np.ndarray, steps: int):
    """One episode started `start` (in the air: at rest `z0` m up) with `controls` held for `steps`
    steps by a pymavlink peer; (the simulator's episode record, the vehicle's last state)."""
    kw = {"initial_state": np.array([0, 0, z0, 0, 0, 0, 0, 0, 0, 0, 0, 0.0])} if start == "air" else {}
    cfg = SimConfig(listen="tcp:127.0.0.1:0", episodes=1, lockstep_timeout_s=2.0, start=start, **kw)
    with serving(cfg) as (port, result):
        c = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=1, source_component=1)
        c.mav = new_codec(c, 1, 1)
        c.mav.heartbeat_send(2, 12, 0, 0, 3)
        for _ in range(steps):
            m = read_step(c)
            c.mav.hil_actuator_controls_send(**wire.actuator_controls_fields(controls, 0, True, True))
        c.close()
        deadline = time.monotonic() + 5.0
        while "stats" not in result:
            assert time.monotonic() < deadline
            time.sleep(0.01)
    (rec,) = result["stats"].records
    return rec, wire.state_from_hil_state_quaternion(m["HIL_STATE_QUATERNION"], cfg.home)


@pytest.mark.parametrize("start", ["air", "landed"])
def test_touching_the_ground_is_a_crash_only_for_a_flight_started_in_the_air(start):
    """The ground holds the drone at z = 0, so the old "below ground" rule can no longer fire: a
    flight started in the air that falls onto the ground must still count as crashed, while a landed
    start, which rests on the ground by design, must not."""
    rec, _ = fly_held(start, 0.3, np.zeros(4), 60)  # motors off: from 0.3 m it is down in about 0.25 s
    assert rec.crashed == (start == "air")


def test_a_landed_start_may_fly_beyond_the_flight_area_without_counting_as_a_crash():
    """A landed start is commanded from a ground station and may be sent anywhere: climbing at full
    thrust far beyond the 5 m flight area around the episode's target is not a crash there, while
    the same climb started in the air is (the flight area still applies to scripted flights)."""
    crashed = {}
    for start in ("landed", "air"):
        rec, last = fly_held(start, 0.5, np.ones(4), 300)  # 3 s at full thrust: well over 5 m up
        assert last[2] > 8.0
        crashed[start] = rec.crashed
    assert crashed == {"landed": False, "air": True}
