"""The node's estimate from HIL_SENSOR alone (`autopilot.dead_reckoning`): what it keeps, what it
corrects, what it refuses."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from quadpilot.autopilot.dead_reckoning import PRESSURE_ALT_UPDATED, InertialEstimate
from quadpilot.autopilot.state_loss import StateLossConfig

G = 9.81
HOVER = [0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0]


def sensor(t_us, gyro=(0.0, 0.0, 0.0), acc_flu=(0.0, 0.0, G), baro=None):
    """A HIL_SENSOR as pymavlink gives it: FRD (y and z negated), the barometer flagged when given."""
    return SimpleNamespace(
        time_usec=t_us,
        xgyro=gyro[0], ygyro=-gyro[1], zgyro=-gyro[2],
        xacc=acc_flu[0], yacc=-acc_flu[1], zacc=-acc_flu[2],
        pressure_alt=0.0 if baro is None else baro,
        fields_updated=0x3F | (PRESSURE_ALT_UPDATED if baro is not None else 0),
    )  # fmt: skip


def test_a_hovering_vehicle_stays_where_it_was():
    est = InertialEstimate(HOVER, 0, G, baro_alt=402.0)
    for k in range(1, 201):  # 2 s at 100 Hz of a perfect hover
        est.update(sensor(k * 10_000, baro=402.0))
    s = est.state()
    assert np.allclose(s[:6], HOVER[:6], atol=1e-9) and s[8] == pytest.approx(0.3) and est.plausible


def test_the_gyro_turns_the_attitude():
    est = InertialEstimate(HOVER, 0, G)
    for k in range(1, 51):  # 0.5 rad/s of yaw for 0.5 s
        est.update(sensor(k * 10_000, gyro=(0.0, 0.0, 0.5)))
    assert est.state()[8] == pytest.approx(0.3 + 0.25, abs=1e-9)


def test_the_accelerometer_levels_a_wrong_attitude_and_the_barometer_corrects_the_height():
    tilted = [*HOVER[:6], 0.1, 0.0, 0.0, 0.0, 0.0, 0.0]  # started 0.1 rad off level
    est = InertialEstimate(tilted, 0, G, baro_alt=400.0)  # 2 m up is 400 m on the barometer
    for k in range(1, 1001):  # 10 s of a level hover, the barometer reading 1 m lower than the start
        est.update(sensor(k * 10_000, baro=399.0))
    s = est.state()
    assert abs(s[6]) < 0.01 and s[2] == pytest.approx(1.0, abs=0.05)


def test_a_sample_that_is_no_measurement_is_not_used():
    est = InertialEstimate(HOVER, 0, G)
    est.update(sensor(10_000, gyro=(math.nan, 0.0, 0.0)))
    est.update(sensor(20_000, acc_flu=(0.0, 0.0, 1e6)))
    assert est.bad_samples == 2 and np.isfinite(est.state()).all() and est.state()[2] == pytest.approx(2.0)


def test_a_tilt_no_hover_has_makes_the_estimate_implausible():
    est = InertialEstimate(HOVER, 0, G)
    for k in range(1, 30):  # 30 rad/s of roll: past 60 degrees within 0.04 s
        est.update(sensor(k * 10_000, gyro=(30.0, 0.0, 0.0)))
    assert not est.plausible and "tilt" in est.implausible


@pytest.mark.parametrize(
    "kw", [{"policy_s": 3.0, "descend_s": 2.0}, {"descent_speed": 2.0}, {"land_speed": 0.9}, {"arm_wait_s": -1.0}]
)
def test_state_loss_settings_out_of_range_are_refused(kw):
    with pytest.raises(ValueError):
        StateLossConfig(**kw)
