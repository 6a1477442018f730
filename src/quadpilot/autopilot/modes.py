"""The navigator's flight modes, one class each, as PX4's navigator has them (src/modules/navigator:
takeoff.cpp, land.cpp, rtl.cpp, loiter.cpp, mission.cpp, each a NavigatorMode).

A mode knows its PX4 custom mode (src/modules/commander/px4_custom_mode.h: AUTO = 4 with sub-modes
2 TAKEOFF, 3 LOITER (Hold), 4 MISSION, 5 RTL, 6 LAND) and the legs it flies from the reference's
position (`legs`), which the commander hands to `navigator.Navigator`; `Mission` also keeps where
in the uploaded mission the vehicle is. Position mode (POSCTL, 3) is not a navigator mode in PX4
(the position flight task flies it): here it holds, as Hold does.

- `Takeoff` (takeoff.cpp): climb at the current position; when reached, Hold ("mode_completed").
- `Land` (land.cpp): descend at a horizontal position until the land detector reports touchdown.
- `Return` (rtl.cpp, `calculate_return_alt_from_cone_half_angle`, the RTL_* parameter descriptions):
  climb at the current position to the return altitude (RTL_RETURN_ALT above home, lowered inside
  the RTL_CONE_ANG cone near home, never below RTL_DESCEND_ALT, never a descent), fly home at that
  altitude, descend to RTL_DESCEND_ALT, wait RTL_LAND_DELAY (−1: stay), land.
- `Loiter` (loiter.cpp): hold where the reference is, or fly to a reposition goal and hold there.
- `Mission` (mission.cpp): the current item's legs, a take-off first when started on the ground;
  MISSION_CURRENT and MISSION_ITEM_REACHED, which it builds, are sent by the commander.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.link.frames import Home

from . import mission_protocol
from .navigator import Leg, outside_fence

M = mavlink2

POSCTL = (3, 0)


class Mode:
    """A navigator mode: its PX4 custom mode (main, sub), its name (as MAVSDK's FlightMode), the legs
    it flies from the reference's position `ref` (ENU m from home), and whether the cruise speed a
    DO_CHANGE_SPEED set carries over into it."""

    custom_mode: ClassVar[tuple[int, int]]
    name: ClassVar[str]
    keep_speed: ClassVar[bool] = False

    def legs(self, ref: np.ndarray, params) -> list[Leg]:
        """The legs to fly."""
        raise NotImplementedError


class Takeoff(Mode):
    custom_mode, name = (4, 2), "Takeoff"

    def __init__(self, altitude: float, tag: object = "takeoff") -> None:
        self.altitude, self.tag = float(altitude), tag

    def legs(self, ref, params) -> list[Leg]:
        """Climb at the reference's horizontal position to `altitude` m above home (never down)."""
        goal = np.array([ref[0], ref[1], max(self.altitude, float(ref[2]))])
        return [Leg("takeoff", goal, tag=self.tag)]


class Land(Mode):
    custom_mode, name = (4, 6), "Land"

    def __init__(self, xy, tag: object = "land") -> None:
        self.xy, self.tag = (float(xy[0]), float(xy[1])), tag

    def legs(self, ref=None, params=None) -> list[Leg]:
        return [Leg("land", np.array([self.xy[0], self.xy[1], 0.0]), tag=self.tag)]


class Return(Mode):
    custom_mode, name = (4, 5), "Return"

    def __init__(self, tag: object = "rtl") -> None:
        self.tag = tag

    @staticmethod
    def altitude(pos, params) -> float:
        """Return altitude above home (m) from the current position (home at the origin)."""
        dist = math.hypot(pos[0], pos[1])
        ret, desc, cone = params["RTL_RETURN_ALT"], params["RTL_DESCEND_ALT"], params["RTL_CONE_ANG"]
        alt = float(pos[2])
        if dist <= params["RTL_MIN_DIST"]:
            target = desc
        elif alt > ret or cone >= 90:
            target = alt
        elif cone <= 0:
            target = ret
        else:
            needed = dist / math.tan(math.radians(min(max(cone, 1.0), 89.0)))
            target = max(alt, min(max(needed, 0.0), ret))
        return max(target, desc)

    def legs(self, ref, params) -> list[Leg]:
        ref = np.asarray(ref, np.float64)
        alt = max(self.altitude(ref, params), float(ref[2]))  # climb first; never descend before returning
        desc = min(params["RTL_DESCEND_ALT"], alt)
        legs = [
            Leg("move", np.array([ref[0], ref[1], alt])),
            Leg("move", np.array([0.0, 0.0, alt])),
            Leg("move", np.array([0.0, 0.0, desc])),
        ]
        delay = params["RTL_LAND_DELAY"]
        if delay != 0:
            legs.append(Leg("wait", seconds=delay))
        return legs + Land((0.0, 0.0), tag=self.tag).legs()


class Loiter(Mode):
    """Hold (AUTO_LOITER), where PX4 also flies DO_REPOSITION: fly to `goal` and hold there (the
    speed a DO_CHANGE_SPEED set carries over, navigator_main.cpp). Holding where the reference is
    needs no legs: `Commander.hold`."""

    custom_mode, name = (4, 3), "Hold"
    keep_speed = True

    def __init__(self, goal: np.ndarray) -> None:
        self.goal = goal

    def legs(self, ref=None, params=None) -> list[Leg]:
        return [Leg("move", self.goal, tag="goto")]


class Mission(Mode):
    """Where the vehicle is in the uploaded mission (`transfer.items`): the current item `seq`, the
    MAVLink MISSION_STATE, the last item reached (−1: none) and how often its MISSION_ITEM_REACHED
    has been repeated. A new upload or a clear starts it over (`changed`)."""

    custom_mode, name = (4, 4), "Mission"

    def __init__(self, transfer: mission_protocol.MissionTransfer, mav) -> None:
        self.transfer, self.mav = transfer, mav
        self.seq, self.state, self.reached = 0, M.MISSION_STATE_NO_MISSION, -1
        self.reached_resends = 0
        self._version = 0

    @property
    def items(self) -> list:
        return self.transfer.items

    @property
    def active(self) -> bool:
        return self.state == M.MISSION_STATE_ACTIVE

    def current(self, flying_it: bool):
        """MISSION_CURRENT; `flying_it`: the vehicle is in Mission mode (mission_mode 1, else 2)."""
        n = len(self.items)
        return self.mav.mission_current_encode(self.seq, n if n else 65535, self.state, 1 if flying_it else 2)

    def changed(self) -> bool:
        """Start over after an upload or a clear; True when that happened (a MISSION_CURRENT is due)."""
        if self.transfer.version == self._version:
            return False
        self._version = self.transfer.version
        self.seq, self.reached = 0, -1
        self.state = M.MISSION_STATE_NOT_STARTED if self.items else M.MISSION_STATE_NO_MISSION
        return True

    def refusal(self, home: Home | None, params) -> str | None:
        """Why the mission cannot start now (for a DENIED or, without a position, TEMPORARILY_REJECTED)."""
        if not self.items:
            return "Mission denied: no mission uploaded"
        if home is None:
            return "Mission denied: no position yet"
        for it in self.items:
            if it.has_position() and (fence := outside_fence(it.local(home), params)):
                return f"Mission denied: item {it.seq} {fence}"[:50]
        return None

    def begin(self, first: int | None) -> None:
        """Start at item `first`, or where it was paused (from the start when it was complete)."""
        if first is not None:
            self.seq, self.reached = first, -1
        elif self.state == M.MISSION_STATE_COMPLETE:
            self.seq, self.reached = 0, -1

    def legs(self, ref, params, home: Home | None = None, landed: bool = False) -> list[Leg]:
        """The current item's legs, after a take-off when started on the ground (mission.cpp)."""
        legs = self.item_legs(self.items[self.seq], ref, home, params)
        if landed:
            alt = self.takeoff_altitude(home, params)
            if alt is not None:
                legs = Takeoff(alt, tag=None).legs(ref, params) + legs
        self.state = M.MISSION_STATE_ACTIVE
        return legs

    def item_yaw(self, seq: int) -> float | None:
        """The heading (rad, MAVLink: clockwise from north) a waypoint item asks for, or None."""
        item = self.items[seq]
        if item.command == mission_protocol.NAV_WAYPOINT and math.isfinite(item.param4):
            return math.radians(item.param4)
        return None

    def pause(self) -> bool:
        """Leaving Mission mode pauses a mission being flown; True when it was."""
        if self.state != M.MISSION_STATE_ACTIVE:
            return False
        self.state = M.MISSION_STATE_PAUSED
        return True

    def item_reached(self, seq: int) -> str:
        """Item `seq` reached: "finished" (the last), "wait" (not autocontinue: paused at the next
        until told to go on) or "next" (`seq` is now the next, whose legs `next_legs` gives)."""
        self.reached, self.reached_resends = seq, 0
        if seq + 1 >= len(self.items):
            self.state = M.MISSION_STATE_COMPLETE
            return "finished"
        self.seq = seq + 1
        if not self.items[seq].autocontinue:
            self.state = M.MISSION_STATE_PAUSED
            return "wait"
        return "next"

    def next_legs(self, ref, home: Home, params) -> list[Leg]:
        return self.item_legs(self.items[self.seq], ref, home, params)

    def repeat_reached(self):
        """PX4 repeats the last MISSION_ITEM_REACHED with MISSION_CURRENT (mavlink_mission.cpp, up
        to 10 times): the message, or None."""
        if self.reached < 0 or self.reached_resends >= 10:
            return None
        self.reached_resends += 1
        return self.mav.mission_item_reached_encode(self.reached)

    def takeoff_altitude(self, home: Home, params) -> float | None:
        """Altitude above home a mission started on the ground first takes off to, or None when its
        current item is itself a take-off: MIS_TAKEOFF_ALT, or the first waypoint's altitude if
        higher (mission.cpp: a mission started landed takes off first)."""
        first = self.items[self.seq]
        if first.command == mission_protocol.NAV_TAKEOFF:
            return None
        alt = params["MIS_TAKEOFF_ALT"]
        if first.command == mission_protocol.NAV_WAYPOINT:
            alt = max(alt, float(first.local(home)[2]))
        return alt

    @staticmethod
    def item_legs(item: mission_protocol.MissionItem, ref, home: Home, params) -> list[Leg]:
        """The legs of one mission item; the last one carries the tag ("item", seq)."""
        tag = ("item", item.seq)
        ref = np.asarray(ref, np.float64)
        cmd = item.command
        if cmd == mission_protocol.NAV_WAYPOINT:
            hold = item.param1 if math.isfinite(item.param1) and item.param1 > 0 else 0.0
            radius = item.param2 if math.isfinite(item.param2) and item.param2 > 0 else None
            return [Leg("move", item.local(home), seconds=hold, acceptance=radius, tag=tag)]
        if cmd == mission_protocol.NAV_TAKEOFF:
            return Takeoff(item.local(home)[2], tag=tag).legs(ref, params)
        if cmd == mission_protocol.NAV_LAND:
            if not item.has_position():
                return Land(ref, tag=tag).legs()
            p = item.local(home)
            return [Leg("move", np.array([p[0], p[1], ref[2]])), *Land(p, tag=tag).legs()]
        if cmd == mission_protocol.NAV_RETURN_TO_LAUNCH:
            return Return(tag=tag).legs(ref, params)
        if cmd == mission_protocol.NAV_DELAY:
            return [Leg("wait", seconds=float(item.param1), tag=tag)]
        if cmd == mission_protocol.DO_CHANGE_SPEED:
            return [Leg("speed", speed=(item.param1, item.param2), tag=tag)]
        if cmd in mission_protocol.PAYLOAD_COMMANDS:  # no gimbal or camera here: reached at once
            return [Leg("none", tag=tag)]
        raise ValueError(f"mission item {item.seq}: command {cmd} has no legs")


NAVIGATOR_MODES = (Takeoff, Land, Return, Loiter, Mission)
HOLD, TAKEOFF, MISSION, RTL, LAND = (m.custom_mode for m in (Loiter, Takeoff, Mission, Return, Land))
MODE_NAMES = {HOLD: "Hold", TAKEOFF: "Takeoff", MISSION: "Mission", RTL: "Return", LAND: "Land", POSCTL: "Position"}
"""PX4 custom mode (main, sub) → name, in the order the docs' mode table lists them."""
