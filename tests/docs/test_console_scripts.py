"""Every console script the package installs is in README.md, and quad-demo says what it is: a
check that the environments run, whose closing hint is a command README.md gives."""

import re
from pathlib import Path

try:  # stdlib from Python 3.11; the `tomli` backport (same API) on 3.10
    import tomllib
except ModuleNotFoundError:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).parents[2]
README = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())  # lines joined


def test_readme_names_every_console_script():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["scripts"]
    missing = [name for name in scripts if not re.search(rf"(?<![\w-]){re.escape(name)}(?![\w-])", README)]
    assert len(scripts) >= 5 and not missing, f"console scripts README.md does not name: {missing}"


def test_quad_demo_says_it_trains_nothing_and_points_at_a_readme_command(capsys):
    from quadpilot import demo

    assert "until" not in demo.__doc__.split("\n\n")[0]  # no promise of a job it does not do
    assert "quad-demo" in README and "trains nothing" in README
    assert demo.main(["--num-envs", "4", "--steps", "3"]) == 0
    hint = capsys.readouterr().out.strip().splitlines()[-1]
    command = re.match(r"next: (quad-[a-z]+(?: --?[\w-]+(?: [\w/]+)?)*)", hint).group(1)
    assert command in README, hint
