"""quad-sitl: a policy flown against a software-in-the-loop quadrotor over MAVLink. The package
orchestrates the node (`autopilot.node`), the simulator process (`simulator`), the impairment proxy
(`link.impair`) and the logs:

- `cli`: the command line (`build_parser`, `main`, the checks of every flag before anything starts);
- `options`: the flags' types, the node's flags, which flags go together, the simulator flags passed on;
- `simulator_process`: starting the simulator process, waiting for it to listen, stopping it;
- `flight`: the one place a flight is set up (`fly`: safety monitor, node configuration, MAVLink log,
  impairment proxy, `Node.fly`), the episodes against our own simulator, the pictures;
- `node_only`: `--node-only`, one flight against any simulator that speaks PX4's Simulator MAVLink API;
- `summary`: what is printed and written about the flights.

`quad-sitl --sim-only` is the simulator's own command line (`simulator.cli`).
"""

from quadpilot.sitl.cli import SHIPPED_HOVER, main

__all__ = ["SHIPPED_HOVER", "main"]
