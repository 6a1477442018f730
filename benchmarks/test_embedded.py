"""Smoke test of benchmarks/embedded.py and its report: every model and core measured on a short
input (--quick), and the tables docs/embedded.md quotes printed from that JSON. The measurement
itself is run on purpose (its docstring has the command). Skips without the cross toolchain and
QEMU (one line naming the apt-get install), fails instead when CI is set."""

from __future__ import annotations

import json
import os

import pytest

import embedded
import report_embedded
from quadpilot.ccode import target as ctarget


def test_embedded_smoke(tmp_path, capsys):
    missing = ctarget.missing_tools()
    if missing:
        message = f"{', '.join(missing)} not installed; install with: {ctarget.APT_INSTALL}"
        (pytest.fail if os.environ.get("CI") else pytest.skip)(message)
    out = tmp_path / "embedded.json"
    assert embedded.main(["--quick", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert [(r["model"], r["target"]) for r in doc["results"]] == [
        (m, t) for m in ("hover", "hover_lstm") for t in ("cortex-m4f", "cortex-m7")
    ]
    for r in doc["results"]:
        assert r["max_abs_diff_vs_numpy"] <= 1e-5 and r["instructions"]["steps"] == 8 + 100 + 50
        assert r["image_flash_bytes"] == sum(r["flash_bytes"].values())
        assert r["stages"][-1]["stage"] == "command map"
    capsys.readouterr()
    assert report_embedded.main([str(out)]) == 0
    text = capsys.readouterr().out
    assert "| hover MLP | Cortex-M4F |" in text and "instructions per inference (mean)" in text
