"""The safety monitor around the real shipped hover policy (every backend) and the real fallback.

What it must guarantee: a bad observation (non-finite, or beyond what any sensor of a flying vehicle
reports) never reaches the policy; a state outside the flight envelope the policy was trained in is
flown by the classical fallback; a bad command never reaches the motors; the fallback hands back to
the policy after `HAND_BACK_HOLD_S` inside the recovery envelope, and latches only for a broken
policy (`tests/runtime/test_safety_handback.py` holds the state machine); and the output is always
a finite float32 (4,) in [0, 1]. The closed-loop flights use `core.dynamics.step` and
`core.observation.build_observation` exactly as the runtime would (float32 observations, float64
state).
"""

import math
from pathlib import Path

import numpy as np
import pytest

from quadpilot.core.dynamics import IDX, step
from quadpilot.core.observation import HOVER_LAYOUT, build_observation
from quadpilot.core.params import ParamBatch
from quadpilot.runtime.backends import BACKENDS, ObservationShapeError, Policy, load_policy
from quadpilot.runtime.cbackend import find_compiler
from quadpilot.runtime.fallback import FallbackController
from quadpilot.runtime.safety import SafetyMonitor

HOVER = Path(__file__).resolve().parents[2] / "models" / "hover" / "policy.onnx"
SLICES = HOVER_LAYOUT.slices()
OBS_DIM = HOVER_LAYOUT.dim
DT = 0.01
TARGET = np.array([0.0, 0.0, 2.0])  # the hover task's home
# the c backend compiles the file's C with the system C compiler: skipped where there is none
HAS_CC = find_compiler() is not None
BACKEND_PARAMS = [
    pytest.param(b, marks=pytest.mark.skipif(not HAS_CC, reason="the c backend needs a C compiler")) if b == "c" else b
    for b in BACKENDS
]


# --- fixtures and doubles ------------------------------------------------------------------


@pytest.fixture(scope="module", params=BACKEND_PARAMS)
def policy(request):
    return load_policy(HOVER, request.param)


class Spy:
    """Delegates to a real policy and records every observation that reaches it. SafetyMonitor
    binds `policy.act_unchecked` at construction and calls it directly, so `act_unchecked` is what
    must be watched; `act` is recorded too, in case a later monitor calls it."""

    def __init__(self, inner: Policy) -> None:
        self.inner = inner
        self.info = inner.info
        self.obs_dim = inner.obs_dim
        self.backend = inner.backend
        self.observation = inner.observation  # the shape check the monitor shares with the policy
        self.seen: list[np.ndarray] = []
        self.resets = 0

    def act_unchecked(self, x):
        self.seen.append(np.array(x, dtype=np.float64, copy=True))
        return self.inner.act_unchecked(x)

    def act(self, obs):
        self.seen.append(np.array(obs, dtype=np.float64, copy=True).reshape(-1))
        return self.inner.act(obs)

    def reset(self):
        self.resets += 1
        self.inner.reset()


class FixedCommand(Policy):
    """A policy with the hover file's metadata that answers a fixed command (a foreign graph)."""

    backend = "test-double"

    def __init__(self, info, command) -> None:
        super().__init__(info)
        self.command = np.asarray(command, np.float32)
        self.calls = 0

    def act_unchecked(self, x):
        self.calls += 1
        return self.command.copy()


def in_envelope_rows(info) -> np.ndarray:
    """The golden observations that lie inside the file's flight envelope (the golden set also
    holds stress rows far from the target, which the monitor rightly gives to the fallback)."""
    rows = []
    for obs in info.golden_obs:
        r = obs[SLICES["rot"]].reshape(3, 3)
        pitch = -math.asin(r[2, 0])
        roll = math.atan2(r[2, 1], r[2, 2])
        far = np.linalg.norm(obs[SLICES["pos_error"]]) >= info.envelope["max_distance_m"] - 0.1
        tilt = max(abs(roll), abs(pitch)) >= math.radians(info.envelope["max_tilt_deg"]) - 0.05
        if not far and not tilt:
            rows.append(obs)
    assert len(rows) >= 2, "the golden set should hold ordinary hover observations"
    return np.array(rows)


def state(pos=(0.0, 0.0, 0.0), vel=(0.0, 0.0, 0.0), roll_deg=0.0, pitch_deg=0.0, yaw_deg=0.0, rates=(0, 0, 0)):
    """12-state at TARGET + pos (world ENU), angles in degrees."""
    s = np.zeros(12)
    s[0:3] = TARGET + np.asarray(pos, float)
    s[3:6] = vel
    s[IDX["roll"]], s[IDX["pitch"]], s[IDX["yaw"]] = np.radians([roll_deg, pitch_deg, yaw_deg])
    s[9:12] = rates
    return s


