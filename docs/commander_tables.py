"""The tables of docs/ground_station.md, printed from the vehicle's own data: the commands it answers
(autopilot.commands.COMMANDS), the flight modes it takes (autopilot.modes.MODE_NAMES)
and its parameters (autopilot.param_protocol.PARAMS).

    .venv/bin/python docs/commander_tables.py commands
    .venv/bin/python docs/commander_tables.py modes
    .venv/bin/python docs/commander_tables.py params

Names, numbers, defaults, ranges and units come from the code; the one-line descriptions below are
this page's words, keyed by name, and the script exits 1 when the code has a command or parameter
without one (or this file describes one the code no longer has), so the page cannot fall behind.
"""

from __future__ import annotations

import math
import re
import sys

from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.autopilot import commands, modes
from quadpilot.autopilot import param_protocol as params

COMMANDS = {
    "MAV_CMD_COMPONENT_ARM_DISARM": "param1 1 arms (on the ground, with a position), 0 disarms (landed only, "
    "unless param2 = 21196: forced)",
    "MAV_CMD_NAV_TAKEOFF": "climbs above the current position to param7 (AMSL) or, if NaN, MIS_TAKEOFF_ALT above "
    "the ground, then Hold; armed only",
    "MAV_CMD_NAV_LAND": "descends and lands where it is; disarms on touchdown after COM_DISARM_LAND",
    "MAV_CMD_NAV_RETURN_TO_LAUNCH": "climbs to the return altitude, flies home, lands (RTL_* parameters); "
    "in flight only",
    "MAV_CMD_DO_REPOSITION": "goto: COMMAND_INT only, frame 0/5 (AMSL) or 3/6 (above home); param1 speed, "
    "param4 yaw; switches to Hold and flies there",
    "MAV_CMD_DO_SET_MODE": "PX4 custom mode (table below); base_mode must carry CUSTOM_MODE_ENABLED; "
    "SET_MODE is answered the same way",
    "MAV_CMD_MISSION_START": "flies the uploaded mission from item param1",
    "MAV_CMD_DO_CHANGE_SPEED": "param1 0/1 horizontal, 2 climb, 3 descent; param2 m/s (−1 keeps, −2 restores the "
    "parameter's value)",
    "MAV_CMD_REQUEST_MESSAGE": "sends the message param1 once (HOME_POSITION, AUTOPILOT_VERSION, ...), then the ACK",
    "MAV_CMD_SET_MESSAGE_INTERVAL": "sets the rate of a streamed message (param1 id, param2 µs; −1 stops it)",
    "MAV_CMD_GET_MESSAGE_INTERVAL": "answers MESSAGE_INTERVAL for message param1",
    "MAV_CMD_GET_HOME_POSITION": "sends HOME_POSITION",
    "MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES": "sends AUTOPILOT_VERSION",
}

PARAMS = {
    "MIS_TAKEOFF_ALT": "take-off height above the ground when NAV_TAKEOFF gives none (MAVSDK's set_takeoff_altitude)",
    "MPC_TKO_SPEED": "climb speed of a take-off",
    "MPC_XY_CRUISE": "horizontal speed of goto, missions and RTL",
    "MPC_XY_VEL_MAX": "upper bound of any horizontal speed asked for (DO_REPOSITION param1, DO_CHANGE_SPEED)",
    "MPC_Z_V_AUTO_UP": "climb speed in automatic modes",
    "MPC_Z_V_AUTO_DN": "descent speed in automatic modes",
    "MPC_LAND_SPEED": "descent speed of the last part of a landing",
    "MPC_LAND_ALT1": "height below which a landing starts slowing down",
    "MPC_LAND_ALT2": "height below which a landing descends at MPC_LAND_SPEED",
    "MPC_THR_MIN": "collective thrust the land detector counts as idle",
    "MPC_THR_HOVER": "collective thrust the land detector compares with (hover)",
    "NAV_ACC_RAD": "horizontal acceptance radius of a goto, take-off or mission position",
    "NAV_MC_ALT_RAD": "vertical acceptance radius",
    "RTL_RETURN_ALT": "height RTL climbs to before flying home",
    "RTL_DESCEND_ALT": "height RTL descends to above home before landing",
    "RTL_LAND_DELAY": "wait above home before landing (−1: hover there)",
    "RTL_MIN_DIST": "closer to home than this, RTL does not climb to RTL_RETURN_ALT",
    "RTL_CONE_ANG": "half-angle of the cone above home that lowers the return altitude",
    "COM_DL_LOSS_T": "ground-station silence that counts as link loss",
    "NAV_DLL_ACT": "action on link loss: 0 none, 1 hold, 2 return, 3 land",
    "COM_FAIL_ACT_T": "hold this long after a failsafe before its action",
    "COM_DISARM_LAND": "disarm this long after landing (−1: never)",
    "COM_DISARM_PRFLT": "disarm an armed vehicle that has not taken off after this long (−1: never)",
    "GF_MAX_HOR_DIST": "geofence radius from home; goals beyond it are refused (0: off)",
    "GF_MAX_VER_DIST": "geofence height above home (0: off)",
    "LNDMC_Z_VEL_MAX": "land detector: vertical speed below which the vehicle may be landed",
    "LNDMC_XY_VEL_MAX": "land detector: horizontal speed below which the vehicle may be landed",
    "LNDMC_ROT_MAX": "land detector: rotation rate below which the vehicle may be landed",
}

