"""`quad-train --init-rotor`: the rotor speeds an episode starts from reach the environment, travel
in the run's saved configuration, and a resume may not change them (what each choice does to the
rotors: tests/train/test_env_yaw_and_rotors.py)."""

import json

import pytest

from quadpilot.train.algorithms import load_checkpoint
from quadpilot.train.cli import main
from quadpilot.train.envs import INIT_ROTOR

TINY = ["--num-envs", "64", "--rollout-steps", "16", "--threads", "1", "--eval-episodes", "0"]


def test_the_flag_offers_exactly_the_environment_choices(capsys):
    assert main(["--help"]) == 0
    text = capsys.readouterr().out
    assert "--init-rotor {" + ",".join(INIT_ROTOR) + "}" in text


@pytest.mark.parametrize("choice", ["rest", "random"])
def test_init_rotor_reaches_the_environment_and_is_saved(tmp_path, choice):
    out = tmp_path / "run"
    args = ["--task", "hover", "--out", str(out), *TINY, "--total-steps", "1024", "--vehicle", "px4_sih_quadx"]
    assert main([*args, "--init-rotor", choice]) == 0
    assert json.loads((out / "config.json").read_text())["env"]["init_rotor"] == choice
    assert load_checkpoint(out / "checkpoint.pt")["env_config"]["init_rotor"] == choice


def test_a_resume_may_not_change_init_rotor(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["--task", "hover", "--out", str(out), *TINY, "--total-steps", "1024"]
    assert main([*args, "--init-rotor", "rest"]) == 0
    capsys.readouterr()
    assert main([*args, "--total-steps", "2048", "--init-rotor", "hover", "--resume"]) == 2
    assert "--init-rotor hover (checkpoint: rest)" in capsys.readouterr().err
