"""The vehicle's parameter table and the MAVLink parameter protocol, as PX4 answers it.

Names, types, defaults, units and ranges are PX4's, from its parameter definition files (cited per
row). A ground station reads them with PARAM_REQUEST_LIST / PARAM_REQUEST_READ and writes them with
PARAM_SET; every answer is a PARAM_VALUE carrying the parameter's value *after* the request, which is
how PX4 answers (src/modules/mavlink/mavlink_parameters.cpp: `param_set(...); send_param(...)`), so a
refused write is seen by the client as an unchanged value. PX4 itself leaves range checks to the
ground station; this table enforces the documented ranges on the vehicle (a value out of range,
non-finite, of the wrong MAVLink type, or not one of an enumeration's values is refused, with a
STATUSTEXT saying why). An unknown name changes nothing and is answered with a STATUSTEXT only
("[pm] unknown param: NAME", as mavlink_parameters.cpp).

Encoding: REAL32 parameters travel as floats; INT32 ones bytewise (the int32's four bytes in the float
field), as PX4 does and announces with MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE; MAVSDK encodes
the same way for any autopilot that is not ArduPilot (mavlink_parameter_client.cpp).

A REAL32 PARAM_SET of an INT32 parameter is taken when its value is a whole number (7.0 sets 7): that
is how MAVProxy sets every parameter once it has read them as a file (`param_pack`), as ArduPilot
takes them; an int32 sent bytewise but typed REAL32 is a tiny denormal float, not a whole number, and
is refused as one.

The table as a file (`param_pack`): what MAVProxy asks for over MAVLink FTP as `@PARAM/param.pck`
before PARAM_REQUEST_LIST. The format is ArduPilot's (libraries/AP_Filesystem/AP_Filesystem_Param.cpp,
decoded by MAVProxy's modules/lib/param_ftp.py); PX4 does not serve it. Little-endian: a header of
magic 0x671b (0x671c with defaults), the number of parameters in the file and in the table; then per
parameter a type byte (low nibble 3 INT32 or 4 REAL32, high nibble flags: 1 = a default follows the
value), a byte with the name's new characters - 1 (high nibble) and the number of leading characters
it shares with the previous name (low nibble), those characters, the value, and the default when the
flag says so (with defaults: for a value that differs from the default).

Deviations from PX4's defaults, each for a reason given on its row: NAV_ACC_RAD and NAV_MC_ALT_RAD
(acceptance radii of 10 m and 0.8 m are for GPS-grade position holds; the policies here hold
centimetres) and NAV_DLL_ACT (PX4 ships the data-link-loss action disabled; a vehicle flown from a
ground station only is safer landing).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

REAL32 = mavlink2.MAV_PARAM_TYPE_REAL32
INT32 = mavlink2.MAV_PARAM_TYPE_INT32
_TYPE_NAMES = {REAL32: "REAL32", INT32: "INT32"}


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: PX4's name, MAVLink type, default, range (inclusive), allowed values for an
    enumeration (None: any value in range), unit, and where the definition comes from."""

    name: str
    kind: int
    default: float
    lo: float = -math.inf
    hi: float = math.inf
    values: tuple[int, ...] | None = None
    unit: str = ""
    source: str = ""

    def check(self, value: float) -> str | None:
        """None if `value` may be set, else why not (a few words: it goes into a STATUSTEXT)."""
        if not math.isfinite(value):
            return f"{value} not a number"
        if self.kind == INT32 and value != int(value):
            return f"{value:g} not an integer"
        if not self.lo <= value <= self.hi:
            return f"{value:g} outside [{self.lo:g}, {self.hi:g}]"
        if self.values is not None and int(value) not in self.values:
            return f"{int(value)} not an allowed value"
        return None


_MPC_AUTO = "src/modules/mc_pos_control/multicopter_autonomous_params.yaml"
_MPC_TKO = "src/modules/mc_pos_control/multicopter_takeoff_land_params.yaml"
_MPC_LIM = "src/modules/mc_pos_control/multicopter_position_control_limits_params.yaml"
_MPC_HOVER = "src/modules/mc_pos_control/multicopter_position_control_params.yaml"
_COM = "src/modules/commander/commander_params.yaml"
_NAV = "src/modules/navigator/navigator_params.yaml"
_RTL = "src/modules/navigator/rtl_params.yaml"
_GF = "src/modules/navigator/geofence_params.yaml"
_LND = "src/modules/land_detector/land_detector_params_mc.yaml"

