"""The waypoint curriculum as pure logic, fed made-up streams of episode outcomes."""

import json

import pytest

from quadpilot.train.envs.curriculum import CurriculumConfig, WaypointCurriculum

N, T, EP = 8, 10, 50  # drones, rollout steps, episode steps → settle = 5 updates


def make(**kw) -> WaypointCurriculum:
    return WaypointCurriculum(CurriculumConfig(**kw), num_envs=N, rollout_steps=T, episode_steps=EP)


def feed(cur, successes, per_update):
    """Feed outcomes in chunks of `per_update`; returns the update indices at which it advanced."""
    advanced = []
    for i in range(0, len(successes), per_update):
        if cur.observe(successes[i : i + per_update]):
            advanced.append(i // per_update)
    return advanced


def test_defaults_follow_seed_000():
    cur = make()
    assert cur.cfg.radii == (0.5, 1.0, 2.0) and cur.cfg.threshold == 0.9
    assert cur.stage == 0 and cur.radius == 0.5
    assert cur.min_episodes == 50 and cur.window == 50  # 2 × 8 drones is below the floor of 50
    assert WaypointCurriculum(CurriculumConfig(), 256, 64, 500).min_episodes == 512


def test_advances_once_enough_episodes_succeed():
    cur = make(min_episodes=20)
    assert not cur.observe([True] * 19)  # 100 % but too few episodes
    assert cur.observe([True])
    assert cur.stage == 1 and cur.radius == 1.0


def test_does_not_advance_below_threshold():
    cur = make(min_episodes=20)
    assert feed(cur, [True] * 8 + [False] * 2, 10) == []
    assert feed(cur, ([True] * 8 + [False] * 2) * 20, 10) == []  # 80 % for ever
    assert cur.stage == 0


def test_sliding_window_forgets_early_failures():
    cur = make(min_episodes=20, window=20)
    assert feed(cur, [False] * 100, 10) == []
    # the window holds the last 20: it passes once 18 of them succeed
    assert feed(cur, [True] * 17, 1) == []
    assert cur.observe([True])
    assert cur.stage == 1


def test_threshold_is_inclusive():
    cur = make(min_episodes=10, threshold=0.9)
    assert cur.observe([True] * 9 + [False])


def test_episodes_ending_just_after_an_advance_are_not_counted():
    cur = make(min_episodes=10)
    assert cur.observe([True] * 10)
    # for one episode length (50 steps = 5 updates of 10) ended episodes began at the old radius
    for _ in range(5):
        assert not cur.observe([True] * 100)
    assert cur.counted == 0
    assert cur.observe([True] * 10)
    assert cur.stage == 2


def test_settle_can_be_switched_off():
    cur = make(min_episodes=10, settle_steps=0)
    assert cur.observe([True] * 10)
    assert cur.observe([True] * 10)


def test_stage_counts_restart_after_an_advance():
    cur = make(min_episodes=10, settle_steps=0)
    assert cur.observe([True] * 10)
    assert not cur.observe([True] * 9)  # 9 episodes into stage 1: not enough yet


def test_final_stage_never_advances():
    cur = make(min_episodes=5, settle_steps=0)
    assert feed(cur, [True] * 50, 5) == [0, 1]
    assert cur.final and cur.stage == 2 and cur.radius == 2.0


def test_state_round_trips_through_json():
    a = make(min_episodes=30)
    a.observe([True] * 30)
    a.observe([True, False, True])
    b = make(min_episodes=30)
    b.load_state_dict(json.loads(json.dumps(a.state_dict())))
    assert b.state_dict() == a.state_dict()
    stream = [True] * 40
    assert feed(a, stream, 4) == feed(b, stream, 4)


@pytest.mark.parametrize(
    "kw",
    [
        {"radii": ()},
        {"radii": (1.0, 0.5)},
        {"radii": (0.0, 1.0)},
        {"threshold": 0.0},
        {"threshold": 1.5},
        {"min_episodes": 0},
        {"window": 0},
        {"settle_steps": -1},
    ],
)
def test_bad_configs_are_refused(kw):
    with pytest.raises(ValueError):
        CurriculumConfig(**kw)
