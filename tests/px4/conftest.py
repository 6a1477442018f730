"""The mc_raptor harness built against RLtools' own headers, for every test here (raptor_build)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import raptor_build as build


def built(include, posix: bool):
    """The harness, or (outside tool missing) a skip in one line; in CI (env CI set) a failure."""
    try:
        return build.compile_harness(include() if callable(include) else include, posix)
    except build.Unavailable as e:
        what, install = e.args
        if os.environ.get("CI"):
            pytest.fail(f"{what} (CI must run this test)")
        pytest.skip(f"{what}; {install}")
    except build.BuildFailed as e:
        pytest.fail(str(e))


@pytest.fixture(scope="session", params=["rltools-2.2.1", "rltools-px4-pin"])
def harness(request) -> Path:
    if request.param == "rltools-2.2.1":
        return built(build.rltools_headers, posix=False)
    include = os.environ.get(build.PX4_INCLUDE_ENV)
    if not include or not (Path(include) / "rl_tools/persist/backends/tar/operations_posix.h").is_file():
        pytest.skip(f"set {build.PX4_INCLUDE_ENV} to the include/ of RLtools at PX4's pinned commit (docs/px4.md)")
    return built(Path(include), posix=True)
