"""Run management, for every algorithm and knowing none: the run loop (`loop`), the `Trainer` every
algorithm is (`trainer`), the run directory's files (`runlog`, `plotting`), checkpoints written and
read (`checkpoint`, `checkpoint_read`, `checks`) and quad-train's flags as configurations (`options`).
What differs between algorithms it asks the Trainer class, and the registry of them is handed to it
(`train.algorithms`), never imported."""
