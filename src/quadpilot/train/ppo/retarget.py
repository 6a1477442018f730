"""A generalist policy on one airframe: its vehicle file's hover command and rotor order, nothing learned.

A policy trained with `quad-train --randomize airframes` (`core.randomization.AIRFRAMES`) never saw
one vehicle: every episode drew a new airframe, and the motor map used that airframe's own hover
command, as its vehicle file would state it (and the true plant differed from the file, as a wrong
file does). To fly a given vehicle, nothing is retrained. `retarget_checkpoint` gives the policy
file that vehicle as its environment, so that the exported graph's motor map holds the file's
hover command and the metadata describes the file's airframe. It also permutes the rows of the
action head into the file's rotor order: output i of the head drives the training layout's rotor i,
and the file may number its rotors otherwise (RotorPy's airframes start at front-left).

Every drawn airframe is a square quad-X (quad-train refuses --vehicle with --randomize airframes),
whose rotors share the weight equally at hover. A file
whose rotors sit off the square (the asymmetric frame: front arms 6 cm ahead of the centre of mass,
rear arms 11 cm behind) hovers only with unequal thrusts, a trim the policy would have to find from
the flight history as a steady error. The file states that trim (`VehicleParams.hover_thrusts`, the
allocation with zero torque), so it goes into the action head's bias (`hover_trim`): with the motor
map's thrust linear in the action (thrust = hover thrust·(1 + a)), rotor i's action a_i + t_i holds
the file's trim where the policy's a_i = 0 holds a square frame's.

`quad-export --vehicle FILE` calls it and writes the result beside the ONNX file (`<name>.pt`), so
the source checksum the ONNX metadata records belongs to a file that exists. `quad-train --init-from`
starts a run from such a policy's weights in its vehicle's rotor order, with its trim
(`vehicle_model`, `init_from`).
"""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import torch

from quadpilot.core.params import VehicleParams, unit_layout


class RetargetError(ValueError):
    """The policy or the vehicle does not allow it: one line that says which and why."""


CORNER_TOLERANCE_DEG = 30.0
"""How far from the training layout's rotor a vehicle's rotor may sit and still be driven by its
output. A quad-X rotor sits on a diagonal, 45° from the nearest axis; a rotor within 30° of it is in
that corner by a clear margin (the asymmetric frame's are 13° to 18° off). A "+" frame's rotors sit
on the axes, 45° from two diagonals at once: that is a turned mixer, refused, not guessed."""


def rotor_permutation(trained: tuple, target: tuple) -> tuple[int, ...]:
    """For each rotor j of `target` (unit layout rows (x, y, spin), body FLU), the rotor i of
    `trained` that sits in the same direction from the centre (within CORNER_TOLERANCE_DEG) and
    spins the same way. RetargetError when there is none or the match is not one-to-one."""
    if len(trained) != len(target):
        raise RetargetError(f"the vehicle has {len(target)} rotors; the policy drives {len(trained)}")
    tolerance = math.radians(CORNER_TOLERANCE_DEG)
    order = []
    for j, (x, y, spin) in enumerate(target):
        bearing = math.atan2(y, x)
        gaps = [abs(math.remainder(math.atan2(yi, xi) - bearing, math.tau)) for xi, yi, _ in trained]
        near = [i for i, gap in enumerate(gaps) if gap <= tolerance]
        side = f"rotor {j + 1} at {math.degrees(bearing):.0f}° (FLU, from the nose, counter-clockwise)"
        if not near:
            raise RetargetError(
                f"the vehicle's {side} is not within {CORNER_TOLERANCE_DEG:.0f}° of a corner of the policy's quad-X "
                "layout (a '+' frame or a turned one); the policy drives one rotor per diagonal"
            )
        i = min(near, key=gaps.__getitem__)
        if trained[i][2] != spin:
            raise RetargetError(
                f"the vehicle's {side} spins {'+' if spin > 0 else '-'}; the policy's rotor in that corner "
                "does not: it spins the other way"
            )
        order.append(i)
    if sorted(order) != list(range(len(trained))):
        raise RetargetError(f"the vehicle's rotors map onto the policy's as {order}, not one to one")
    return tuple(order)


def _head_names(ckpt: dict) -> tuple[str, str]:
    model = ckpt["model"]
    if "actor_head.weight" in model:  # the LSTM (networks.RecurrentActorCritic)
        return "actor_head.weight", "actor_head.bias"
    layers = sorted(
        {k.rsplit(".", 1)[0] for k in model if k.startswith("actor.") and k.endswith(".weight")},
        key=lambda k: int(k.split(".")[1]),
    )
    return f"{layers[-1]}.weight", f"{layers[-1]}.bias"


