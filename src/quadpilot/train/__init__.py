"""Training side (torch + gymnasium): environments, PPO, curriculum, checkpoints, quad-train.

Importing this package registers the Gymnasium environments quadpilot/Hover-v0,
quadpilot/Waypoint-v0 and quadpilot/Circle-v0, so that
`gymnasium.make("quadpilot.train:quadpilot/Hover-v0")` works with no import first.
"""

import gymnasium as gym

_ENTRY = "quadpilot.train.envs:QuadEnv"
_VECTOR_ENTRY = "quadpilot.train.envs:QuadVectorEnv"
for _name, _task in (("Hover", "hover"), ("Waypoint", "waypoint"), ("Circle", "circle")):
    _id = f"quadpilot/{_name}-v0"
    if _id not in gym.registry:
        gym.register(id=_id, entry_point=_ENTRY, kwargs={"task": _task}, vector_entry_point=_VECTOR_ENTRY)
