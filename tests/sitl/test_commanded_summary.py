"""quad-sitl's printed summary of a commanded flight (--start landed) leaves out the hover verdict:
the flight has no fixed target, so a success rate or an error against the episode's start target
would be a number about nothing."""

from pathlib import Path

from quadpilot.sitl.summary import print_summary

BASE = {
    "episodes": 1,
    "steps": 3585,
    "steps_per_s": 100.0,
    "success_rate": 0.0,
    "crashes": 0,
    "position_rms_error_m": 0.3729,
    "mean_error_last_2s_m": 0.5,
    "final_distance_m": 0.5,
    "mean_abs_yaw_rate_last_2s_radps": 0.01,
    "max_abs_yaw_rate_last_2s_radps": 0.02,
    "max_heading_error_last_2s_deg": 3.0,
    "control_latency_p50_us": 660.0,
    "control_latency_p99_us": 1600.0,
    "packets_dropped": {},
    "failsafe_events": 0,
    "fallback_steps": 0,
    "hand_overs": 0,
    "hand_backs": 0,
}
COMMANDED = {
    "landed_state": "ON_GROUND",
    "armed": False,
    "mode": "HOLD",
    "disarmed_at_s": 30.2,
    "gcs_messages": 1234,
    "gcs_dropped": {},
}


def test_a_scripted_flight_prints_its_verdict(capsys):
    print_summary(BASE, Path("p.onnx"))
    out = capsys.readouterr().out
    assert "success rate            0%" in out and "RMS 37.29 cm" in out
    assert "worst heading error 3.0°" in out  # the yaw rule's figures
    assert "fallback steps 0 (hand-overs 0, hand-backs 0)" in out


def test_a_commanded_flight_prints_the_commander_line_and_no_hover_verdict(capsys):
    print_summary({**BASE, "commanded": [COMMANDED]}, Path("p.onnx"))
    out = capsys.readouterr().out
    assert "commanded flight        ON_GROUND, disarmed, mode HOLD, disarmed at 30.2 s" in out
    assert "success rate" not in out and "position error" not in out and "heading, last 2 s" not in out
