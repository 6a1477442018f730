"""The simulator side of software-in-the-loop: `core.dynamics` served over MAVLink like a PX4
simulator (PX4's "Simulator MAVLink API"; docs/architecture.md, "How a MAVLink message flows").

The simulator listens (TCP 127.0.0.1:4560 by default, UDP as an option) and serves one episode per
connection. This module gathers its public names; each part has its module:

- `config`: `SimConfig`, everything that defines a run;
- `plant`: `Plant`, the vehicle's physics step (`core.dynamics`, wind and gusts);
- `sensors`: IMU, magnetometer, barometer and the state estimate of each step;
- `protocol`: the messages each step sends, the one receive point, the check of actuator commands;
- `process`: `Simulator`, the server loop (lockstep or realtime, the ESC timeout);
- `records`: `EpisodeRecord` and `SimStats`, what a run reports;
- `cli`: its command line (`main_sim_only`: `python -m quadpilot.simulator`, which `quad-sitl --sim-only`
  runs), where the flags quad-sitl passes on to it are declared once (`passed_on_flags`).

Every in-range command sequence keeps the simulation finite and every message encodable, however
long it runs: the plant stays in its model's domain (`Plant`), the barometer in its atmosphere's
(`sensors.isa_pressure_hpa`), and integer wire fields saturate at their MAVLink types' limits
(`link.wire`). Malformed input never ends the simulator.
"""

from __future__ import annotations

from quadpilot.link.transport import SimulatorError

from .cli import UsageError, build_sim_parser, config_from_args, main_sim_only
from .config import DEFAULT_WIND_DRAG, SimConfig
from .plant import Plant
from .process import POLL_S, Simulator
from .protocol import TIME_ORIGIN_US
from .records import END_REASONS, EpisodeRecord, SimStats

__all__ = [
    "DEFAULT_WIND_DRAG",
    "END_REASONS",
    "POLL_S",
    "TIME_ORIGIN_US",
    "EpisodeRecord",
    "Plant",
    "SimConfig",
    "SimStats",
    "Simulator",
    "SimulatorError",
    "UsageError",
    "build_sim_parser",
    "config_from_args",
    "main_sim_only",
]