MODES = {
    "Hold": "AUTO_LOITER: hold the position; goto (DO_REPOSITION) flies in this mode",
    "Takeoff": "AUTO_TAKEOFF: as NAV_TAKEOFF with MIS_TAKEOFF_ALT",
    "Mission": "AUTO_MISSION: fly the uploaded mission (MAVSDK's start_mission)",
    "Return": "AUTO_RTL: as NAV_RETURN_TO_LAUNCH",
    "Land": "AUTO_LAND: as NAV_LAND",
    "Position": "POSCTL: hold where the reference is (no stick input is read)",
}

_PX4_DEFAULT = re.compile(r"\(PX4 default ([^)]*?)(?::[^)]*)?\)")


def _num(v: float) -> str:
    if math.isinf(v):
        return "−∞" if v < 0 else "∞"
    return f"{v:g}".replace("-", "−")


def _check(described: dict, names: list[str], what: str) -> None:
    missing = [n for n in names if n not in described]
    stale = [n for n in described if n not in names]
    if missing or stale:
        print(
            f"docs/commander_tables.py: {what} without a description {missing}, described but gone {stale}",
            file=sys.stderr,
        )
        raise SystemExit(1)


def command_table() -> None:
    ids = list(commands.COMMANDS)
    names = [mavlink2.enums["MAV_CMD"][i].name for i in ids]
    _check(COMMANDS, names, "commands")
    print("| command | id | what the vehicle does |")
    print("|---|---|---|")
    for i, name in zip(ids, names, strict=True):
        print(f"| `{name.removeprefix('MAV_CMD_')}` | {i} | {COMMANDS[name]} |")


def mode_table() -> None:
    names = list(modes.MODE_NAMES.values())
    _check(MODES, names, "modes")
    print("| mode (MAVSDK FlightMode) | PX4 main / sub mode | what it does |")
    print("|---|---|---|")
    for (main, sub), name in modes.MODE_NAMES.items():
        print(f"| {name} | {main} / {sub} | {MODES[name]} |")


def param_table() -> None:
    names = [p.name for p in params.PARAMS]
    _check(PARAMS, names, "parameters")
    print("| parameter | type | default here | PX4 default | range | unit | what it sets |")
    print("|---|---|---|---|---|---|---|")
    for p in params.PARAMS:
        kind = "INT32" if p.kind == params.INT32 else "REAL32"
        m = _PX4_DEFAULT.search(p.source)
        px4 = m.group(1).removesuffix(p.unit).strip() if m else _num(p.default)
        allowed = f"{{{', '.join(str(v) for v in p.values)}}}" if p.values is not None else ""
        rng = f"[{_num(p.lo)}, {_num(p.hi)}]" + (f" of {allowed}" if allowed else "")
        print(f"| `{p.name}` | {kind} | {_num(p.default)} | {px4} | {rng} | {p.unit} | {PARAMS[p.name]} |")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    tables = {"commands": command_table, "modes": mode_table, "params": param_table}
    if len(argv) != 1 or argv[0] not in tables:
        print(f"usage: commander_tables.py {{{','.join(tables)}}}", file=sys.stderr)
        return 2
    tables[argv[0]]()
    return 0


if __name__ == "__main__":
    sys.exit(main())
