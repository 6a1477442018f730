"""A RotorPy airframe (the `quad_params` dict of a rotorpy/vehicles/*_params.py module) as a
vehicle file, with nothing its dynamics uses dropped:

    python -m quadpilot.core.rotorpy_vehicle rotorpy.vehicles.hummingbird_params -o hummingbird.toml

| RotorPy (`Multirotor`) | vehicle file |
|---|---|
| `mass`, `Ixx`, `Iyy`, `Izz` | `mass`, `ixx`, `iyy`, `izz` (`Ixy`, `Ixz`, `Iyz` must be 0: principal axes) |
| `k_eta`, `k_m` | `k_thrust`, `k_torque` |
| `rotor_speed_max`, `rotor_speed_min`, `tau_m` | `omega_max`, `omega_min`, `motor_tau` |
| `c_Dx`, `c_Dy`, `c_Dz` | `drag_quadratic` |
| `k_d`, `k_z`, `k_h`, `k_flap` | the same names |
| `rotor_pos` r1..r4 (FLU, z = 0) | `[[rotor]]` in that order, y negated (FRD) |
| `rotor_directions` | each rotor's `spin`: +1 is `cw`, −1 `ccw` |

Not carried, because RotorPy's dynamics do not use them or they are not the airframe's: the IMU
position `rI`, `rotor_radius`, `motor_noise_std` (a simulator option: quad-sitl's noise flags), and
the gains of RotorPy's own low-level controllers (`k_w`, `k_v`, `kp_att`, `kd_att`). Refused in one
line: a key the dynamics uses that the model cannot hold (products of inertia, a rotor above or
below the centre of mass, not four rotors).
"""

from __future__ import annotations

import argparse
import importlib
import math
import re
import sys
from pathlib import Path

from .params import Rotor, VehicleParams, VehicleParamsError
from .vehicle_file import NAME_PATTERN, NAME_RULE, vehicle_to_toml

SOURCE_KEYS = {
    "mass": "mass",
    "ixx": "Ixx",
    "iyy": "Iyy",
    "izz": "Izz",
    "k_thrust": "k_eta",
    "k_torque": "k_m",
    "omega_max": "rotor_speed_max",
    "omega_min": "rotor_speed_min",
    "motor_tau": "tau_m",
    "drag": None,
    "drag_quadratic": "c_Dx, c_Dy, c_Dz",
    "k_d": "k_d",
    "k_z": "k_z",
    "k_h": "k_h",
    "k_flap": "k_flap",
}
"""Vehicle-file key → the RotorPy key it is written from (each line of a written file cites it)."""

IGNORED = ("rI", "rotor_radius", "motor_noise_std", "k_w", "k_v", "kp_att", "kd_att", "num_rotors")
"""RotorPy keys that are not the airframe's dynamics (module docstring)."""

_ZERO_DEFAULT = ("c_Dx", "c_Dy", "c_Dz", "k_d", "k_z", "k_h", "k_flap", "Ixy", "Ixz", "Iyz", "rotor_speed_min")
"""Keys RotorPy's Multirotor reads with `quad_params.get(key, 0.0)` (or treats as 0 when absent)."""


class RotorPyAirframeError(ValueError):
    """A RotorPy airframe this model cannot hold; one line saying which key and why."""


def vehicle_from_rotorpy(quad_params: dict, name: str) -> VehicleParams:
    """The `VehicleParams` of a RotorPy airframe (module docstring)."""

    def number(key: str) -> float:
        if key not in quad_params:
            if key in _ZERO_DEFAULT:
                return 0.0
            raise RotorPyAirframeError(f"{key}: missing; RotorPy's Multirotor needs it")
        v = quad_params[key]
        try:
            f = float(v)
        except (TypeError, ValueError):
            raise RotorPyAirframeError(f"{key} = {v!r}: expected a number") from None
        if not math.isfinite(f):
            raise RotorPyAirframeError(f"{key} = {v!r}: expected a finite number")
        return f

    for key in ("Ixy", "Ixz", "Iyz"):
        if number(key) != 0.0:
            raise RotorPyAirframeError(
                f"{key} = {number(key)}: the model takes a diagonal inertia (principal axes); expected 0"
            )
    positions = quad_params.get("rotor_pos")
    directions = quad_params.get("rotor_directions")
    if not isinstance(positions, dict) or directions is None:
        raise RotorPyAirframeError("rotor_pos and rotor_directions: missing; expected one entry per rotor")
    directions = [float(d) for d in list(directions)]
    if len(positions) != 4 or len(directions) != 4:
        raise RotorPyAirframeError(
            f"rotor_pos: {len(positions)} rotors, rotor_directions: {len(directions)}; expected 4 (the policy's action)"
        )
    rotors = []
    for (label, pos), direction in zip(positions.items(), directions, strict=True):
        x, y, z = (float(c) for c in list(pos))
        if z != 0.0:
            raise RotorPyAirframeError(f"rotor_pos {label}: z = {z}; the model's rotors lie in the body x-y plane")
        if direction not in (1.0, -1.0):
            raise RotorPyAirframeError(f"rotor_directions: {direction} for {label}; expected +1 or -1")
        # FLU → FRD; RotorPy's direction is the sign of the rotor's yaw moment on the body: +1 is clockwise
        rotors.append(Rotor(x, -y, "cw" if direction > 0 else "ccw"))
    k_eta = number("k_eta")
    try:
        return VehicleParams(
            name=name,
            mass=number("mass"),
            arm=None,  # the rotors' mean distance (what a vehicle file derives)
            ixx=number("Ixx"),
            iyy=number("Iyy"),
            izz=number("Izz"),
            k_f=k_eta,
            k_m=number("k_m") / k_eta,
            omega_max=number("rotor_speed_max"),
            motor_tau=number("tau_m"),
            omega_min=number("rotor_speed_min"),
            rotors=tuple(rotors),
            c_dx=number("c_Dx"),
            c_dy=number("c_Dy"),
            c_dz=number("c_Dz"),
            k_d=number("k_d"),
            k_z=number("k_z"),
            k_h=number("k_h"),
            k_flap=number("k_flap"),
        )
    except VehicleParamsError as e:
        raise RotorPyAirframeError(str(e)) from None


