"""The commands a ground station sends (COMMAND_LONG, COMMAND_INT, SET_MODE) and their answers.

`CommandHandlers` is the half of `commander.Commander` that executes commands; it works on the
commander's state (arming, mode, navigator, missions, streams), which `commander` owns.

- Every COMMAND_LONG and COMMAND_INT for this vehicle gets exactly one COMMAND_ACK: ACCEPTED, DENIED
  (cannot be done: bad parameters or not in this state), TEMPORARILY_REJECTED (not yet: no position
  or home), UNSUPPORTED (unknown command), COMMAND_INT_ONLY (DO_REPOSITION as COMMAND_LONG: its
  float latitude would be ~0.4 m coarse), FAILED (an internal error, counted). A refusal also gets
  a STATUSTEXT saying why. MAVSDK resends a command every 0.5 s with `confirmation` counting up
  until it hears the ACK: a COMMAND_LONG repeated with confirmation > 0 within `repeat_window_s`
  is answered with the first answer and not executed again; the handlers are also idempotent
  (taking off, landing or returning while already doing it changes nothing).
- Arming (PX4 src/modules/commander/Commander.cpp, arm/disarm): arm only on the ground with a
  position; disarm only when landed unless param2 = 21196 (forced, MAVLink COMPONENT_ARM_DISARM).
  A disarmed vehicle takes no take-off, goto, land or return; a landed one no goto or return.
- NAV_TAKEOFF altitude (src/modules/navigator/takeoff.cpp): param7 (AMSL; above home for a
  COMMAND_INT in frame 3 or 6) if finite, else the current altitude + MIS_TAKEOFF_ALT; below the
  current altitude it is refused. When reached: Hold (PX4: "mode_completed" → Hold).
- DO_REPOSITION (src/modules/navigator/navigator_main.cpp): COMMAND_INT, frame 0/5 (altitude AMSL)
  or 3/6 (above home), x/y INT32_MAX or z NaN keep the current goal, param1 > 0 the speed, param4
  yaw in radians (as PX4 reads it, though common.xml says degrees; NaN keeps); switches to Hold
  (AUTO/LOITER, where PX4 flies repositions) and flies there.
- DO_SET_MODE with PX4 custom modes (MAVSDK's hold, start_mission and return_to_launch; base_mode
  must carry CUSTOM_MODE_ENABLED), SET_MODE likewise (acknowledged as DO_SET_MODE, as PX4 does),
  MISSION_START (param1 the first item), NAV_LAND (at the current position, as
  src/modules/navigator/land.cpp), NAV_RETURN_TO_LAUNCH, DO_CHANGE_SPEED.
- REQUEST_MESSAGE (the message, then the ACK), SET_MESSAGE_INTERVAL, GET_MESSAGE_INTERVAL,
  GET_HOME_POSITION and REQUEST_AUTOPILOT_CAPABILITIES for the telemetry of `streams`.
- A geofence (GF_MAX_HOR_DIST, GF_MAX_VER_DIST) refuses take-off, goto and mission goals beyond it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.core.state import POS_XY, Z
from quadpilot.link.frames import geodetic_to_local

from . import mission_protocol, navigator, streams
from .navigator import Leg

M = mavlink2
ACCEPTED, TEMP_REJECTED, DENIED = M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_TEMPORARILY_REJECTED, M.MAV_RESULT_DENIED
UNSUPPORTED, FAILED = M.MAV_RESULT_UNSUPPORTED, M.MAV_RESULT_FAILED
FORCE_DISARM = 21196  # COMPONENT_ARM_DISARM param2 that disarms in flight (MAVLink common.xml)
INT32_MAX = 2**31 - 1  # COMMAND_INT x/y "unchanged"

# PX4 custom modes (main, sub), src/modules/commander/px4_custom_mode.h
HOLD, TAKEOFF, MISSION, RTL, LAND, POSCTL = (4, 3), (4, 2), (4, 4), (4, 5), (4, 6), (3, 0)
MODE_NAMES = {HOLD: "Hold", TAKEOFF: "Takeoff", MISSION: "Mission", RTL: "Return", LAND: "Land", POSCTL: "Position"}


@dataclass
class _Cmd:
    command: int
    p: tuple  # param1..param4
    x: float  # param5 (COMMAND_LONG) or x (COMMAND_INT)
    y: float
    z: float
    frame: int | None  # None: COMMAND_LONG
    src: tuple


class CommandHandlers:
    """COMMAND_LONG / COMMAND_INT / SET_MODE → COMMAND_ACK (see the module docstring)."""

    def _on_set_mode(self, msg) -> None:
        """SET_MODE (deprecated): as DO_SET_MODE, acknowledged as that command (as PX4 does)."""
        main, sub = (msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        self._execute(_Cmd(M.MAV_CMD_DO_SET_MODE, (msg.base_mode, main, sub, 0.0), 0, 0, 0, None, src), repeat=False)

    def _on_command(self, msg) -> None:
        is_int = msg.get_type() == "COMMAND_INT"
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        p = (msg.param1, msg.param2, msg.param3, msg.param4)
        if is_int:
            cmd = _Cmd(msg.command, p, msg.x, msg.y, msg.z, msg.frame, src)
        else:
            cmd = _Cmd(msg.command, p, msg.param5, msg.param6, msg.param7, None, src)
        self._execute(cmd, repeat=not is_int and msg.confirmation > 0)

    def _execute(self, c: _Cmd, repeat: bool) -> None:
        key = (c.src, c.command, c.frame is not None)
        args = (c.p, c.x, c.y, c.z, c.frame)
        prior = self._recent.get(key)
        if repeat and prior is not None and _same(prior[0], args) and self.now - prior[2] <= self.cfg.repeat_window_s:
            result = prior[1]  # a resend: answered as before, not done twice
        else:
            handler = self._COMMANDS.get(c.command)
            if handler is None:
                result, why = UNSUPPORTED, None
            else:
                try:
                    result, why = handler(self, c)
                except Exception as e:  # never silence, never a dead loop: the ACK says it failed
                    self.dropped["command_error"] += 1
                    result, why = FAILED, f"command {c.command} failed: {type(e).__name__}"
            if why:
                self._text(why, M.MAV_SEVERITY_WARNING if result != ACCEPTED else M.MAV_SEVERITY_INFO)
            self._recent[key] = (args, result, self.now)
        self._out.append(self.mav.command_ack_encode(c.command, result, 0, 0, c.src[0], c.src[1]))

    # --- commands ------------------------------------------------------------------------------------
    def _armable(self) -> str | None:
        """Why the vehicle may not arm now, or None."""
        if self.state is None or self.home is None:
            return "no position yet"
        g = self.cfg.ground_alt_max_m
        if g is not None and self.state[Z] > g:
            return f"not on the ground ({self.state[Z]:.1f} m above home)"
        if self.failsafe:
            return "failsafe active"
        return None

    def _cmd_arm(self, c: _Cmd) -> tuple[int, str | None]:
        if c.p[0] == 1.0:
            if self.armed:
                return (ACCEPTED, None) if self.landed else (DENIED, "Arming denied: already flying")
            why = self._armable()
            if why is not None:
                return (TEMP_REJECTED if self.state is None else DENIED), f"Arming denied: {why}"
            self._arm()
            return ACCEPTED, "Armed by external command"
        if c.p[0] != 0.0:
            return DENIED, f"arm/disarm: param1 {c.p[0]}, expected 0 or 1"
        if not self.armed:
            return ACCEPTED, None
        if not self.landed and c.p[1] != FORCE_DISARM:
            return DENIED, "Disarming denied: not landed"
        self._disarm()
        return ACCEPTED, "Disarmed by external command"

    def _cmd_takeoff(self, c: _Cmd) -> tuple[int, str | None]:
        if (why := self._need("Takeoff", land_ok=True)) is not None:
            return why
        s = self.state
        if math.isfinite(c.z):
            alt = c.z if c.frame in mission_protocol.RELATIVE_FRAMES else c.z - self.home.alt_m
        elif self.mode == TAKEOFF and self.nav.taking_off:
            return ACCEPTED, None  # the same take-off again
        else:
            alt = float(s[Z]) + self.params["MIS_TAKEOFF_ALT"]
        if alt <= s[Z]:
            return DENIED, "Takeoff denied: already higher than that"  # ≤ 50 chars: STATUSTEXT
        goal = np.array([self.mover.ref[0], self.mover.ref[1], alt])
        if (fence := navigator.outside_fence(goal, self.params)) is not None:
            return DENIED, f"Takeoff denied: {fence}"
        self._leave_mission()
        self.nav.start(navigator.takeoff_legs(self.mover.ref, alt))
        self._set_mode(TAKEOFF)
        return ACCEPTED, f"Takeoff to {alt:.1f} m"

    def _cmd_land(self, c: _Cmd) -> tuple[int, str | None]:
        if (why := self._need("Land", land_ok=True)) is not None:
            return why
        if self.mode == LAND:
            return ACCEPTED, None
        self._leave_mission()
        self.nav.start(navigator.land_legs(self.state[POS_XY]))
        self._set_mode(LAND)
        return ACCEPTED, None

    def _cmd_rtl(self, c: _Cmd) -> tuple[int, str | None]:
        if (why := self._need("Return")) is not None:
            return why
        if self.mode == RTL:
            return ACCEPTED, None
        self._leave_mission()
        self.nav.start(navigator.rtl_legs(self.mover.ref, self.params))
        self._set_mode(RTL)
        return ACCEPTED, None

    def _cmd_reposition(self, c: _Cmd) -> tuple[int, str | None]:
        if c.frame is None:
            return M.MAV_RESULT_COMMAND_INT_ONLY, "DO_REPOSITION: send it as COMMAND_INT"
        if (why := self._need("Goto")) is not None:
            return why
        if c.frame not in mission_protocol.GLOBAL_FRAMES:
            return DENIED, f"Goto denied: frame {c.frame}, expected 0, 3, 5 or 6"
        goal = (
            self.nav.leg.goal.copy()
            if self.nav.leg is not None and self.nav.leg.goal is not None
            else self.mover.goal.copy()
        )
        if c.x != INT32_MAX and c.y != INT32_MAX:
            if not (-900_000_000 <= c.x <= 900_000_000 and -1_800_000_000 <= c.y <= 1_800_000_000):
                return DENIED, f"Goto denied: lat/lon {c.x}/{c.y} degE7 off the globe"
            goal[0:2] = geodetic_to_local(c.x, c.y, 0, self.home)[0:2]
        if math.isfinite(c.z):
            goal[2] = c.z if c.frame in mission_protocol.RELATIVE_FRAMES else c.z - self.home.alt_m
        if (fence := navigator.outside_fence(goal, self.params)) is not None:
            return DENIED, f"Goto denied: {fence}"
        self._leave_mission()
        # the speed set by DO_CHANGE_SPEED carries over (navigator_main.cpp: param1 < 0 → the current cruising speed)
        self.nav.start([Leg("move", goal, tag="goto")], keep_speed=True)
        if math.isfinite(c.p[0]) and c.p[0] > 0:
            self.nav.cruise = min(float(c.p[0]), self.params["MPC_XY_VEL_MAX"])
        if math.isfinite(c.p[3]):
            self.yaw = enu_yaw(c.p[3])
        self._set_mode(HOLD)
        return ACCEPTED, None

    def _cmd_set_mode(self, c: _Cmd) -> tuple[int, str | None]:
        base, main, sub = c.p[0], c.p[1], c.p[2]
        if not all(math.isfinite(v) for v in (base, main, sub)) or not int(base) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return DENIED, "Mode denied: expected a PX4 custom mode"
        mode = (int(main), int(sub)) if int(main) == 4 else (int(main), 0)
        if mode not in MODE_NAMES:
            return DENIED, f"Mode {int(main)}/{int(sub)} not supported"
        if mode == self.mode:
            return ACCEPTED, None
        if mode == TAKEOFF:
            return self._cmd_takeoff(_Cmd(M.MAV_CMD_NAV_TAKEOFF, (math.nan,) * 4, 0, 0, math.nan, None, c.src))
        if mode == LAND:
            return self._cmd_land(c)
        if mode == RTL:
            return self._cmd_rtl(c)
        if mode == MISSION:
            return self._start_mission(None)
        self._leave_mission()  # Hold or Position: stop and hold where the reference is
        if self.armed:
            self.nav.hold()
        self._set_mode(mode)
        return ACCEPTED, None

    def _cmd_mission_start(self, c: _Cmd) -> tuple[int, str | None]:
        first = c.p[0]
        if not math.isfinite(first) or not 0 <= first < max(1, len(self.missions.items)):
            return DENIED, f"Mission start denied: first item {first}"
        return self._start_mission(int(first))

    def _cmd_change_speed(self, c: _Cmd) -> tuple[int, str | None]:
        kind, speed = c.p[0], c.p[1]
        if kind not in (0, 1, 2, 3) or not (speed in (-1.0, -2.0) or (math.isfinite(speed) and speed > 0)):
            return DENIED, f"Speed change denied: type {kind}, speed {speed}"
        self.nav.apply_speed(kind, speed)
        self.nav._active = False  # re-aim the current leg at the new speed
        return ACCEPTED, None

    def _cmd_request_message(self, c: _Cmd) -> tuple[int, str | None]:
        msg_id = int(c.p[0]) if math.isfinite(c.p[0]) else -1
        if msg_id not in streams.REQUESTABLE:
            return UNSUPPORTED, None
        msg = self._message(msg_id)
        if msg is None:
            return TEMP_REJECTED, None
        self._out.append(msg)  # the message, then its ACK
        return ACCEPTED, None

    def _cmd_home(self, c: _Cmd) -> tuple[int, str | None]:
        return self._cmd_request_message(_Cmd(c.command, (streams.HOME_POSITION, 0, 0, 0), 0, 0, 0, None, c.src))

    def _cmd_capabilities(self, c: _Cmd) -> tuple[int, str | None]:
        return self._cmd_request_message(_Cmd(c.command, (streams.AUTOPILOT_VERSION, 0, 0, 0), 0, 0, 0, None, c.src))

    def _cmd_set_interval(self, c: _Cmd) -> tuple[int, str | None]:
        msg_id = int(c.p[0]) if math.isfinite(c.p[0]) else -1
        if msg_id not in streams.DEFAULT_INTERVALS_S:
            return UNSUPPORTED, None
        why = self.streams.set_interval(msg_id, c.p[1])
        return (ACCEPTED, None) if why is None else (DENIED, f"Interval denied: {why}")

    def _cmd_get_interval(self, c: _Cmd) -> tuple[int, str | None]:
        msg_id = int(c.p[0]) if math.isfinite(c.p[0]) and 0 <= c.p[0] < 2**16 else -1
        if msg_id < 0:
            return DENIED, None
        self._out.append(self.mav.message_interval_encode(msg_id, self.streams.interval_us(msg_id)))
        return ACCEPTED, None

    def _need(self, what: str, land_ok: bool = False) -> tuple[int, str] | None:
        """The refusal of a flight command in this state, or None."""
        if self.state is None or self.home is None:
            return TEMP_REJECTED, f"{what} denied: no position yet"
        if not self.armed:
            return DENIED, f"{what} denied: disarmed"
        if self.landed and not land_ok:
            return DENIED, f"{what} denied: landed, take off first"
        return None

    _COMMANDS = {
        M.MAV_CMD_COMPONENT_ARM_DISARM: _cmd_arm,
        M.MAV_CMD_NAV_TAKEOFF: _cmd_takeoff,
        M.MAV_CMD_NAV_LAND: _cmd_land,
        M.MAV_CMD_NAV_RETURN_TO_LAUNCH: _cmd_rtl,
        M.MAV_CMD_DO_REPOSITION: _cmd_reposition,
        M.MAV_CMD_DO_SET_MODE: _cmd_set_mode,
        M.MAV_CMD_MISSION_START: _cmd_mission_start,
        M.MAV_CMD_DO_CHANGE_SPEED: _cmd_change_speed,
        M.MAV_CMD_REQUEST_MESSAGE: _cmd_request_message,
        M.MAV_CMD_SET_MESSAGE_INTERVAL: _cmd_set_interval,
        M.MAV_CMD_GET_MESSAGE_INTERVAL: _cmd_get_interval,
        M.MAV_CMD_GET_HOME_POSITION: _cmd_home,
        M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: _cmd_capabilities,
    }


def enu_yaw(heading_rad: float) -> float:
    """A heading (rad clockwise from north, MAVLink/NED) → yaw (rad counter-clockwise from east, ENU)."""
    return math.remainder(math.pi / 2 - heading_rad, 2 * math.pi)


def _same(a, b) -> bool:
    """Two commands' arguments equal (NaN equal to NaN)."""
    return all(
        x == y or (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y))
        for x, y in zip(_flat(a), _flat(b), strict=True)
    )


def _flat(args):
    p, x, y, z, frame = args
    return (*p, x, y, z, frame)