def obs_of(s) -> np.ndarray:
    return build_observation(np.asarray(s)[None], TARGET)[0]


def assert_safe_command(u):
    assert isinstance(u, np.ndarray) and u.shape == (4,) and u.dtype == np.float32, (type(u), u)
    assert np.all(np.isfinite(u)) and np.all((u >= 0.0) & (u <= 1.0)), u


# --- normal observations pass straight through ---------------------------------------------


def test_normal_observation_gives_the_bare_policys_command(policy):
    spy = Spy(policy)
    monitor = SafetyMonitor(spy)
    for obs in in_envelope_rows(policy.info):
        want = policy.act(obs)
        got = monitor.act(obs)
        assert_safe_command(got)
        np.testing.assert_array_equal(got, want)
        assert monitor.source == "policy" and not monitor.in_fallback
    assert sum(monitor.events.values()) == 0, dict(monitor.events)
    assert len(spy.seen) == len(in_envelope_rows(policy.info))


# --- bad observations never reach the policy -----------------------------------------------


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf], ids=["nan", "+inf", "-inf"])
def test_non_finite_value_in_any_field_never_reaches_the_policy(policy, bad):
    good = in_envelope_rows(policy.info)[0]
    hover = np.full(4, policy.info.vehicle.hover_command, np.float32)
    for i in range(OBS_DIM):
        spy = Spy(policy)
        monitor = SafetyMonitor(spy)
        obs = good.copy()
        obs[i] = bad
        u = monitor.act(obs)  # first call: no good observation yet → hover trim
        assert_safe_command(u)
        np.testing.assert_allclose(u, hover, atol=1e-6)
        assert spy.seen == [], f"index {i}: the bad observation reached the policy"
        assert monitor.events["obs_nonfinite"] == 1 and monitor.in_fallback and monitor.source == "fallback"
        assert monitor.events["obs_out_of_range"] == 0


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf], ids=["nan", "+inf", "-inf"])
def test_after_a_good_observation_bad_ones_still_never_reach_the_policy(policy, bad):
    good = in_envelope_rows(policy.info)[0]
    spy = Spy(policy)
    monitor = SafetyMonitor(spy)
    monitor.act(good)
    assert len(spy.seen) == 1
    for i in (0, 4, 8, 14, 16):  # one value in each field
        obs = good.copy()
        obs[i] = bad
        u = monitor.act(obs)
        assert_safe_command(u)
        assert monitor.source == "fallback"
        assert len(spy.seen) == 1 and np.all(np.isfinite(spy.seen[0]))
    assert monitor.events["obs_nonfinite"] == 5 and monitor.events["fallback_engaged"] == 1


ABSURD = {
    "pos_error 1e6 m": (SLICES["pos_error"].start, 1e6),
    "pos_error -1e6 m": (SLICES["pos_error"].start + 2, -1e6),
    "vel 1e3 m/s": (SLICES["vel"].start + 1, 1e3),
    "rot entry 2.0": (SLICES["rot"].start + 4, 2.0),
    "rot entry -2.0": (SLICES["rot"].stop - 1, -2.0),
    "rate 1e3 rad/s": (SLICES["rates"].start, 1e3),
    "rate -1e3 rad/s": (SLICES["rates"].start + 2, -1e3),
}


@pytest.mark.parametrize("case", list(ABSURD))
def test_absurd_finite_value_never_reaches_the_policy(policy, case):
    i, value = ABSURD[case]
    good = in_envelope_rows(policy.info)[0]
    spy = Spy(policy)
    monitor = SafetyMonitor(spy)
    obs = good.copy()
    obs[i] = value
    u = monitor.act(obs)
    assert_safe_command(u)
    assert spy.seen == []
    assert monitor.events["obs_out_of_range"] == 1 and monitor.events["obs_nonfinite"] == 0
    assert monitor.in_fallback and monitor.source == "fallback"


