""".ci/run, the CI: it sets CI before running the tests, so that every test that skips for want of an
outside tool here (a cross compiler, QEMU, g++) fails there instead, and it installs those tools."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

from quadpilot.ccode import target as ctarget

SCRIPT = Path(__file__).resolve().parents[1] / ".ci" / "run"


def _lines() -> list[str]:
    return [line.strip() for line in SCRIPT.read_text().splitlines() if line.strip() and not line.startswith("#")]


def test_ci_is_set_before_the_tests_run():
    lines = _lines()
    tests = next(i for i, line in enumerate(lines) if re.search(r"-m pytest\b", line))
    exported = [i for i, line in enumerate(lines) if re.fullmatch(r"export CI=1", line)]
    assert exported and exported[0] < tests, "export CI=1 must come before the pytest line"


def test_ci_installs_every_tool_a_test_fails_without_in_ci():
    installed = set()
    for line in _lines():
        for command in re.split(r"&&|;", line):
            words = shlex.split(command)
            if words[:2] == ["apt-get", "install"]:
                installed |= {w for w in words[2:] if not w.startswith("-")}
    cross = set(shlex.split(ctarget.APT_INSTALL)[3:])  # tests/runtime/test_ctarget.py, benchmarks/test_embedded.py
    host = {"gcc", "g++"}  # the C backend's kernels (test_raptor_gru), the mc_raptor harness (tests/px4)
    assert cross and cross | host <= installed, sorted((cross | host) - installed)
