"""The study scripts answer bad input as every command does (`console.run_command`): one stderr
line, exit 2 for a flag, exit 1 for a file, no traceback, and before any work is done."""

from __future__ import annotations

import pytest

from quadpilot.studies import robustness, sac_compare


@pytest.mark.parametrize(
    ("main", "argv", "code", "says"),
    [
        (robustness.main, ["--out", "{tmp}/r"], 2, "nothing to measure"),
        (robustness.main, ["--fallback", "--write-eval", "x={tmp}/e.json", "--out", "{tmp}/r"], 2, "no --policy named"),
        (robustness.main, ["--policy", "nominal", "--out", "{tmp}/r"], 2, "NAME=PATH"),
        (robustness.main, ["--policy", "a={tmp}/not_a_checkpoint.pt", "--out", "{tmp}/r"], 1, "expected a quadpilot"),
        (sac_compare.main, [], 2, "give --ppo and/or --sac"),
        (sac_compare.main, ["--ppo", "{tmp}/no_run"], 1, "expected a finished quad-train run directory"),
        (sac_compare.main, ["--ppo", "{tmp}"], 1, "expected a finished quad-train run directory"),
    ],
)
def test_bad_input_gets_one_line_and_its_exit_code(tmp_path, capsys, main, argv, code, says):
    (tmp_path / "not_a_checkpoint.pt").write_bytes(b"not a torch file")
    assert main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == code
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err and "Traceback" not in err, err
    assert not (tmp_path / "r").exists()  # refused before the work
