"""The step and figure-eight flights (`core.maneuver`): their targets, and what they measure, on
trajectories whose answers are known."""

import math

import numpy as np
import pytest

from quadpilot.core.maneuver import SETTLE_BAND_M, FigureEight, Step, parse_maneuver
from quadpilot.core.state import POS

DT = 0.01


def _states(positions: np.ndarray) -> np.ndarray:
    s = np.zeros((len(positions), 12))
    s[:, POS] = positions
    return s


def _along_x(x: np.ndarray, home=(0.0, 0.0, 2.0)) -> np.ndarray:
    return _states(np.stack([home[0] + x, np.full_like(x, home[1]), np.full_like(x, home[2])], axis=1))


def test_a_first_order_step_has_no_overshoot_and_settles_when_its_error_enters_the_band():
    t = np.arange(500) * DT
    tau = 0.3
    m = Step(1.0).measure(_along_x(1.0 - np.exp(-t / tau)), DT)
    assert m["overshoot_m"] == 0.0 and m["overshoot_pct"] == 0.0
    # the error e^(−t/τ) first drops to 5 cm at t = τ·ln 20; rise 10 → 90 % is τ·ln 9
    assert m["settling_s"] == pytest.approx(tau * math.log(1.0 / SETTLE_BAND_M), abs=DT)
    assert m["rise_s"] == pytest.approx(tau * math.log(9.0), abs=DT)


def test_a_step_that_overshoots_reports_how_far_and_settles_only_after_it_comes_back():
    t = np.arange(500) * DT
    x = np.interp(t, [0.0, 0.5, 1.0, 2.0, 5.0], [0.0, 1.0, 1.2, 1.0, 1.0])
    m = Step(1.0).measure(_along_x(x), DT)
    assert m["overshoot_m"] == pytest.approx(0.2) and m["overshoot_pct"] == pytest.approx(20.0)
    # back within 5 cm of the target on the way down at x = 1.05: t = 1.75 s
    assert m["settling_s"] == pytest.approx(1.75 + DT, abs=1.5 * DT)


def test_a_step_still_outside_the_band_at_the_end_never_settled():
    t = np.arange(500) * DT
    m = Step(1.0).measure(_along_x(0.9 * (1.0 - np.exp(-t / 0.3))), DT)
    assert math.isnan(m["settling_s"]) and m["overshoot_m"] == 0.0


def test_the_step_target_is_one_metre_east_of_home_from_the_first_step():
    s = Step()
    for k in (0, 1, 499):
        p, v = s.target_at(k)
        np.testing.assert_array_equal(p, [1.0, 0.0, 2.0])
        np.testing.assert_array_equal(v, 0.0)


@pytest.mark.parametrize("speed", [1.0, 2.0, 4.0])
def test_the_figure_eight_velocity_is_the_derivative_of_its_position_and_peaks_at_its_speed(speed):
    f = FigureEight(speed)
    n = round(f.duration_s / DT)
    p = np.array([f.target_at(k)[0] for k in range(n)])
    v = np.array([f.target_at(k)[1] for k in range(n)])
    central = (p[2:] - p[:-2]) / (2 * DT)
    np.testing.assert_allclose(central, v[1:-1], atol=2e-3 * speed**2)  # O(dt²) of the curve's jerk
    after = np.linalg.norm(v[round(f.ramp_s / DT) :], axis=1)
    assert after.max() == pytest.approx(speed, rel=1e-4)
    np.testing.assert_allclose(v[0], 0.0)  # from rest
    assert np.all(p[:, 2] == 2.0)  # level, at home's height
    # mc_raptor's shape: x = A sin θ, y = B sin 2θ, so x spans ±A and y ±B over the lap
    assert np.ptp(p[:, 0]) == pytest.approx(2 * f.a, rel=1e-3) and np.ptp(p[:, 1]) == pytest.approx(2 * f.b, rel=1e-3)