def test_plus_inf_through_the_bare_policy_is_a_finite_rolling_command_the_monitor_prevents_it(policy):
    """Why observations are checked first: +Inf is no error to the network, it goes through tanh
    to a finite command in range (the first layer's units pinned at ±1), so a NaN check on the
    command would let it through, and the motors it asks for differ by a quarter of full speed or
    more: a hard roll, not hover."""
    good = in_envelope_rows(policy.info)[0]
    obs = good.copy()
    obs[SLICES["pos_error"].start] = np.inf
    bare = policy.act(obs)
    assert np.all(np.isfinite(bare)) and np.all((bare >= 0) & (bare <= 1)), "finite and in range: no alarm"
    assert bare.max() - bare.min() > 0.25, f"a command that rolls the vehicle hard: {bare}"
    hover = policy.info.vehicle.hover_command
    assert np.abs(bare - hover).max() > 0.15, f"far from hover: {bare} against {hover}"

    monitor = SafetyMonitor(policy)
    guarded = monitor.act(obs)
    assert_safe_command(guarded)
    np.testing.assert_allclose(guarded, policy.info.vehicle.hover_command, atol=1e-6)
    assert guarded.max() - guarded.min() < 1e-6
    assert monitor.events["obs_nonfinite"] == 1


# --- the flight envelope -------------------------------------------------------------------

ENVELOPE = {
    # name: (state kwargs, expected source)
    "level at target": ({}, "policy"),
    "4.5 m away": ({"pos": (3.0, -3.0, 1.5)}, "policy"),
    "6 m away": ({"pos": (6.0, 0.0, 0.0)}, "fallback"),
    "6 m above": ({"pos": (0.0, 0.0, 6.0)}, "fallback"),
    "roll 70": ({"roll_deg": 70.0}, "fallback"),
    "roll -70": ({"roll_deg": -70.0, "yaw_deg": 120.0}, "fallback"),
    "pitch 70": ({"pitch_deg": 70.0}, "fallback"),
    "pitch -70": ({"pitch_deg": -70.0, "yaw_deg": -45.0}, "fallback"),
    "upside down": ({"roll_deg": 180.0}, "fallback"),
    "roll 120": ({"roll_deg": 120.0}, "fallback"),
    "roll 50": ({"roll_deg": 50.0}, "policy"),
    "pitch 50": ({"pitch_deg": 50.0}, "policy"),
    "roll 50 and pitch 50": ({"roll_deg": 50.0, "pitch_deg": 50.0, "yaw_deg": 30.0}, "policy"),
    "roll -50 and pitch -50": ({"roll_deg": -50.0, "pitch_deg": -50.0, "yaw_deg": 170.0}, "policy"),
}


@pytest.mark.parametrize("case", list(ENVELOPE))
def test_envelope(policy, case):
    kwargs, expected = ENVELOPE[case]
    spy = Spy(policy)
    monitor = SafetyMonitor(spy)
    obs = obs_of(state(**kwargs))
    u = monitor.act(obs)
    assert_safe_command(u)
    assert monitor.source == expected
    if expected == "policy":
        np.testing.assert_array_equal(u, policy.act(obs))
        assert len(spy.seen) == 1 and sum(monitor.events.values()) == 0
    else:
        assert spy.seen == [], "outside the envelope the policy is not asked"
        assert monitor.events["out_of_envelope"] == 1 and monitor.in_fallback
        reference = FallbackController(
            policy.info.vehicle, policy.info.control_period_s, heading_frame=policy.info.layout.heading_frame
        )
        np.testing.assert_allclose(u, reference.act(obs), atol=1e-6)


def test_envelope_limits_are_the_files():
    policy = load_policy(HOVER, "numpy")
    assert policy.info.envelope == {"max_distance_m": 5.0, "max_tilt_deg": 60.0}


# --- hand-over and hand-back ----------------------------------------------------------------


def test_hand_over_hands_back_after_the_hold_and_events_are_kept(policy):
    good = obs_of(state(pos=(0.1, -0.1, 0.05)))
    spy = Spy(policy)
    monitor = SafetyMonitor(spy)
    monitor.act(good)
    assert monitor.source == "policy" and len(spy.seen) == 1

    bad = good.copy()
    bad[3] = np.nan
    monitor.act(bad)
    assert monitor.in_fallback and monitor.events["fallback_engaged"] == 1

    resets = spy.resets
    for _ in range(monitor.hold_ticks):  # good observations: the fallback holds, the policy is not asked
        assert_safe_command(monitor.act(good))
        assert monitor.source == "recovering" and monitor.in_fallback
    assert len(spy.seen) == 1
    assert monitor.events["fallback_engaged"] == 1, "one hand-over, however long the fallback flies"
    assert monitor.events["blind_steps"] == 1, "the bad observation itself is flown blind at hover thrust"
    assert monitor.events["fallback_steps"] == monitor.hold_ticks

    u = monitor.act(good)  # the hold is over: the policy flies again, its recurrent state cleared
    np.testing.assert_array_equal(u, policy.act(good))
    assert monitor.source == "policy" and not monitor.in_fallback and len(spy.seen) == 2
    assert spy.resets == resets + 1, "a hand-back clears the policy's recurrent state"
    assert monitor.events["handed_back"] == 1 and monitor.events["obs_nonfinite"] == 1

    # and a second fault is a second hand-over
    monitor.act(bad)
    assert monitor.events["obs_nonfinite"] == 2 and monitor.events["fallback_engaged"] == 2


