"""The simulator's flags that quad-sitl passes on are declared once (`simulator.cli.passed_on_flags`):
both command lines show the same text for each, and what quad-sitl passes on is what it was given."""

import argparse
import contextlib
import io
import re

from quadpilot.simulator.cli import build_sim_parser, passed_on_flags
from quadpilot.sitl.cli import build_parser
from quadpilot.sitl.options import sim_args


def _help_of(parser: argparse.ArgumentParser) -> dict[str, str]:
    """flag → its help line(s) as printed, whitespace folded."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        parser.print_help()
    entries = re.split(r"\n(?=  --)", out.getvalue())
    found = {}
    for e in entries:
        m = re.match(r"\s*(--[a-z-]+)", e)
        if m:
            found[m.group(1)] = " ".join(e.split("\n\n")[0].split())  # not the epilog after the last
    return found


def test_both_command_lines_show_the_same_text_for_every_passed_on_flag():
    sim, sitl = _help_of(build_sim_parser()), _help_of(build_parser())
    flags = list(passed_on_flags())
    assert len(flags) >= 15
    for flag in flags:
        assert flag in sim and flag in sitl, flag
        assert sim[flag] == sitl[flag], (sim[flag], sitl[flag])


def test_quad_sitl_passes_on_what_it_was_given_and_nothing_else():
    args = build_parser().parse_args(["--wind", "-0.9,0,0", "--imu-noise", "--mass-scale", "1.1"])
    assert sim_args(args) == ["--mass-scale=1.1", "--wind=-0.9,0,0", "--imu-noise"]
    assert sim_args(build_parser().parse_args([])) == []
    # and the simulator's own parser reads them back to the same values
    sim = build_sim_parser().parse_args(sim_args(args))
    assert sim.mass_scale == 1.1 and sim.wind == (-0.9, 0.0, 0.0) and sim.imu_noise
