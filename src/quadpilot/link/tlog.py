"""Telemetry logs (.tlog): every MAVLink message as it crossed the wire, for pymavlink's tools.

The format is the one MAVProxy and QGroundControl write and `mavlogdump.py`, `mavgraph.py` and
QGC's log replay read: for each message, its wall-clock time as a big-endian uint64 of
microseconds since the Unix epoch, then the raw message bytes (MAVLink 1 or 2, signature included).
"""

from __future__ import annotations

import struct
import time
from pathlib import Path

_STAMP = struct.Struct(">Q")


class TlogWriter:
    """Appends messages to a .tlog. Use as `link.tap = writer.tap`; `close()` when done."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._f = open(self.path, "wb")
        self.messages = 0

    def write(self, raw: bytes, t: float | None = None) -> None:
        self._f.write(_STAMP.pack(int((time.time() if t is None else t) * 1e6)) + raw)
        self.messages += 1

    def tap(self, direction: str, raw: bytes) -> None:
        """A `Link.tap`: log what was sent and received alike."""
        self.write(raw)

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
