"""Console scripts whose issue has not landed yet say so plainly instead of pretending to work."""

from __future__ import annotations

import sys


def not_yet(command: str, issue: str) -> int:
    print(f"{command}: not yet implemented (tracked in {issue}).", file=sys.stderr)
    return 2
