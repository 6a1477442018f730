"""benchmarks/rltools_proof.py runs and gives what docs/bench/rltools_px4.json records for rltools 2.2.1
(PX4's pin needs an rl-tools checkout and is run by hand: the script's docstring has the command)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "px4"))
import raptor_build as build  # noqa: E402

import rltools_proof  # noqa: E402


def test_rltools_proof_reproduces_the_committed_record(tmp_path):
    try:
        build.compile_harness(build.rltools_headers(), posix=False)
    except build.Unavailable as e:
        if os.environ.get("CI"):
            pytest.fail(f"{e.args[0]} (CI must run this test)")
        pytest.skip(f"{e.args[0]}; {e.args[1]}")
    out = tmp_path / "proof.json"
    assert rltools_proof.main(["--out", str(out)]) == 0
    now, committed = json.loads(out.read_text()), json.loads((ROOT / "docs/bench/rltools_px4.json").read_text())
    assert now["policy"] == committed["policy"]  # the same bytes, name and replay
    name = f"rltools {build.RLTOOLS_VERSION}"
    fresh, kept = now["loaders"][name], committed["loaders"][name]
    assert {k: v["exit"] for k, v in fresh["damage"].items()} == {k: v["exit"] for k, v in kept["damage"].items()}
    assert fresh["rltools_writer_writes_the_same_bytes"] and fresh["native_steps"] == kept["native_steps"]
    for key in ("check_mean_abs_diff", "max_action_diff_our_forward", "max_action_diff_foundation_policy"):
        assert fresh[key] <= 1e-5 and kept[key] <= 1e-5
    assert now["our_reader_content_only"] == committed["our_reader_content_only"]
