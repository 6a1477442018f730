"""quad-train --init-from POLICY.pt: a fresh run that starts from a trained policy's weights.

The use it is made for: a generalist (`--randomize airframes`) fine-tuned on one vehicle file, so
that a policy for that file inherits what the generalist learned over thousands of airframes (its
recurrent adaptation, its tracking) and spends minutes, not an hour, on the file. Any PPO policy
of the same observation layout may be the start: its network's shape (architecture, widths,
activation, history, normalisation) is taken over unless a flag names another, which is refused;
its action head is put into the new vehicle's rotor order (`train.ppo.retarget.rotor_permutation`,
one rotor per corner) and given the new vehicle's hover trim (`train.ppo.retarget.vehicle_model`: the
asymmetric frame's unequal thrusts, none for a square frame); its observation statistics come with
it. The optimiser, the learning-rate schedule, the step count and the seed are the new run's. The
run's config.json records the file and its checksum (`init_from`); a resumed run continues from its
own checkpoint, not the file.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from quadpilot.console import UsageError

NETWORK_KEYS = ("arch", "lstm_hidden", "actor_hidden", "critic_hidden", "activation", "obs_history", "normalize_obs")
"""PPOConfig's fields that shape the network (and what it is fed): the new run takes the file's."""


def load_source(path: str, algorithms: dict) -> dict:
    """The checked checkpoint --init-from names (CheckpointError, exit 1, for a bad file); quad-train
    has refused --init-from for any --algo but ppo before."""
    from ..runs.checkpoint_read import load_checkpoint

    ckpt = load_checkpoint(path, algorithms)
    if ckpt.get("algo", "ppo") != "ppo":
        raise UsageError(f"--init-from {path}: a {ckpt['algo']} policy; it starts PPO runs from PPO policies")
    return ckpt


def network_options(ckpt: dict, explicit: dict, source: str) -> dict:
    """`explicit` with the source's network fields added; UsageError if a flag names another."""
    stored = ckpt["ppo_config"]
    clashes = [
        f"{k}={explicit[k]!r} (file: {stored[k]!r})"
        for k in NETWORK_KEYS
        if k in explicit and _differ(explicit[k], stored[k])
    ]
    if clashes:
        raise UsageError(f"--init-from {source}: the run's network is the file's; not {', '.join(clashes)}")
    return {**explicit, **{k: _value(stored[k]) for k in NETWORK_KEYS if k in stored}}


def _value(v):
    return tuple(v) if isinstance(v, list) else v


def _differ(a, b) -> bool:
    return _value(a) != _value(b)


def start_from(agent, ckpt: dict, source: str) -> dict:
    """Put the source's weights (head in the agent's rotor order) and observation statistics into
    the fresh `agent`; return what config.json records."""
    from quadpilot.core.params import unit_layout

    from ..envs import EnvConfig
    from ..runs.checks import rms_state
    from .retarget import RetargetError, rotor_permutation, vehicle_model

    theirs = EnvConfig.from_json(ckpt["env_config"])
    if ckpt["obs_layout"]["name"] != agent.env_cfg.layout.name:
        raise UsageError(
            f"--init-from {source}: its policy observes {ckpt['obs_layout']['name']}, this run's task "
            f"{agent.env_cfg.task} observes {agent.env_cfg.layout.name}"
        )
    try:
        order = rotor_permutation(unit_layout(theirs.params), unit_layout(agent.env_cfg.params))
        model, _ = vehicle_model(ckpt, order, theirs.params, agent.env_cfg.params)
    except RetargetError as e:
        raise UsageError(f"--init-from {source}: {e}") from None
    try:
        agent.model.load_state_dict(model)
    except RuntimeError as e:  # shapes: a check in load_checkpoint should have caught it
        raise UsageError(f"--init-from {source}: its weights do not fit this run's network ({str(e)[:200]})") from None
    agent.obs_rms.load_state_dict(rms_state(ckpt["obs_rms"]))
    digest = hashlib.sha256(Path(source).read_bytes()).hexdigest()
    return {
        "policy": source,
        "sha256": digest,
        "global_step": int(ckpt["global_step"]),
        "vehicle": theirs.params.name,
        "randomization": theirs.randomization.name if theirs.randomization else None,
        "rotor_order": list(order),
    }
