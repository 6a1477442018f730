"""quad-train's timing flags: the default trains through delay, the flags set one range each, bad
values are one line that says what was expected, and a resume keeps the run's own timing."""

from __future__ import annotations

import json

import pytest

from quadpilot.core.timing import PRESETS, TimingConfig
from quadpilot.train.cli import main

TINY = ["--num-envs", "64", "--rollout-steps", "16", "--threads", "1", "--eval-episodes", "4", "--total-steps", "1024"]


def _timing(out) -> dict | None:
    return json.loads((out / "config.json").read_text())["env"]["timing"]


def test_a_fresh_run_trains_through_the_link_preset_by_default(tmp_path):
    out = tmp_path / "run"
    assert main(["--task", "hover", "--out", str(out), *TINY]) == 0
    assert TimingConfig.from_json(_timing(out)) == PRESETS["link"]
    ev = json.loads((out / "eval.json").read_text())
    assert set(ev["timings"]) == {"no_delay", "delay_20ms_jitter_10ms"}  # judged without delay and at a fixed link


def test_the_range_flags_set_one_range_each_and_none_turns_it_off(tmp_path):
    out = tmp_path / "ranges"
    assert main(["--task", "hover", "--out", str(out), *TINY, "--obs-delay", "5:15", "--jitter", "3"]) == 0
    t = _timing(out)
    assert t["name"] == "custom" and t["obs_delay_ms"] == [5.0, 15.0] and t["jitter_ms"] == [3.0, 3.0]
    assert t["action_delay_ms"] == list(PRESETS["link"].action_delay_ms)  # the rest from the preset
    off = tmp_path / "off"
    assert main(["--task", "hover", "--out", str(off), *TINY, "--timing", "none"]) == 0
    assert _timing(off)["name"] == "none"
    assert "timings" not in json.loads((off / "eval.json").read_text())


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--timing", "radio"], "--timing 'radio': expected one of link, none"),
        (["--action-delay", "-5"], "--action-delay '-5': expected milliseconds ≥ 0"),
        (["--obs-delay", "20:10"], "--obs-delay '20:10': expected milliseconds ≥ 0"),
        (["--jitter", "nan"], "--jitter 'nan': expected milliseconds ≥ 0"),
        (["--obs-delay", "1:2:3"], "--obs-delay '1:2:3'"),
        (["--action-delay", "450", "--jitter", "100"], "at most 500 ms"),
        (["--reward", "heading_sigma=-1"], "--reward 'heading_sigma=-1': expected a finite number > 0"),
        (["--reward", "heading"], "expected NAME=VALUE"),
    ],
)
def test_bad_timing_and_reward_flags_are_one_line(tmp_path, capsys, flags, message):
    assert main(["--task", "hover", "--out", str(tmp_path / "bad"), *TINY, *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "bad").exists()


def test_a_resume_may_not_change_the_timing(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["--task", "hover", "--out", str(out), *TINY]) == 0
    more = [*TINY[:-1], "2048"]
    assert main(["--task", "hover", "--out", str(out), *more, "--resume", "--timing", "none"]) == 2
    assert "--timing none (checkpoint: link)" in capsys.readouterr().err
    assert main(["--task", "hover", "--out", str(out), *more, "--resume", "--reward", "heading_sigma=0.5"]) == 2
    assert main(["--task", "hover", "--out", str(out), *more, "--resume", "--timing", "link"]) == 0


def test_a_reward_flag_sets_one_field_on_top_of_the_task_s_reward(tmp_path):
    out = tmp_path / "wp"
    assert (
        main(["--task", "waypoint", "--out", str(out), *TINY, "--timing", "none", "--reward", "heading_sigma=0.4"]) == 0
    )
    reward = json.loads((out / "config.json").read_text())["env"]["reward"]
    assert reward["heading_sigma"] == 0.4 and reward["tilt_weight"] == 50.0  # waypoint's own tilt penalty kept