MIN_TAU_M_S = 0.001
"""s: the motor time constant RotorPy is given for a vehicle without one (0 would divide by zero)."""


def rotorpy_params(v: VehicleParams) -> dict:
    """The other way: a vehicle as RotorPy's `quad_params`, for flying a vehicle file in RotorPy's
    simulators (its Multirotor, PX4Multirotor). RotorPy has no linear drag: a vehicle with `drag` > 0
    is refused (RotorPyAirframeError) rather than flown without it. A vehicle without a motor lag is
    given `MIN_TAU_M_S` (RotorPy's rotor dynamics divide by it)."""
    if v.drag > 0:
        raise RotorPyAirframeError(
            f"vehicle {v.name!r}: drag = {v.drag} N s/m (linear): RotorPy has no linear drag; "
            "expected drag = 0 (RotorPy's is drag_quadratic)"
        )
    import numpy as np  # the rotor positions as RotorPy's arrays

    return {
        "mass": v.mass,
        "Ixx": v.ixx,
        "Iyy": v.iyy,
        "Izz": v.izz,
        "Ixy": 0.0,
        "Iyz": 0.0,
        "Ixz": 0.0,
        "num_rotors": 4,
        "rotor_radius": 0.0,  # not used by RotorPy's dynamics
        "rotor_pos": {f"r{i}": np.array([r.x, -r.y, 0.0]) for i, r in enumerate(v.rotors, start=1)},
        "rotor_directions": np.array([1 if r.spin == "cw" else -1 for r in v.rotors]),
        "rI": np.zeros(3),
        "c_Dx": v.c_dx,
        "c_Dy": v.c_dy,
        "c_Dz": v.c_dz,
        "k_eta": v.k_f,
        "k_m": v.k_m * v.k_f,
        "k_d": v.k_d,
        "k_z": v.k_z,
        "k_h": v.k_h,
        "k_flap": v.k_flap,
        # RotorPy integrates the rotor lag as (command − speed)/tau_m and divides by zero without one:
        # a vehicle without lag gets MIN_TAU_M_S, a tenth of a 100 Hz control step
        "tau_m": max(v.motor_tau, MIN_TAU_M_S),
        "rotor_speed_min": v.omega_min,
        "rotor_speed_max": v.omega_max,
        "motor_noise_std": 0.0,
    }


def cite_sources(text: str, module: str) -> str:
    """A written vehicle file with every value's RotorPy source added to its comment."""
    out, rotor = [], 0
    for line in text.splitlines():
        key = line.split("=", 1)[0].strip()
        if line.startswith("[[rotor]]"):
            rotor += 1
        elif key in SOURCE_KEYS and "#" in line:
            src = SOURCE_KEYS[key]
            line += f", {module} {src}" if src else f" (RotorPy has no linear drag: {module} gives none)"
        elif key in ("x", "y"):
            line += f", {module} rotor_pos r{rotor}" + (" (FLU y negated)" if key == "y" else "")
        elif key == "spin":
            line += f"  # {module} rotor_directions[{rotor - 1}] (+1 cw, -1 ccw)"
        out.append(line)
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m quadpilot.core.rotorpy_vehicle",
        description="Write a RotorPy airframe module's quad_params as a quadpilot vehicle file.",
    )
    ap.add_argument("module", help="a RotorPy parameter module, e.g. rotorpy.vehicles.crazyflie_params")
    ap.add_argument("--name", help="the vehicle's name (default: the module's last part without _params)")
    ap.add_argument("-o", "--out", type=Path, help="the .toml file to write (default: print it)")
    args = ap.parse_args(argv)
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*", args.module):
        print(f"error: {args.module!r}: expected a dotted module name, not a path", file=sys.stderr)
        return 2
    name = args.name or args.module.rsplit(".", 1)[-1].removesuffix("_params")
    if not NAME_PATTERN.fullmatch(name):
        print(f"error: --name {name!r}: expected {NAME_RULE}", file=sys.stderr)
        return 2
    try:
        module = importlib.import_module(args.module)
    except ImportError as e:
        print(f"error: cannot import {args.module}: {e} (pip install rotorpy)", file=sys.stderr)
        return 1
    params = getattr(module, "quad_params", None)
    if not isinstance(params, dict):
        print(f"error: {args.module} has no quad_params dict; expected a RotorPy parameter module", file=sys.stderr)
        return 1
    try:
        vehicle = vehicle_from_rotorpy(params, name)
    except RotorPyAirframeError as e:
        print(f"error: {args.module}: {e}", file=sys.stderr)
        return 1
    head = f"# {args.module} (RotorPy), written by python -m quadpilot.core.rotorpy_vehicle\n"
    text = head + cite_sources(vehicle_to_toml(vehicle), args.module)
    if args.out is None:
        sys.stdout.write(text)
    else:
        args.out.write_text(text, encoding="utf-8")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
