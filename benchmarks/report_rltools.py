"""The damage table of docs/px4.md from one run of benchmarks/rltools_proof.py.

    .venv/bin/python benchmarks/report_rltools.py docs/bench/rltools_px4.json

One row per damaged copy of policy.tar: what mc_raptor's start-up procedure does with it under each
RLtools (exit 0: accepted; 1: its check refuses; an RLtools assert aborts the process, as in PX4's
POSIX build), and what our reader says, on the content alone and with the good file's SHA-256 beside
the file.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _loader_cell(outcome: dict) -> str:
    if outcome["exit"] == 0:
        return "**accepted**"
    if outcome["exit"] == 1:
        return "refused: check failed"
    return f"aborts: `{outcome['last_line'].removeprefix('persist::backends::tar: ')}`"


def _reader_cell(message: str) -> str:
    if message == "accepted":
        return "**accepted**"
    if message.startswith("SHA-256"):
        return "refused: SHA-256"
    if "does not replay" in message:
        return "refused: replay"
    if "not finite" in message:
        return "refused: not finite"
    if "readable tar" in message:
        return "refused: truncated"
    return "refused: " + ("shape" if "shape" in message else "layout")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("json", type=Path)
    r = json.loads(p.parse_args(argv).json.read_text())
    loaders = r["loaders"]
    head = ["damage", *(f"mc_raptor, {name}" for name in loaders), "our reader", "our reader with SHA-256"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for how, mine in r["our_reader_content_only"].items():
        cells = [how, *(_loader_cell(lo["damage"][how]) for lo in loaders.values())]
        cells += [_reader_cell(mine), _reader_cell(r["our_reader_with_sha256"][how])]
        print("| " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