def permuted_model(ckpt: dict, order: tuple[int, ...]) -> dict:
    """The checkpoint's network weights with the action head's rows (and the action's spread) put
    into `order` (`rotor_permutation`): output j of the result is output order[j] of the original."""
    model = dict(ckpt["model"])
    index = torch.tensor(order)
    for name in (*_head_names(ckpt), "log_std"):  # the action's rows (and its spread), per rotor
        if name in model:
            model[name] = model[name].index_select(0, index).clone()
    return model


def hover_trim(vehicle: VehicleParams) -> np.ndarray | None:
    """Per rotor (the vehicle's order), the action that holds its hover with zero torque, relative to
    an equal share of the weight: T_i/(W/M) − 1 with T_i = `hover_thrusts`; None for a balanced
    layout, where every share is equal and the policy's own zero action is the trim."""
    if vehicle.balanced:
        return None
    return vehicle.hover_thrusts / vehicle.hover_thrust - 1.0


def vehicle_model(
    ckpt: dict, order: tuple[int, ...], trained: VehicleParams, vehicle: VehicleParams
) -> tuple[dict, np.ndarray | None]:
    """The checkpoint's weights for `vehicle` and the offset added to its action head's bias (None:
    none): the head in the vehicle's rotor order (`permuted_model`), its bias offset by the
    vehicle's hover trim less the one the policy was trained with (`hover_trim`; both are None for
    the square frames a generalist draws, and a policy trained on an unbalanced frame has its trim
    in its weights already). RetargetError for a policy that sees its past actions (--obs-history)
    on a vehicle that numbers its rotors otherwise, or with an offset: its input would hold them in
    the vehicle's order, or shifted by what it never saw."""
    history = int(ckpt.get("ppo_config", {}).get("obs_history", 1))
    if history > 1 and list(order) != sorted(order):  # its input holds past actions, per rotor
        raise RetargetError(
            f"a policy with --obs-history {history} sees its past actions in its own rotor order, and "
            f"{vehicle.name} numbers its rotors otherwise ({[i + 1 for i in order]}); retarget it only onto a "
            "vehicle with the same order"
        )
    model = permuted_model(ckpt, order)
    new, old = hover_trim(vehicle), hover_trim(trained)
    offset = (0.0 if new is None else new) - (0.0 if old is None else old[list(order)])
    if not np.any(offset != 0.0):
        return model, None
    if history > 1:
        raise RetargetError(
            f"a policy with --obs-history {history} sees its past actions, and {vehicle.name}'s hover trim would "
            "shift them by what it never saw; retarget it only between frames with the same trim"
        )
    bias = _head_names(ckpt)[1]
    model[bias] = model[bias] + torch.as_tensor(offset, dtype=model[bias].dtype)
    return model, offset


def retarget_checkpoint(ckpt: dict, vehicle: VehicleParams, source: str = "policy") -> dict:
    """A copy of the checkpoint `ckpt` (a loaded policy.pt) that flies `vehicle`: its environment is
    `vehicle` without randomisation, its action head permuted into the vehicle's rotor order and its
    bias offset by the vehicle's hover trim (`hover_trim`) where the layout is not balanced."""
    from ..envs import EnvConfig

    env = EnvConfig.from_json(ckpt["env_config"])
    if env.randomization is None or not env.randomization.airframes:
        raise RetargetError(
            f"{source} was trained for one airframe ({env.params.name}); --vehicle flies another file only with a "
            "policy trained over drawn airframes (quad-train --randomize airframes)"
        )
    if ckpt.get("algo", "ppo") != "ppo":
        raise RetargetError(f"{source}: only PPO policies are retargeted, this one is {ckpt.get('algo')!r}")
    order = rotor_permutation(unit_layout(env.params), unit_layout(vehicle))
    out = copy.copy(ckpt)
    out["model"], trim = vehicle_model(ckpt, order, env.params, vehicle)
    out["env_config"] = dataclasses.replace(env, vehicle=vehicle, randomization=None).to_json()
    out["extra"] = {
        **dict(ckpt.get("extra", {})),
        "retargeted": {
            "from": source,
            "vehicle": vehicle.name,
            "rotor_order": list(order),
            "hover_trim": None if trim is None else [round(float(t), 9) for t in trim],
        },
    }
    for k in ("optimizer", "trainer", "env", "rng"):  # a deployable file, not a resumable one
        out[k] = {}
    return out
