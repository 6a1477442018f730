"""The safety monitor's hand-over / hand-back state machine (`runtime.safety`), on its own: the
shipped hover policy (numpy backend) and a scripted fallback, observations chosen by kind.

The monitor hands over at once (a bad observation: flown blind; an envelope exit; a non-finite
command) and hands back once HAND_BACK_HOLD_S of consecutive valid observations lay inside the
recovery envelope (RECOVERY_FRACTION of the exit envelope). A non-finite command and the
MAX_ENVELOPE_EXITS-th envelope exit latch until reset(). A reference model written here from that
description predicts who flies every step of random sequences (Hypothesis)."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from quadpilot.core.observation import build_observation
from quadpilot.runtime.backends import Policy, load_policy
from quadpilot.runtime.safety import HAND_BACK_HOLD_S, MAX_ENVELOPE_EXITS, RECOVERY_FRACTION, SafetyMonitor

HOVER = Path(__file__).resolve().parents[2] / "models" / "hover" / "policy.onnx"
TARGET = np.array([0.0, 0.0, 2.0])


@pytest.fixture(scope="module")
def policy():
    return load_policy(HOVER, "numpy")


class ScriptedFallback:
    def __init__(self) -> None:
        self.resets = 0

    def act(self, obs):
        return np.full(4, 0.5)

    def reset(self):
        self.resets += 1


class NanOnce(Policy):
    """The hover file's metadata; answers NaN on call `bad_call` (0-based), else 0.5."""

    backend = "test-double"

    def __init__(self, info, bad_call: int) -> None:
        super().__init__(info)
        self.bad_call, self.calls = bad_call, 0

    def act_unchecked(self, x):
        self.calls += 1
        return np.full(4, np.nan if self.calls - 1 == self.bad_call else 0.5, np.float32)


def obs_at(offset=(0.0, 0.0, 0.0), roll_deg=0.0) -> np.ndarray:
    s = np.zeros((1, 12))
    s[0, 0:3] = TARGET + np.asarray(offset, float)
    s[0, 6] = np.radians(roll_deg)
    return build_observation(s, TARGET)[0]


KINDS = {
    "home": obs_at(),  # inside the recovery envelope
    "between": obs_at((3.5, 0.0, 0.0)),  # inside the 5 m exit envelope, outside the 2.5 m recovery one
    "tilted": obs_at(roll_deg=45.0),  # inside the 60° exit envelope, outside the 30° recovery one
    "outside": obs_at((0.0, 0.0, 6.0)),  # beyond the exit envelope
    "bad": np.full(obs_at().shape, np.nan, np.float32),  # flown blind
}


def new_monitor(policy, inner=None):
    return SafetyMonitor(inner or policy, fallback=ScriptedFallback())


def test_the_numbers_are_the_documented_ones(policy):
    monitor = new_monitor(policy)
    assert HAND_BACK_HOLD_S == 0.2 and RECOVERY_FRACTION == 0.5 and MAX_ENVELOPE_EXITS == 3
    assert monitor.hold_ticks == 20  # 0.2 s at the hover policy's 100 Hz


def test_one_bad_observation_costs_one_blind_step_and_the_hold(policy):
    monitor = new_monitor(policy)
    sources = []
    for kind in ["home"] * 5 + ["bad"] + ["home"] * 40:
        monitor.act(KINDS[kind])
        sources.append(monitor.source)
    hold = monitor.hold_ticks
    assert sources == ["policy"] * 5 + ["fallback"] + ["recovering"] * hold + ["policy"] * (40 - hold)
    assert monitor.events["fallback_engaged"] == 1 and monitor.events["handed_back"] == 1
    assert list(monitor.transitions) == [
        ("hand-over", "obs_nonfinite"),
        ("hand-back", f"{HAND_BACK_HOLD_S:g} s in recovery envelope"),
    ]


def test_a_bad_observation_during_the_hold_restarts_it(policy):
    monitor = new_monitor(policy)
    hold = monitor.hold_ticks
    seq = ["bad"] + ["home"] * (hold - 1) + ["bad"] + ["home"] * hold
    for kind in seq:
        monitor.act(KINDS[kind])
        assert monitor.source != "policy"
    monitor.act(KINDS["home"])
    assert monitor.source == "policy" and monitor.events["fallback_engaged"] == 1, "one hand-over, one hand-back"


