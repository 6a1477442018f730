"""quad-train --contract px4-raptor: a PPO teacher distilled into the small policy PX4's mc_raptor
loads (`distill`, the student network in `student`, the command in `cli`)."""
