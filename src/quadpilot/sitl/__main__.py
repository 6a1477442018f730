"""`python -m quadpilot.sitl ...`: quad-sitl."""

import sys

from quadpilot.sitl.cli import main

sys.exit(main())
