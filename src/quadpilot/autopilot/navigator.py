"""The legs of a flight mode (`modes`), flown one after the other on the `setpoint.Mover`.

A leg moves the reference to a goal and is done when the vehicle has arrived (reference at the goal,
the vehicle within NAV_ACC_RAD horizontally and NAV_MC_ALT_RAD vertically, or a mission item's own
acceptance radius, for `dwell_s` or the item's hold time, as PX4's MissionBlock::
is_mission_item_reached does in src/modules/navigator/mission_block.cpp), or, for a landing, when
the land detector reports touchdown. Speeds are read from the parameters at every step, so a
PARAM_SET in flight takes effect at once: MPC_XY_CRUISE horizontally (or a DO_CHANGE_SPEED /
DO_REPOSITION speed), MPC_Z_V_AUTO_UP and MPC_Z_V_AUTO_DN vertically, MPC_TKO_SPEED while taking
off, and the landing speed schedule of `setpoint.land_speed` while landing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .setpoint import Mover, land_speed

LAND_DEPTH_M = 1000.0
"""A landing moves the reference towards this far below home; the lead limit stops it below the
vehicle once the vehicle stops on the ground."""


@dataclass
class Leg:
    """One piece of a flight task. kind: "move", "takeoff" (as move, climbing at MPC_TKO_SPEED),
    "land" (x, y of `goal` only), "wait" (`seconds`, hold the reference; < 0: for ever), "speed"
    (DO_CHANGE_SPEED `speed` = (type, m/s), instantaneous), "none" (an item with nothing to fly,
    done at once). `tag` is returned when the leg is done."""

    kind: str
    goal: np.ndarray | None = None
    seconds: float = 0.0
    acceptance: float | None = None
    speed: tuple[float, float] | None = None
    tag: object = None


class Navigator:
    """Runs a list of legs on a Mover; `update` returns the tags of the legs finished this step."""

    def __init__(self, mover: Mover, params, dwell_s: float) -> None:
        self.mover, self.params, self.dwell_s = mover, params, dwell_s
        self.legs: list[Leg] = []
        self.leg: Leg | None = None
        self.frozen = False
        self.cruise: float | None = None
        """Horizontal speed set by DO_CHANGE_SPEED or DO_REPOSITION, until the next task."""
        self.climb: float | None = None
        self.descent: float | None = None
        self._active = False
        self._inside_since: float | None = None
        self._until = 0.0

    def start(self, legs: list[Leg], keep_speed: bool = False) -> None:
        """Fly `legs` from the reference's current position (no jump)."""
        if not keep_speed:
            self.cruise = self.climb = self.descent = None
        self.legs = list(legs)
        self._next()

    def hold(self) -> None:
        """No task: stop the reference where it is and hold it there."""
        self.legs, self.leg = [], None
        self.mover.stop()

    @property
    def busy(self) -> bool:
        return self.leg is not None

    @property
    def landing(self) -> bool:
        return self.leg is not None and self.leg.kind == "land"

    @property
    def taking_off(self) -> bool:
        return self.leg is not None and self.leg.kind == "takeoff"

    def freeze(self, frozen: bool) -> None:
        """Frozen: hold the reference and make no progress (the failsafe's hold delay)."""
        if frozen and not self.frozen:
            self.mover.stop()
        if not frozen and self.frozen:
            self._active = False  # resume: aim at the leg's goal again
        self.frozen = frozen

    def reaim(self) -> None:
        """Aim the current leg at its goal again (at a new speed, from where the reference is)."""
        self._active = False

    def apply_speed(self, speed_type: float, value: float) -> None:
        """DO_CHANGE_SPEED: type 0 airspeed or 1 ground speed (horizontal), 2 climb, 3 descent;
        −1 keeps, −2 restores the parameter's value."""
        if value == -1.0:
            return
        v = None if value == -2.0 else min(float(value), self.params["MPC_XY_VEL_MAX"])
        if speed_type in (0, 1):
            self.cruise = v
        elif speed_type == 2:
            self.climb = v
        elif speed_type == 3:
            self.descent = v

    def _speeds(self, kind: str, altitude: float) -> tuple[float, float, float]:
        p = self.params
        xy = self.cruise or p["MPC_XY_CRUISE"]
        up = p["MPC_TKO_SPEED"] if kind == "takeoff" else (self.climb or p["MPC_Z_V_AUTO_UP"])
        down = self.descent or p["MPC_Z_V_AUTO_DN"]
        if kind == "land":
            down = land_speed(altitude, down, p["MPC_LAND_SPEED"], p["MPC_LAND_ALT1"], p["MPC_LAND_ALT2"])
        return xy, up, down

    def _next(self) -> None:
        self.leg = self.legs.pop(0) if self.legs else None
        self._active = False
        self._inside_since = None

    def _activate(self, now: float, altitude: float) -> None:
        leg = self.leg
        if leg.kind == "wait":
            self.mover.stop()
            self._until = now + leg.seconds
        elif leg.kind == "land":
            goal = np.array([leg.goal[0], leg.goal[1], -LAND_DEPTH_M])
            self.mover.set_goal(goal, *self._speeds("land", altitude))
        else:
            self.mover.set_goal(leg.goal, *self._speeds(leg.kind, altitude))
        self._active = True

    def _arrived(self, now: float, pos: np.ndarray, landed: bool) -> bool:
        leg = self.leg
        if leg.kind == "land":
            return landed
        if leg.kind == "wait":
            return leg.seconds >= 0 and now >= self._until
        p = self.params
        radius = leg.acceptance if leg.acceptance and leg.acceptance > 0 else p["NAV_ACC_RAD"]
        inside = (
            self.mover.at_goal
            and math.hypot(pos[0] - leg.goal[0], pos[1] - leg.goal[1]) <= radius
            and abs(pos[2] - leg.goal[2]) <= p["NAV_MC_ALT_RAD"]
        )
        if not inside:
            self._inside_since = None
            return False
        if self._inside_since is None:
            self._inside_since = now
        return now - self._inside_since >= max(self.dwell_s, leg.seconds)

    def update(self, now: float, dt: float, pos, landed: bool) -> list:
        pos = np.asarray(pos, np.float64)
        done = []
        while self.leg is not None and not self.frozen:
            if self.leg.kind in ("speed", "none"):
                if self.leg.kind == "speed":
                    self.apply_speed(*self.leg.speed)
                done.append(self.leg.tag)
                self._next()
                continue
            if not self._active:
                self._activate(now, float(pos[2]))
            if not self._arrived(now, pos, landed):
                break
            done.append(self.leg.tag)
            self._next()
        if self.leg is not None and self.leg.kind == "land" and not self.frozen:
            self.mover.speed_down = self._speeds("land", float(pos[2]))[2]
        self.mover.update(dt, pos)
        return done


def outside_fence(goal, params) -> str | None:
    """Why `goal` (ENU from home) breaks GF_MAX_HOR_DIST / GF_MAX_VER_DIST (0: no limit), or None."""
    hor, ver = params["GF_MAX_HOR_DIST"], params["GF_MAX_VER_DIST"]
    d = math.hypot(goal[0], goal[1])
    if hor > 0 and d > hor:
        return f"{d:.1f} m from home, geofence {hor:g} m"
    if ver > 0 and goal[2] > ver:
        return f"{goal[2]:.1f} m above home, geofence {ver:g} m"
    return None