PARAMS: tuple[ParamSpec, ...] = (
    # take-off (src/modules/navigator/mission_params.c: "This is the minimum altitude the system will take off to")
    ParamSpec("MIS_TAKEOFF_ALT", REAL32, 2.5, 0.0, 80.0, unit="m", source="src/modules/navigator/mission_params.c"),
    ParamSpec("MPC_TKO_SPEED", REAL32, 1.5, 1.0, 5.0, unit="m/s", source=_MPC_TKO),
    # speeds of goto, missions and RTL
    ParamSpec("MPC_XY_CRUISE", REAL32, 5.0, 3.0, 20.0, unit="m/s", source=_MPC_AUTO),
    ParamSpec("MPC_XY_VEL_MAX", REAL32, 12.0, 0.0, 20.0, unit="m/s", source=_MPC_LIM),
    ParamSpec("MPC_Z_V_AUTO_UP", REAL32, 3.0, 0.5, 8.0, unit="m/s", source=_MPC_AUTO),
    ParamSpec("MPC_Z_V_AUTO_DN", REAL32, 1.5, 0.5, 4.0, unit="m/s", source=_MPC_AUTO),
    # landing: descent slows from MPC_Z_V_AUTO_DN above MPC_LAND_ALT1 to MPC_LAND_SPEED below MPC_LAND_ALT2
    ParamSpec(
        "MPC_LAND_SPEED", REAL32, 0.7, 0.6, 4.0, unit="m/s", source=_MPC_TKO + " (no max there; 4 = MPC_Z_V_AUTO_DN's)"
    ),
    ParamSpec("MPC_LAND_ALT1", REAL32, 10.0, 0.0, 122.0, unit="m", source=_MPC_TKO),
    ParamSpec("MPC_LAND_ALT2", REAL32, 5.0, 0.0, 122.0, unit="m", source=_MPC_TKO),
    # thrust levels the land detector compares the commanded collective thrust with
    ParamSpec("MPC_THR_MIN", REAL32, 0.12, 0.05, 0.5, unit="norm", source=_MPC_LIM),
    ParamSpec("MPC_THR_HOVER", REAL32, 0.5, 0.1, 0.8, unit="norm", source=_MPC_HOVER),
    # arrival at a goto, take-off or mission position (a mission item's own radius, param2, wins)
    ParamSpec("NAV_ACC_RAD", REAL32, 0.1, 0.05, 200.0, unit="m", source=_NAV + " (PX4 default 10 m)"),
    ParamSpec("NAV_MC_ALT_RAD", REAL32, 0.1, 0.05, 200.0, unit="m", source=_NAV + " (PX4 default 0.8 m)"),
    # return
    ParamSpec("RTL_RETURN_ALT", REAL32, 60.0, 0.0, 1000.0, unit="m", source=_RTL + " (no max there)"),
    ParamSpec("RTL_DESCEND_ALT", REAL32, 30.0, 0.0, 1000.0, unit="m", source=_RTL + " (no max there)"),
    ParamSpec("RTL_LAND_DELAY", REAL32, 0.0, -1.0, 300.0, unit="s", source=_RTL + " (no max there)"),
    ParamSpec("RTL_MIN_DIST", REAL32, 10.0, 0.5, 1000.0, unit="m", source=_RTL + " (no max there)"),
    ParamSpec("RTL_CONE_ANG", INT32, 45, 0, 90, values=(0, 25, 45, 65, 80, 90), unit="deg", source=_RTL),
    # failsafes: ground-station link loss, then hold for COM_FAIL_ACT_T, then NAV_DLL_ACT
    ParamSpec("COM_DL_LOSS_T", INT32, 10, 5, 300, unit="s", source=_COM),
    ParamSpec("NAV_DLL_ACT", INT32, 3, 0, 6, values=(0, 1, 2, 3), source=_COM + " (PX4 default 0: disabled)"),
    ParamSpec("COM_FAIL_ACT_T", REAL32, 5.0, 0.0, 25.0, unit="s", source=_COM),
    ParamSpec("COM_DISARM_LAND", REAL32, 2.0, -1.0, 20.0, unit="s", source=_COM + " (no range there)"),
    ParamSpec("COM_DISARM_PRFLT", REAL32, 10.0, -1.0, 60.0, unit="s", source=_COM + " (no range there)"),
    # geofence: 0 disables
    ParamSpec("GF_MAX_HOR_DIST", REAL32, 0.0, 0.0, 10000.0, unit="m", source=_GF),
    ParamSpec("GF_MAX_VER_DIST", REAL32, 0.0, 0.0, 10000.0, unit="m", source=_GF),
    # land detector thresholds
    ParamSpec("LNDMC_Z_VEL_MAX", REAL32, 0.25, 0.0, 10.0, unit="m/s", source=_LND + " (no max there)"),
    ParamSpec("LNDMC_XY_VEL_MAX", REAL32, 1.5, 0.0, 10.0, unit="m/s", source=_LND + " (no range there)"),
    ParamSpec("LNDMC_ROT_MAX", REAL32, 20.0, 0.0, 360.0, unit="deg/s", source=_LND + " (no range there)"),
)
"""Every parameter the vehicle has, in PARAM_VALUE index order."""

