"""`python -m quadpilot.simulator [--listen tcp:127.0.0.1:4560] ...`: the simulator alone
(what `quad-sitl --sim-only` runs, and what quad-sitl starts as its simulator process)."""

import sys

from .cli import main_sim_only

sys.exit(main_sim_only(sys.argv[1:]))