def test_out_of_envelope_hands_back_once_inside_the_recovery_envelope(policy):
    monitor = SafetyMonitor(policy)
    monitor.act(obs_of(state(roll_deg=75.0)))
    assert monitor.source == "fallback" and monitor.events["out_of_envelope"] == 1
    monitor.act(obs_of(state(roll_deg=45.0)))  # back inside the exit envelope, not the recovery one
    for _ in range(3 * monitor.hold_ticks):
        monitor.act(obs_of(state(roll_deg=40.0)))
        assert monitor.source == "fallback", "40° is beyond the 30° recovery envelope"
    for _ in range(monitor.hold_ticks):
        monitor.act(obs_of(state()))
        assert monitor.source == "fallback", "the policy's own exit: its hold counts as fallback"
    monitor.act(obs_of(state()))
    assert monitor.source == "policy" and monitor.events["handed_back"] == 1


# --- command checks (a foreign graph, simulated) -------------------------------------------


@pytest.fixture(scope="module")
def info():
    return load_policy(HOVER, "numpy").info


def test_nonfinite_command_hands_over_to_the_fallback(info):
    double = FixedCommand(info, [0.5, np.nan, 0.5, 0.5])
    monitor = SafetyMonitor(double)
    obs = in_envelope_rows(info)[0]
    u = monitor.act(obs)
    assert_safe_command(u)
    assert double.calls == 1
    assert monitor.events["command_nonfinite"] == 1 and monitor.in_fallback and monitor.source == "fallback"
    reference = FallbackController(info.vehicle, info.control_period_s, heading_frame=info.layout.heading_frame)
    np.testing.assert_allclose(u, reference.act(obs), atol=1e-6)
    for _ in range(3 * monitor.hold_ticks):  # latched: the broken policy is not asked again
        monitor.act(obs)
    assert double.calls == 1 and monitor.latched and monitor.events["handed_back"] == 0


@pytest.mark.parametrize("bad", [np.inf, -np.inf], ids=["+inf", "-inf"])
def test_infinite_command_is_non_finite_not_clamped(info, bad):
    monitor = SafetyMonitor(FixedCommand(info, [0.5, 0.5, bad, 0.5]))
    u = monitor.act(in_envelope_rows(info)[0])
    assert_safe_command(u)
    assert monitor.events["command_nonfinite"] == 1 and monitor.events["command_clamped"] == 0
    assert monitor.in_fallback


def test_out_of_range_command_is_clamped_and_counted(info):
    double = FixedCommand(info, [1.2, 0.5, -0.1, 0.7])
    monitor = SafetyMonitor(double)
    obs = in_envelope_rows(info)[0]
    for k in range(3):
        u = monitor.act(obs)
        assert_safe_command(u)
        np.testing.assert_array_equal(u, np.array([1.0, 0.5, 0.0, 0.7], np.float32))
        assert monitor.source == "policy" and not monitor.in_fallback, "clamping is no hand-over"
        assert monitor.events["command_clamped"] == k + 1
    assert double.calls == 3 and monitor.events["fallback_engaged"] == 0


def test_command_of_1_2_everywhere_is_clamped_to_1(info):
    monitor = SafetyMonitor(FixedCommand(info, [1.2] * 4))
    u = monitor.act(in_envelope_rows(info)[0])
    np.testing.assert_array_equal(u, np.ones(4, np.float32))
    assert monitor.events["command_clamped"] == 1


# --- the observation's shape ---------------------------------------------------------------


@pytest.mark.parametrize("shape", [(17,), (19,), (2, OBS_DIM)], ids=str)
def test_wrong_observation_size_raises(policy, shape):
    spy = Spy(policy)
    monitor = SafetyMonitor(spy)
    with pytest.raises(ObservationShapeError, match=rf"expects \({OBS_DIM},\)"):
        monitor.act(np.zeros(shape, np.float32))
    assert spy.seen == [] and sum(monitor.events.values()) == 0


def test_a_list_and_a_batch_of_one_are_accepted(policy):
    obs = in_envelope_rows(policy.info)[0]
    monitor = SafetyMonitor(policy)
    want = policy.act(obs)
    np.testing.assert_allclose(monitor.act([float(v) for v in obs]), want, atol=1e-7)
    np.testing.assert_allclose(monitor.act(obs[None]), want, atol=1e-7)
    assert monitor.source == "policy"


