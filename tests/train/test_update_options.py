"""PPO's update settings on quad-train's command line (--epochs, --lr, --lr-schedule): they reach
the run's configuration, SAC refuses them in one line, a resume may not change them, and the run
says where its time went."""

import json

import pytest

from quadpilot.train.cli import main

TINY = [
    *("--task", "hover", "--num-envs", "8", "--rollout-steps", "16", "--minibatch-size", "64"),
    *("--total-steps", "256", "--threads", "1", "--eval-episodes", "0", "--eval-every", "0"),
]


def test_the_update_settings_reach_the_configuration_and_the_time_split_is_printed(tmp_path, capsys):
    out = tmp_path / "run"
    argv = [*TINY, "--epochs", "3", "--lr", "2.5e-4", "--lr-schedule", "constant", "--out", str(out)]
    assert main(argv) == 0
    ppo = json.loads((out / "config.json").read_text())["ppo"]
    assert (ppo["epochs"], ppo["lr"], ppo["lr_schedule"]) == (3, 2.5e-4, "constant")
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("quad-train: time:"))
    assert "environment" in line and "policy inference" in line and "update" in line and "evaluation" in line


@pytest.mark.parametrize(
    ("flags", "says"),
    [
        (["--algo", "sac", "--epochs", "3"], "--epochs: PPO's update settings, not SAC's"),
        (["--lr", "0"], "--lr: expected a finite number > 0"),
        (["--lr", "nan"], "--lr: expected a finite number > 0"),
        (["--epochs", "0"], "--epochs: must be ≥ 1"),
        (["--lr-schedule", "cosine"], "--lr-schedule: invalid choice"),
    ],
)
def test_a_bad_update_setting_is_one_line_and_exit_2(tmp_path, capsys, flags, says):
    assert main([*TINY, *flags, "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1


def test_a_resume_may_not_change_the_update_settings(tmp_path, capsys):
    out = tmp_path / "run"
    assert main([*TINY, "--epochs", "2", "--out", str(out)]) == 0
    capsys.readouterr()
    assert main([*TINY, "--total-steps", "512", "--epochs", "4", "--resume", "--out", str(out)]) == 2
    assert "--epochs 4 (checkpoint: 2)" in capsys.readouterr().err
