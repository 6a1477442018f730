"""The commands a ground station sends (COMMAND_LONG, COMMAND_INT, SET_MODE) and their answers.

One function per command, in one table (`COMMANDS`: MAV_CMD → a function of the commander `cmdr`,
a `commander.Commander`, which imports this module, and the command; it returns the result and
why). `on_command` and `on_set_mode` are the commander's handlers of the three messages. A command
acts through the commander's own operations (arm, disarm, `fly` a navigator mode, start the
mission) and reads its state; it keeps none of its own.

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

from . import mission_protocol, streams
from .modes import LAND, MISSION, MODE_NAMES, RTL, TAKEOFF, Land, Loiter, Return, Takeoff
from .navigator import outside_fence

M = mavlink2
ACCEPTED, TEMP_REJECTED, DENIED = M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_TEMPORARILY_REJECTED, M.MAV_RESULT_DENIED
UNSUPPORTED, FAILED = M.MAV_RESULT_UNSUPPORTED, M.MAV_RESULT_FAILED
FORCE_DISARM = 21196  # COMPONENT_ARM_DISARM param2 that disarms in flight (MAVLink common.xml)
INT32_MAX = 2**31 - 1  # COMMAND_INT x/y "unchanged"


@dataclass
class _Cmd:
    command: int
    p: tuple  # param1..param4
    x: float  # param5 (COMMAND_LONG) or x (COMMAND_INT)
    y: float
    z: float
    frame: int | None  # None: COMMAND_LONG
    src: tuple


Result = tuple[int, "str | None"]


def on_set_mode(cmdr, msg) -> None:
    """SET_MODE (deprecated): as DO_SET_MODE, acknowledged as that command (as PX4 does)."""
    main, sub = (msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF
    src = (msg.get_srcSystem(), msg.get_srcComponent())
    _execute(cmdr, _Cmd(M.MAV_CMD_DO_SET_MODE, (msg.base_mode, main, sub, 0.0), 0, 0, 0, None, src), repeat=False)


def on_command(cmdr, msg) -> None:
    """COMMAND_LONG or COMMAND_INT."""
    is_int = msg.get_type() == "COMMAND_INT"
    src = (msg.get_srcSystem(), msg.get_srcComponent())
    p = (msg.param1, msg.param2, msg.param3, msg.param4)
    if is_int:
        cmd = _Cmd(msg.command, p, msg.x, msg.y, msg.z, msg.frame, src)
    else:
        cmd = _Cmd(msg.command, p, msg.param5, msg.param6, msg.param7, None, src)
    _execute(cmdr, cmd, repeat=not is_int and msg.confirmation > 0)


def _execute(cmdr, c: _Cmd, repeat: bool) -> None:
    key = (c.src, c.command, c.frame is not None)
    args = (c.p, c.x, c.y, c.z, c.frame)
    prior = cmdr.recent_commands.get(key)
    if repeat and prior is not None and _same(prior[0], args) and cmdr.now - prior[2] <= cmdr.cfg.repeat_window_s:
        result = prior[1]  # a resend: answered as before, not done twice
    else:
        run = COMMANDS.get(c.command)
        if run is None:
            result, why = UNSUPPORTED, None
        else:
            try:
                result, why = run(cmdr, c)
            except Exception as e:  # never silence, never a dead loop: the ACK says it failed
                cmdr.dropped["command_error"] += 1
                result, why = FAILED, f"command {c.command} failed: {type(e).__name__}"
        if why:
            cmdr.text(why, M.MAV_SEVERITY_WARNING if result != ACCEPTED else M.MAV_SEVERITY_INFO)
        cmdr.recent_commands[key] = (args, result, cmdr.now)
    cmdr.send(cmdr.mav.command_ack_encode(c.command, result, 0, 0, c.src[0], c.src[1]))


# --- commands ----------------------------------------------------------------------------------------
def arm_disarm(cmdr, c: _Cmd) -> Result:
    if c.p[0] == 1.0:
        if cmdr.armed:
            return (ACCEPTED, None) if cmdr.landed else (DENIED, "Arming denied: already flying")
        why = cmdr.armable()
        if why is not None:
            return (TEMP_REJECTED if cmdr.state is None else DENIED), f"Arming denied: {why}"
        cmdr.arm()
        return ACCEPTED, "Armed by external command"
    if c.p[0] != 0.0:
        return DENIED, f"arm/disarm: param1 {c.p[0]}, expected 0 or 1"
    if not cmdr.armed:
        return ACCEPTED, None
    if not cmdr.landed and c.p[1] != FORCE_DISARM:
        return DENIED, "Disarming denied: not landed"
    cmdr.disarm()
    return ACCEPTED, "Disarmed by external command"


def takeoff(cmdr, c: _Cmd) -> Result:
    if (why := _need(cmdr, "Takeoff", land_ok=True)) is not None:
        return why
    s = cmdr.state
    if math.isfinite(c.z):
        alt = c.z if c.frame in mission_protocol.RELATIVE_FRAMES else c.z - cmdr.home.alt_m
    elif cmdr.mode == TAKEOFF and cmdr.nav.taking_off:
        return ACCEPTED, None  # the same take-off again
    else:
        alt = float(s[Z]) + cmdr.params["MIS_TAKEOFF_ALT"]
    if alt <= s[Z]:
        return DENIED, "Takeoff denied: already higher than that"  # ≤ 50 chars: STATUSTEXT
    goal = np.array([cmdr.mover.ref[0], cmdr.mover.ref[1], alt])
    if (fence := outside_fence(goal, cmdr.params)) is not None:
        return DENIED, f"Takeoff denied: {fence}"
    cmdr.fly(Takeoff(alt))
    return ACCEPTED, f"Takeoff to {alt:.1f} m"


def land(cmdr, c: _Cmd) -> Result:
    if (why := _need(cmdr, "Land", land_ok=True)) is not None:
        return why
    if cmdr.mode == LAND:
        return ACCEPTED, None
    cmdr.fly(Land(cmdr.state[POS_XY]))
    return ACCEPTED, None


def return_to_launch(cmdr, c: _Cmd) -> Result:
    if (why := _need(cmdr, "Return")) is not None:
        return why
    if cmdr.mode == RTL:
        return ACCEPTED, None
    cmdr.fly(Return())
    return ACCEPTED, None


def reposition(cmdr, c: _Cmd) -> Result:
    if c.frame is None:
        return M.MAV_RESULT_COMMAND_INT_ONLY, "DO_REPOSITION: send it as COMMAND_INT"
    if (why := _need(cmdr, "Goto")) is not None:
        return why
    if c.frame not in mission_protocol.GLOBAL_FRAMES:
        return DENIED, f"Goto denied: frame {c.frame}, expected 0, 3, 5 or 6"
    leg = cmdr.nav.leg
    goal = leg.goal.copy() if leg is not None and leg.goal is not None else cmdr.mover.goal.copy()
    if c.x != INT32_MAX and c.y != INT32_MAX:
        if not (-900_000_000 <= c.x <= 900_000_000 and -1_800_000_000 <= c.y <= 1_800_000_000):
            return DENIED, f"Goto denied: lat/lon {c.x}/{c.y} degE7 off the globe"
        goal[0:2] = geodetic_to_local(c.x, c.y, 0, cmdr.home)[0:2]
    if math.isfinite(c.z):
        goal[2] = c.z if c.frame in mission_protocol.RELATIVE_FRAMES else c.z - cmdr.home.alt_m
    if (fence := outside_fence(goal, cmdr.params)) is not None:
        return DENIED, f"Goto denied: {fence}"
    # the speed set by DO_CHANGE_SPEED carries over (navigator_main.cpp: param1 < 0 → the current cruising speed)
    cmdr.fly(Loiter(goal))
    if math.isfinite(c.p[0]) and c.p[0] > 0:
        cmdr.nav.cruise = min(float(c.p[0]), cmdr.params["MPC_XY_VEL_MAX"])
    if math.isfinite(c.p[3]):
        cmdr.yaw = enu_yaw(c.p[3])
    return ACCEPTED, None


def set_mode(cmdr, c: _Cmd) -> Result:
    base, main, sub = c.p[0], c.p[1], c.p[2]
    if not all(math.isfinite(v) for v in (base, main, sub)) or not int(base) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return DENIED, "Mode denied: expected a PX4 custom mode"
    mode = (int(main), int(sub)) if int(main) == 4 else (int(main), 0)
    if mode not in MODE_NAMES:
        return DENIED, f"Mode {int(main)}/{int(sub)} not supported"
    if mode == cmdr.mode:
        return ACCEPTED, None
    if mode == TAKEOFF:
        return takeoff(cmdr, _Cmd(M.MAV_CMD_NAV_TAKEOFF, (math.nan,) * 4, 0, 0, math.nan, None, c.src))
    if mode == LAND:
        return land(cmdr, c)
    if mode == RTL:
        return return_to_launch(cmdr, c)
    if mode == MISSION:
        return cmdr.start_mission(None)
    cmdr.hold(mode)  # Hold or Position: stop and hold where the reference is
    return ACCEPTED, None


def mission_start(cmdr, c: _Cmd) -> Result:
    first = c.p[0]
    if not math.isfinite(first) or not 0 <= first < max(1, len(cmdr.mission.items)):
        return DENIED, f"Mission start denied: first item {first}"
    return cmdr.start_mission(int(first))


def change_speed(cmdr, c: _Cmd) -> Result:
    kind, speed = c.p[0], c.p[1]
    if kind not in (0, 1, 2, 3) or not (speed in (-1.0, -2.0) or (math.isfinite(speed) and speed > 0)):
        return DENIED, f"Speed change denied: type {kind}, speed {speed}"
    cmdr.nav.apply_speed(kind, speed)
    cmdr.nav.reaim()
    return ACCEPTED, None


def request_message(cmdr, c: _Cmd) -> Result:
    msg_id = int(c.p[0]) if math.isfinite(c.p[0]) else -1
    if msg_id not in streams.REQUESTABLE:
        return UNSUPPORTED, None
    msg = cmdr.message(msg_id)
    if msg is None:
        return TEMP_REJECTED, None
    cmdr.send(msg)  # the message, then its ACK
    return ACCEPTED, None


def get_home_position(cmdr, c: _Cmd) -> Result:
    return request_message(cmdr, _Cmd(c.command, (streams.HOME_POSITION, 0, 0, 0), 0, 0, 0, None, c.src))


def autopilot_capabilities(cmdr, c: _Cmd) -> Result:
    return request_message(cmdr, _Cmd(c.command, (streams.AUTOPILOT_VERSION, 0, 0, 0), 0, 0, 0, None, c.src))


def set_message_interval(cmdr, c: _Cmd) -> Result:
    msg_id = int(c.p[0]) if math.isfinite(c.p[0]) else -1
    if msg_id not in streams.DEFAULT_INTERVALS_S:
        return UNSUPPORTED, None
    why = cmdr.streams.set_interval(msg_id, c.p[1])
    return (ACCEPTED, None) if why is None else (DENIED, f"Interval denied: {why}")


def get_message_interval(cmdr, c: _Cmd) -> Result:
    msg_id = int(c.p[0]) if math.isfinite(c.p[0]) and 0 <= c.p[0] < 2**16 else -1
    if msg_id < 0:
        return DENIED, None
    cmdr.send(cmdr.mav.message_interval_encode(msg_id, cmdr.streams.interval_us(msg_id)))
    return ACCEPTED, None


def _need(cmdr, what: str, land_ok: bool = False) -> Result | None:
    """The refusal of a flight command in this state, or None."""
    if cmdr.state is None or cmdr.home is None:
        return TEMP_REJECTED, f"{what} denied: no position yet"
    if not cmdr.armed:
        return DENIED, f"{what} denied: disarmed"
    if cmdr.landed and not land_ok:
        return DENIED, f"{what} denied: landed, take off first"
    return None


COMMANDS = {
    M.MAV_CMD_COMPONENT_ARM_DISARM: arm_disarm,
    M.MAV_CMD_NAV_TAKEOFF: takeoff,
    M.MAV_CMD_NAV_LAND: land,
    M.MAV_CMD_NAV_RETURN_TO_LAUNCH: return_to_launch,
    M.MAV_CMD_DO_REPOSITION: reposition,
    M.MAV_CMD_DO_SET_MODE: set_mode,
    M.MAV_CMD_MISSION_START: mission_start,
    M.MAV_CMD_DO_CHANGE_SPEED: change_speed,
    M.MAV_CMD_REQUEST_MESSAGE: request_message,
    M.MAV_CMD_SET_MESSAGE_INTERVAL: set_message_interval,
    M.MAV_CMD_GET_MESSAGE_INTERVAL: get_message_interval,
    M.MAV_CMD_GET_HOME_POSITION: get_home_position,
    M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: autopilot_capabilities,
}
"""MAV_CMD → the function that carries it out; a command not here is answered UNSUPPORTED."""


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