# --- closed loop against the core model ----------------------------------------------------


def fly(monitor, s0, seconds, corrupt=None):
    """Closed-loop flight at 100 Hz; `corrupt(k, obs)` may edit the observation of step k in place.
    Returns the states (T+1, 12) and the sources per step."""
    params = ParamBatch.from_preset(monitor.policy.info.vehicle, 1)
    s, rotor = np.asarray(s0, np.float64)[None].copy(), np.zeros((1, 4))
    states, sources = [s[0].copy()], []
    for k in range(round(seconds / DT)):
        obs = build_observation(s, TARGET)[0]  # float32, as the runtime builds it
        if corrupt is not None:
            corrupt(k, obs)
        u = monitor.act(obs)
        assert_safe_command(u)
        s, rotor = step(s, rotor, u[None].astype(np.float64), params, DT)
        states.append(s[0].copy())
        sources.append(monitor.source)
    return np.array(states), sources


def pos_error(states):
    return np.linalg.norm(states[:, 0:3] - TARGET, axis=1)


def tilt_deg(states):
    return np.degrees(np.arccos(np.clip(np.cos(states[:, 6]) * np.cos(states[:, 7]), -1.0, 1.0)))


def test_policy_under_the_monitor_flies_a_normal_start_to_the_target(policy):
    monitor = SafetyMonitor(policy)
    s0 = state(pos=(0.6, -0.5, 0.4), vel=(0.2, -0.3, 0.1), roll_deg=10.0, pitch_deg=-12.0, yaw_deg=40.0)
    states, sources = fly(monitor, s0, 5.0)
    err = pos_error(states)
    assert set(sources) == {"policy"} and sum(monitor.events.values()) == 0
    assert np.all(states[:, 2] > 0.0)
    assert err[-200:].mean() <= 0.05, f"mean error over the last 2 s: {err[-200:].mean():.3f} m"


def test_start_outside_the_envelope_is_caught_and_flown_back_by_the_fallback(policy):
    monitor = SafetyMonitor(policy)
    s0 = state(pos=(4.8, -3.6, 0.0), yaw_deg=-60.0)  # 6 m away
    assert np.linalg.norm(s0[0:3] - TARGET) > policy.info.envelope["max_distance_m"]
    states, sources = fly(monitor, s0, 8.0)
    err = pos_error(states)
    back = sources.index("policy")  # the fallback from the first step, the policy once back inside
    assert back > monitor.hold_ticks and set(sources[:back]) == {"fallback"} and set(sources[back:]) == {"policy"}
    assert monitor.events["out_of_envelope"] == 1 and monitor.events["fallback_engaged"] == 1
    assert monitor.events["handed_back"] == 1
    assert np.all(tilt_deg(states) < 60.0) and np.all(states[:, 2] > 0.0)
    assert err[-1] <= 0.10, f"final error {err[-1]:.3f} m"


@pytest.mark.parametrize("burst_start_s", [0.3, 0.5, 1.0, 1.5])
def test_sensor_dropout_mid_flight_does_not_crash_the_vehicle(policy, burst_start_s):
    """20 NaN observations (0.2 s without sensors), at several moments of the approach to the
    target: the vehicle must not crash (tilt below the 60° training limit, altitude above ground)
    and must end within 10 cm. While the observations are bad, nothing can be measured, so
    whatever flies those steps flies blind; a controller that keeps correcting the attitude error
    of the last good observation commands the same moment for 0.2 s with no feedback."""
    monitor = SafetyMonitor(policy)
    s0 = state(pos=(0.5, 0.3, -0.4), roll_deg=-8.0, yaw_deg=100.0)
    first = round(burst_start_s / DT)
    burst = range(first, first + 20)

    def dropout(k, obs):
        if k in burst:
            obs[:] = np.nan

    states, sources = fly(monitor, s0, 6.0, corrupt=dropout)
    err = pos_error(states)
    assert set(sources[:first]) == {"policy"} and set(sources[first : first + len(burst)]) == {"fallback"}
    back = first + len(burst) + sources[first + len(burst) :].index("policy")
    assert set(sources[back:]) == {"policy"}, "handed back once, for good"
    assert monitor.events["obs_nonfinite"] == len(burst) and monitor.events["handed_back"] == 1
    tilt = tilt_deg(states)
    assert tilt.max() < 60.0, f"tilted {tilt.max():.0f}° at {DT * tilt.argmax():.2f} s (dropout from {burst_start_s} s)"
    assert states[:, 2].min() > 0.0, f"lowest altitude {states[:, 2].min():.2f} m"
    assert err[-1] <= 0.10, f"final error {err[-1]:.3f} m"
