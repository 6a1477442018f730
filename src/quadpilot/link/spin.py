"""How long a lockstep link polls its socket before it sleeps (`transport.Link.spin_s`).

In lockstep each side waits for the other's answer, which comes within about a hundred
microseconds of the peer receiving its question. Waking a process that sleeps in select costs
more than that on a VM (benchmarks/test_sitl_speed.py `test_tcp_round_trip`, quoted in
docs/benchmarks.md), so a waiting side first polls its non-blocking socket for a short window.
The window costs a busy CPU while it lasts; a window that finds nothing makes the next waits sleep
at once (`SPIN_BACKOFF_MAX`), and with one usable CPU there is no window (`spin_window`): the
spinner would take the time the peer needs to answer.
"""

from __future__ import annotations

import os

LOCKSTEP_SPIN_S = 500e-6
"""s, the window: the node's policy and the simulator's step answer well inside it on the machine
of docs/benchmarks.md."""
MAX_SPIN_US = 1e6
"""µs, the longest window `--spin-us` takes: a whole second of polling is never of use."""
SPIN_BACKOFF_MAX = 256
"""After an empty window the next 1, 2, 4, ... (at most this many) waits sleep at once: a slow peer,
or one sharing the spinner's CPU, costs one window per that many waits. An answer caught resets it."""


def check_spin(spin_s) -> None:
    """ValueError (one line) unless `spin_s` is a window in seconds from 0 to MAX_SPIN_US."""
    if isinstance(spin_s, bool) or not isinstance(spin_s, (int, float)) or not 0 <= spin_s <= MAX_SPIN_US / 1e6:
        raise ValueError(f"spin_s must be a number of seconds from 0 to {MAX_SPIN_US / 1e6:g}, got {spin_s!r}")


def spin_window(spin_s: float) -> float:
    """`spin_s`, or 0 with one usable CPU."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return spin_s if cpus >= 2 else 0.0
