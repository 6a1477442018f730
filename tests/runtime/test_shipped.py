"""The shipped models as the package finds them (runtime.shipped) and quad-sitl's --model and
--list-models, in process (tests/test_wheel.py does the same from an installed wheel)."""

from pathlib import Path

import pytest

from quadpilot.runtime.shipped import listing, shipped_models, shipped_policy
from quadpilot.sitl import SHIPPED_HOVER, main

ROOT = Path(__file__).parents[2]


def test_every_folder_of_models_with_a_policy_is_shipped_and_hover_is_the_default():
    assert sorted(shipped_models()) == sorted(p.parent.name for p in (ROOT / "models").glob("*/policy.onnx"))
    assert shipped_policy() == SHIPPED_HOVER == (ROOT / "models" / "hover" / "policy.onnx").resolve()
    assert shipped_policy("circle").parent.name == "circle"


def test_an_unknown_name_is_refused_naming_the_choices():
    with pytest.raises(ValueError, match=r"'nope'.*expected one of circle, hover, hover_crazyflie, hover_dr"):
        shipped_policy("nope")


def test_listing_says_what_each_model_was_trained_for():
    lines = listing()
    assert lines[-1] == "fly one with: quad-sitl --model NAME"
    by_name = {line.split()[0]: line for line in lines[:-1]}
    assert " ".join(by_name["hover_px4_sih"].split()).startswith("hover_px4_sih hover on px4_sih_quadx (1 kg), mlp")
    assert "(default)" in by_name["hover"] and "(default)" not in by_name["circle"]
    assert "% of 100 episodes" in by_name["waypoint"]


def test_list_models_prints_the_listing(capsys):
    assert main(["--list-models"]) == 0
    assert capsys.readouterr().out.splitlines() == listing()


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--model", "nope"], "no shipped model of that name"),
        ([str(SHIPPED_HOVER), "--model", "circle"], "a policy file or --model, not both"),
    ],
)
def test_a_bad_model_choice_is_one_line_and_exit_2(capsys, argv, says):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err