def test_the_figure_eight_speeds_up_smoothly_and_ends_its_lap_where_the_lap_began():
    f = FigureEight(2.0)
    k_ramp = round(f.ramp_s / DT)
    speeds = [np.linalg.norm(f.target_at(k)[1]) for k in range(k_ramp + 2)]
    _, rate = f.theta(f.ramp_s)
    assert rate == f.rate and f.theta(f.ramp_s - 1e-9)[1] == pytest.approx(f.rate)  # continuous at the ramp's end
    assert speeds[0] == 0.0 and speeds[k_ramp // 2] < speeds[k_ramp]
    start, end = f.target_at(k_ramp)[0], f.target_at(round(f.duration_s / DT))[0]
    np.testing.assert_allclose(start, end, atol=f.speed * DT)


def test_tracking_error_is_measured_over_the_lap_after_the_ramp_only():
    f = FigureEight(1.0)
    n = round(f.duration_s / DT)
    targets = np.array([f.target_at(k)[0] for k in range(n)])
    flown = targets.copy()
    k0 = round(f.ramp_s / DT)
    flown[:k0, 0] += 1.0  # far off during the ramp: not counted
    assert f.measure(_states(flown), targets, DT) == {"tracking_rms_m": 0.0, "tracking_max_m": 0.0}
    flown[k0:, 1] += 0.1  # 10 cm off across the lap
    m = f.measure(_states(flown), targets, DT)
    assert m["tracking_rms_m"] == pytest.approx(0.1) and m["tracking_max_m"] == pytest.approx(0.1)


@pytest.mark.parametrize(
    ("text", "expected"), [("step", Step(1.0)), ("step:0.5", Step(0.5)), ("figure8:4", FigureEight(4.0))]
)
def test_maneuvers_are_named_as_quad_sitl_takes_them(text, expected):
    assert parse_maneuver(text) == expected


@pytest.mark.parametrize(
    "text",
    [
        "figure8",
        "figure8:0",
        "figure8:-1",
        "figure8:nan",
        "figure8:1e-320",
        "figure8:25",
        "step:0",
        "step:1e6",
        "step:x",
        "loop",
    ],
)
def test_a_maneuver_that_cannot_be_flown_is_refused_saying_what_is_expected(text):
    with pytest.raises(ValueError, match="expected step, step:METRES"):
        parse_maneuver(text)


def test_a_summary_of_no_flight_has_every_figure_as_nan_and_prints():
    """quad-sitl interrupted during its first flight summarises nothing: the figures are NaN, not missing."""
    from quadpilot.core.maneuver import summarise, summary_line

    for m in (Step(), FigureEight(2.0)):
        s = summarise(m, [])
        counts = ("not_settled", "laps_not_flown")
        figures = [v for k, v in s.items() if k not in ("maneuver", "maneuver_per_episode", *counts)]
        assert figures and all(math.isnan(v) for v in figures)
        assert summary_line(s)


def test_the_figure_eight_summary_measures_only_laps_flown_whole():
    """A flight that ended before the ramp and the lap did (a short --duration, a crash) is no lap:
    its figures stay out of the means, and a summary with no lap flown says so instead of a figure."""
    from quadpilot.core.maneuver import summarise, summary_line

    f = FigureEight(2.0)
    n = round(f.duration_s / DT)
    targets = np.array([f.target_at(k)[0] for k in range(n)])
    whole = _states(targets + np.array([0.0, 0.1, 0.0]))  # 10 cm off all along
    part = _states(targets[: n // 2] + np.array([0.0, 0.5, 0.0]))  # 50 cm off, half the lap
    s = summarise(f, [(whole, targets, DT), (part, targets[: n // 2], DT)])
    assert s["tracking_rms_m"] == pytest.approx(0.1) and s["laps_not_flown"] == 1
    assert "1 of 2 flights ended before their lap did" in summary_line(s)
    short = summarise(f, [(part, targets[: n // 2], DT)])
    line = summary_line(short)
    assert "tracking RMS" not in line and "lap not flown" in line
    assert f"{n // 2 * DT:.1f} s flown" in line and f"{f.duration_s:.1f} s" in line