@pytest.mark.parametrize("kind", ["between", "tilted"])
def test_between_the_envelopes_the_fallback_keeps_flying(policy, kind):
    """Hysteresis: a vehicle back inside the exit envelope but not the recovery one is not handed back."""
    monitor = new_monitor(policy)
    monitor.act(KINDS["bad"])
    for _ in range(10 * monitor.hold_ticks):
        monitor.act(KINDS[kind])
        assert monitor.source == "fallback"
    for _ in range(monitor.hold_ticks):
        monitor.act(KINDS["home"])
    monitor.act(KINDS["home"])
    assert monitor.source == "policy"


def test_a_hand_back_resets_the_fallback_too(policy):
    fallback = ScriptedFallback()
    monitor = SafetyMonitor(policy, fallback=fallback)
    for kind in ["bad"] + ["home"] * (monitor.hold_ticks + 1):
        monitor.act(KINDS[kind])
    assert monitor.source == "policy" and fallback.resets == 1


def test_the_third_envelope_exit_latches(policy):
    monitor = new_monitor(policy)
    back = ["home"] * (monitor.hold_ticks + 1)
    for exit_no in range(1, MAX_ENVELOPE_EXITS + 1):
        for kind in ["outside", *back]:
            monitor.act(KINDS[kind])
        assert monitor.events["out_of_envelope"] == exit_no
        assert monitor.source == ("policy" if exit_no < MAX_ENVELOPE_EXITS else "fallback")
    assert monitor.latched and monitor.events["fallback_latched"] == 1
    assert ("latched", "out_of_envelope") in monitor.transitions
    monitor.reset()
    monitor.act(KINDS["home"])
    assert monitor.source == "policy" and not monitor.latched and not monitor.transitions


def test_a_non_finite_command_latches(policy):
    double = NanOnce(policy.info, bad_call=3)
    monitor = new_monitor(policy, double)
    for _ in range(4):
        monitor.act(KINDS["home"])
    assert monitor.latched and monitor.events["command_nonfinite"] == 1
    for _ in range(5 * monitor.hold_ticks):
        monitor.act(KINDS["home"])
        assert monitor.source == "fallback"
    assert double.calls == 4 and monitor.events["handed_back"] == 0


def reference(kinds: list[str], hold: int) -> list[str]:
    """Who flies each step, from the module docstring (the policy never computes NaN here)."""
    engaged, latched, cause, inside, exits, out = False, False, "", 0, 0, []
    for kind in kinds:
        if kind == "bad":
            if not engaged:
                engaged, cause = True, "input"
            inside = 0
            out.append("fallback")
            continue
        if engaged:
            if latched or kind != "home":
                inside = 0
                out.append("fallback")
                continue
            inside += 1
            if inside <= hold:
                out.append("recovering" if cause == "input" else "fallback")
                continue
            engaged, inside = False, 0
        if kind == "outside":
            exits += 1
            engaged, cause, inside = True, "policy", 0
            latched = latched or exits >= MAX_ENVELOPE_EXITS
            out.append("fallback")
            continue
        out.append("policy")
    return out


@settings(max_examples=60, deadline=None)
@given(st.lists(st.sampled_from(sorted(KINDS)), min_size=1, max_size=200), st.data())
def test_who_flies_every_step_matches_the_reference_model(policy, kinds, data):
    # runs of "home" long enough to reach the hold, so that hand-backs happen
    kinds = [k for kind in kinds for k in ([kind] if kind != "home" else ["home"] * data.draw(st.integers(1, 25)))]
    monitor = new_monitor(policy)
    got = []
    for kind in kinds:
        u = monitor.act(KINDS[kind])
        assert u.dtype == np.float32 and np.all((u >= 0) & (u <= 1))
        got.append(monitor.source)
    assert got == reference(kinds, monitor.hold_ticks)
    changes = [kind for kind, _ in monitor.transitions]
    assert changes.count("hand-over") == monitor.events["fallback_engaged"]
    assert changes.count("hand-back") == monitor.events["handed_back"]
