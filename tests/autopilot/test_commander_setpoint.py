"""The moving target (speed and lead bounds), the land detector (PX4's stages and thresholds), the
landing speed schedule and the return altitude, each against hand-worked cases."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from quadpilot.autopilot.modes import Return
from quadpilot.autopilot.param_protocol import PARAMS
from quadpilot.autopilot.setpoint import LandDetector, LandLimits, Mover, collective_thrust, land_speed

DT = 0.01
DEFAULTS = {p.name: p.default for p in PARAMS}


def test_reference_moves_at_the_horizontal_and_vertical_limits_and_arrives_exactly():
    m = Mover(lead_m=0.75)
    m.reset([0.0, 0.0, 1.0])
    m.set_goal([10.0, 0.0, 1.0], 2.0, 1.0, 0.5)
    m.update(DT, m.ref)  # the vehicle exactly on the reference: no lead braking
    assert m.velocity[0] == pytest.approx(2.0)
    m.set_goal([0.0, 0.0, 11.0], 2.0, 1.0, 0.5)
    m.update(DT, m.ref)
    assert np.linalg.norm(m.velocity[:2]) <= 2.0 + 1e-9 and m.velocity[2] == pytest.approx(1.0)
    m.set_goal([0.0, 0.0, -5.0], 2.0, 1.0, 0.5)
    for _ in range(10000):
        m.update(DT, m.ref)
        assert m.velocity[2] >= -0.5 - 1e-9
    assert np.array_equal(m.ref, [0.0, 0.0, -5.0]) and m.at_goal


@settings(derandomize=True, database=None, deadline=None, max_examples=50)
@given(
    goal=st.tuples(*[st.floats(-50, 50)] * 3),
    speeds=st.tuples(st.floats(0.5, 20), st.floats(0.5, 8), st.floats(0.5, 4)),
    lead=st.floats(0.2, 1.5),
    tau=st.floats(0.05, 2.0),
)
def test_reference_never_leads_the_vehicle_by_more_than_the_lead_distance(goal, speeds, lead, tau):
    """Whatever the distance, the vehicle (a first-order lag) never sees its target further than
    `lead` plus one step of travel away: the observation stays in the trained range."""
    m = Mover(lead_m=lead)
    pos = np.zeros(3)
    m.reset(pos)
    m.set_goal(goal, *speeds)
    v_max = math.hypot(speeds[0], max(speeds[1:]))
    for _ in range(1500):
        ref = m.update(DT, pos)
        assert np.linalg.norm(ref - pos) <= lead + v_max * DT + 1e-9
        pos = pos + (ref - pos) * (1 - math.exp(-DT / tau))


def test_reference_waits_for_a_vehicle_that_does_not_move():
    m = Mover(lead_m=0.75)
    m.reset([0.0, 0.0, 0.0])
    m.set_goal([0.0, 0.0, 5.0], 5.0, 3.0, 1.5)
    for _ in range(2000):
        m.update(DT, [0.0, 0.0, 0.0])
    assert 0.7 < m.ref[2] <= 0.75 and m.velocity[2] < 0.01


def test_a_new_goal_does_not_move_the_reference():
    m = Mover(lead_m=0.75)
    m.reset([1.0, 2.0, 3.0])
    m.set_goal([5.0, 5.0, 5.0], 5, 3, 1.5)
    m.update(DT, [1.0, 2.0, 3.0])
    before = m.ref.copy()
    m.set_goal([-5.0, 0.0, 3.0], 5, 3, 1.5)
    assert np.array_equal(m.ref, before)
    m.stop()
    m.update(DT, before)
    assert np.array_equal(m.ref, before) and m.at_goal


def test_lead_must_be_positive():
    with pytest.raises(ValueError, match="lead distance"):
        Mover(lead_m=0.0)


def test_land_speed_schedule():
    # MPC_Z_V_AUTO_DN above MPC_LAND_ALT1, MPC_LAND_SPEED below MPC_LAND_ALT2, linear between
    assert land_speed(20.0, 1.5, 0.7, 10.0, 5.0) == 1.5
    assert land_speed(2.0, 1.5, 0.7, 10.0, 5.0) == 0.7
    assert land_speed(7.5, 1.5, 0.7, 10.0, 5.0) == pytest.approx(1.1)


def test_collective_thrust_is_the_mean_square_of_the_rotor_commands():
    assert collective_thrust([0.5, 0.5, 0.5, 0.5]) == pytest.approx(0.25)
    assert collective_thrust([1.0, 0.0, 2.0, -1.0]) == pytest.approx(0.5)  # clipped to [0, 1]


# --- land detector -------------------------------------------------------------------------------

LIM = LandLimits(0.12, 0.45, 0.25, 1.5, math.radians(20.0), 0.5, 1.0)
STILL = np.zeros(3)


def run(det: LandDetector, seconds: float, **kw) -> list[bool]:
    args = dict(armed=True, altitude=0.0, velocity=STILL, body_rates=STILL, thrust=0.0, in_descend=True, lim=LIM)
    args.update(kw)
    out = []
    t0 = getattr(det, "_t", 0.0)
    for k in range(round(seconds / DT)):
        det._t = t0 + (k + 1) * DT
        out.append(det.update(det._t, **args))
    return out


def airborne() -> LandDetector:
    det = LandDetector()
    run(det, 0.1, thrust=0.45, altitude=1.0, in_descend=False)  # taking off: hover thrust
    assert not det.landed
    return det


def test_touchdown_is_landed_after_three_stages_of_a_third_of_the_trigger_time():
    det = airborne()
    states = run(det, 1.5)
    first = states.index(True)
    assert 0.95 <= (first + 1) * DT <= 1.05  # ground contact, maybe landed, landed: 1/3 s each


@pytest.mark.parametrize(
    "kw",
    [
        {"thrust": 0.33},  # above MPC_THR_MIN + 0.6 (hover − min) = 0.318
        {"velocity": np.array([0.0, 0.0, -0.3])},  # still descending: > LNDMC_Z_VEL_MAX
        {"velocity": np.array([1.6, 0.0, 0.0])},  # sliding: > LNDMC_XY_VEL_MAX
        {"altitude": 0.6},  # above ground_alt_max_m: cannot be standing on the ground
        {"in_descend": False},  # no descent commanded: not a landing
        {"body_rates": np.array([0.4, 0.0, 0.0])},  # rolling at 23 °/s > LNDMC_ROT_MAX
        {"thrust": 0.2},  # ground contact, but above MPC_THR_MIN + 0.1 (hover − min): not maybe landed
    ],
)
def test_each_condition_alone_keeps_the_vehicle_in_the_air(kw):
    det = airborne()
    assert not any(run(det, 3.0, **kw))


def test_ground_contact_needs_thrust_below_sixty_percent_of_the_hover_range():
    # MPC_THR_MIN + 0.6 (MPC_THR_HOVER − MPC_THR_MIN) = 0.12 + 0.6 · 0.33 = 0.318
    below, above = airborne(), airborne()
    run(below, 1.0, thrust=0.31)
    run(above, 1.0, thrust=0.33)
    assert below.contact and not below.landed  # contact, but not maybe landed (thrust > 0.153)
    assert not above.contact


def test_thrust_leaves_the_ground_at_once_and_disarmed_is_landed():
    det = LandDetector()
    assert all(run(det, 0.5, thrust=0.0, in_descend=False))  # armed on the ground, idle
    assert run(det, DT, thrust=0.45, in_descend=False) == [False]  # take-off thrust: airborne at once
    assert run(det, DT, armed=False, thrust=0.45, altitude=5.0) == [True]


# --- return altitude -----------------------------------------------------------------------------


def rtl(pos, **params) -> float:
    return Return.altitude(np.array(pos, float), {**DEFAULTS, **params})


def test_return_altitude_follows_px4s_cone():
    # inside RTL_MIN_DIST: RTL_DESCEND_ALT
    assert rtl([3, 0, 2], RTL_MIN_DIST=5, RTL_DESCEND_ALT=4) == 4
    # higher than RTL_RETURN_ALT already: stay there
    assert rtl([30, 0, 70]) == 70
    # no cone: RTL_RETURN_ALT
    assert rtl([30, 0, 2], RTL_CONE_ANG=0, RTL_RETURN_ALT=8, RTL_DESCEND_ALT=1) == 8
    # 45° cone at 6 m: at least 6 m above home, at most RTL_RETURN_ALT, never below RTL_DESCEND_ALT
    assert rtl([6, 0, 2], RTL_MIN_DIST=0.5, RTL_RETURN_ALT=10, RTL_DESCEND_ALT=1) == pytest.approx(6.0)
    assert rtl([6, 0, 2], RTL_MIN_DIST=0.5, RTL_RETURN_ALT=5, RTL_DESCEND_ALT=1) == pytest.approx(5.0)
    assert rtl([6, 0, 7], RTL_MIN_DIST=0.5, RTL_RETURN_ALT=10, RTL_DESCEND_ALT=1) == pytest.approx(7.0)
    assert rtl([6, 0, 2], RTL_MIN_DIST=0.5, RTL_RETURN_ALT=10, RTL_DESCEND_ALT=9) == 9
