"""Collects the per-drone-step figures of the environment-speed benchmarks and prints them at the
end of the run (pytest-benchmark's own tables show time per round, not drone-steps per second)."""

from __future__ import annotations

import pytest

_RESULTS = pytest.StashKey[list]()


def pytest_configure(config) -> None:
    config.stash[_RESULTS] = []


@pytest.fixture
def speed_results(request) -> list:
    """A list the benchmarks append their `extra_info` to, printed in the terminal summary."""
    return request.config.stash[_RESULTS]


def pytest_terminal_summary(terminalreporter, config) -> None:
    results = config.stash.get(_RESULTS, [])
    if not results:
        return
    tr = terminalreporter
    tr.section("drone-steps per second (fastest round; median round in brackets)")
    for r in results:
        tr.write_line(
            f"{r['kind']:<10} {r['dtype']:<7} N={r['n']:>4} {r['drone_steps_per_s'] / 1e6:9.4f} M/s"
            f" [{r['drone_steps_per_s_median'] / 1e6:9.4f}]   minor page faults/step {r['page_faults_per_step']:6.1f}"
        )