NAV_DLL_DISABLED, NAV_DLL_HOLD, NAV_DLL_RETURN, NAV_DLL_LAND = 0, 1, 2, 3
"""NAV_DLL_ACT values this vehicle supports (PX4's 5 Terminate and 6 Disarm drop a flying vehicle)."""


def encode(kind: int, value: float) -> float:
    """The float carried in param_value: the value itself (REAL32) or an int32's bytes (INT32)."""
    if kind == INT32:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return float(value)


def decode(kind: int, carried: float) -> float:
    """Inverse of `encode`."""
    if kind == INT32:
        return float(struct.unpack("<i", struct.pack("<f", carried))[0])
    return float(carried)


class ParamTable:
    """The current values, by name; they persist for the life of the object (one run).

    `handle(msg)` answers one PARAM_* message and returns `(replies, statustexts)`: the PARAM_VALUE
    messages to send (built with `mav`) and the lines to report as STATUSTEXT."""

    def __init__(self, mav, overrides: dict[str, float] | None = None) -> None:
        self.mav = mav
        self.specs = {p.name: p for p in PARAMS}
        self.index = {p.name: i for i, p in enumerate(PARAMS)}
        self.values = {p.name: float(p.default) for p in PARAMS}
        for name, value in (overrides or {}).items():
            spec = self.specs.get(name)
            if spec is None:
                raise ValueError(f"unknown parameter {name!r}; expected one of {sorted(self.specs)}")
            why = spec.check(float(value))
            if why is not None:
                raise ValueError(f"{name}: {why}")
            self.values[name] = float(value)
        self.changed: list[str] = []
        """Names set by PARAM_SET since the owner last cleared this list."""

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def value_message(self, name: str):
        spec = self.specs[name]
        return self.mav.param_value_encode(
            name.encode(), encode(spec.kind, self.values[name]), spec.kind, len(PARAMS), self.index[name]
        )

    def handle(self, msg) -> tuple[list, list[str]]:
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            return [self.value_message(p.name) for p in PARAMS], []
        if kind == "PARAM_REQUEST_READ":
            if msg.param_index >= 0:  # by index; -1: by name (MAVLink parameter protocol)
                if msg.param_index >= len(PARAMS):
                    return [], [f"[pm] unknown param ID: {msg.param_index}"]
                return [self.value_message(PARAMS[msg.param_index].name)], []
            name = _name(msg.param_id)
            if name not in self.specs:
                return [], [f"[pm] unknown param: {name}"]
            return [self.value_message(name)], []
        if kind == "PARAM_SET":
            return self._set(msg)
        raise ValueError(f"not a parameter message: {kind}")

    def _set(self, msg) -> tuple[list, list[str]]:
        name = _name(msg.param_id)
        spec = self.specs.get(name)
        if spec is None:
            return [], [f"[pm] unknown param: {name}"]
        as_float = spec.kind == INT32 and msg.param_type == REAL32  # MAVProxy after reading the file
        if msg.param_type != spec.kind and not as_float:
            why = f"type {_TYPE_NAMES.get(msg.param_type, msg.param_type)}, expected {_TYPE_NAMES[spec.kind]}"
        else:
            value = float(msg.param_value) if as_float else decode(spec.kind, msg.param_value)
            why = spec.check(value)
            if why is None:
                self.values[name] = value
                self.changed.append(name)
        # answered with the value as it now is, set or refused (PX4's send_param after param_set)
        return [self.value_message(name)], ([] if why is None else [f"{name} refused: {why}"])


def _name(raw) -> str:
    """A param_id field (up to 16 characters, NUL-padded unless 16 long) as text."""
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return raw.split("\x00", 1)[0]


PACK_MAGIC, PACK_MAGIC_DEFAULTS = 0x671B, 0x671C
_PACK_TYPES = {INT32: (3, "<i"), REAL32: (4, "<f")}


def param_pack(table: ParamTable, with_defaults: bool = False) -> bytes:
    """The parameters as ArduPilot's packed parameter file (see the module docstring), in index order."""
    out = bytearray(struct.pack("<HHH", PACK_MAGIC_DEFAULTS if with_defaults else PACK_MAGIC, len(PARAMS), len(PARAMS)))
    last = b""
    for p in PARAMS:
        name = p.name.encode()
        common = 0
        while common < min(len(name) - 1, len(last), 15) and name[common] == last[common]:
            common += 1
        kind, fmt = _PACK_TYPES[p.kind]
        value = table.values[p.name]
        has_default = with_defaults and value != p.default
        out += bytes([kind | (0x10 if has_default else 0), (len(name) - common - 1) << 4 | common])
        out += name[common:]
        out += struct.pack(fmt, int(value) if p.kind == INT32 else value)
        if has_default:
            out += struct.pack(fmt, int(p.default) if p.kind == INT32 else p.default)
        last = name
    return bytes(out)
