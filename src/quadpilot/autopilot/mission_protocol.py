"""The MAVLink mission protocol on the vehicle side: upload, download, clear.

As https://mavlink.io/en/services/mission.html defines it and PX4 answers it
(src/modules/mavlink/mavlink_mission.cpp):
- upload: MISSION_COUNT → the vehicle requests each item with MISSION_REQUEST_INT → MISSION_ITEM_INT
  → … → MISSION_ACK(ACCEPTED) after the last. A request unanswered for `retry_s` is sent again
  (PX4: MAVLINK_MISSION_RETRY_TIMEOUT_DEFAULT, 250 ms); nothing from the partner for `timeout_s`
  (MAVLINK_MISSION_PROTOCOL_TIMEOUT_DEFAULT, 5 s) ends the transfer with MISSION_ACK
  (OPERATION_CANCELLED) and a STATUSTEXT. A repeat of the item just stored (the ground station did not
  hear the next request) is answered with that request again; any other out-of-order item ends the
  transfer with INVALID_SEQUENCE. A bad item ends it with the error naming what was wrong
  (UNSUPPORTED command, UNSUPPORTED_FRAME, INVALID_PARAMn). The stored mission changes only when an
  upload completes; count 0 clears it.
- download: MISSION_REQUEST_LIST → MISSION_COUNT; each MISSION_REQUEST_INT → that MISSION_ITEM_INT,
  a sequence number beyond the mission → MISSION_ACK(INVALID_SEQUENCE).
- clear: MISSION_CLEAR_ALL → MISSION_ACK(ACCEPTED).
Fence and rally lists are empty and cannot be uploaded (MISSION_ACK UNSUPPORTED, with that
mission_type). MISSION_ITEM (the float form, deprecated) is answered UNSUPPORTED.

Items: NAV_WAYPOINT, NAV_TAKEOFF, NAV_LAND (positions, frames 0 GLOBAL and 5 GLOBAL_INT with altitude
above mean sea level, 3 GLOBAL_RELATIVE_ALT, which MAVSDK 4.1.0 sends, and 6 GLOBAL_RELATIVE_ALT_INT,
which newer MAVSDK sends, with altitude above home), NAV_RETURN_TO_LAUNCH, NAV_DELAY and
DO_CHANGE_SPEED (MAVSDK adds the last two for a mission item's loiter time and speed), and the
camera and gimbal items of `PAYLOAD_COMMANDS`, which this vehicle has neither of: stored, flown as
done at once, moving nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.link.frames import Home, geodetic_to_local

NAV_WAYPOINT = mavlink2.MAV_CMD_NAV_WAYPOINT
NAV_TAKEOFF = mavlink2.MAV_CMD_NAV_TAKEOFF
NAV_LAND = mavlink2.MAV_CMD_NAV_LAND
NAV_RETURN_TO_LAUNCH = mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH
NAV_DELAY = mavlink2.MAV_CMD_NAV_DELAY
DO_CHANGE_SPEED = mavlink2.MAV_CMD_DO_CHANGE_SPEED
POSITION_COMMANDS = frozenset({NAV_WAYPOINT, NAV_TAKEOFF, NAV_LAND})
PAYLOAD_COMMANDS = frozenset(
    {
        mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
        mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
        mavlink2.MAV_CMD_DO_MOUNT_CONFIGURE,
        mavlink2.MAV_CMD_DO_MOUNT_CONTROL,
        mavlink2.MAV_CMD_IMAGE_START_CAPTURE,
        mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE,
        mavlink2.MAV_CMD_VIDEO_START_CAPTURE,
        mavlink2.MAV_CMD_VIDEO_STOP_CAPTURE,
        mavlink2.MAV_CMD_DO_CONTROL_VIDEO,
        mavlink2.MAV_CMD_DO_TRIGGER_CONTROL,
        mavlink2.MAV_CMD_DO_DIGICAM_CONTROL,
        mavlink2.MAV_CMD_DO_SET_CAM_TRIGG_DIST,
        mavlink2.MAV_CMD_DO_SET_CAM_TRIGG_INTERVAL,
        mavlink2.MAV_CMD_SET_CAMERA_MODE,
        mavlink2.MAV_CMD_SET_CAMERA_ZOOM,
        mavlink2.MAV_CMD_SET_CAMERA_FOCUS,
    }
)
"""Gimbal, mount and camera items: no motion, and nothing on this vehicle to act on them. PX4 accepts
each in an upload (src/modules/mavlink/mavlink_mission.cpp, parse_mavlink_mission_item: copied as
they are) and counts it reached as soon as it is current (src/modules/navigator/mission_block.cpp,
MissionBlock::is_mission_item_reached_or_completed: "return true" for these commands), whereupon
MissionBase::on_active (mission_base.cpp) reports it reached and moves on to the next item; the
command it issues finds no gimbal or camera on a vehicle without one. So here: stored, reported
current and reached in their order, and not flown. MAVSDK's Mission plugin uploads them for a
MissionItem's gimbal angles and camera action (cpp/src/mavsdk/plugins/mission/mission_impl.cpp,
convert_to_int_items). Items that would move or turn the vehicle (DO_SET_ROI*, DO_JUMP, loiters,
DO_VTOL_TRANSITION...) stay refused."""
SUPPORTED_COMMANDS = POSITION_COMMANDS | PAYLOAD_COMMANDS | {NAV_RETURN_TO_LAUNCH, NAV_DELAY, DO_CHANGE_SPEED}
AMSL_FRAMES = frozenset({mavlink2.MAV_FRAME_GLOBAL, mavlink2.MAV_FRAME_GLOBAL_INT})
RELATIVE_FRAMES = frozenset({mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})
GLOBAL_FRAMES = AMSL_FRAMES | RELATIVE_FRAMES
MAX_ITEMS = 500
"""Items one mission may hold (MISSION_COUNT beyond it: NO_SPACE)."""

MISSION = mavlink2.MAV_MISSION_TYPE_MISSION


@dataclass(frozen=True)
class MissionItem:
    """One stored MISSION_ITEM_INT, as received (x, y degE7 for global frames; z m)."""

    seq: int
    frame: int
    command: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float

    @classmethod
    def from_message(cls, msg) -> MissionItem:
        return cls(
            msg.seq,
            msg.frame,
            msg.command,
            msg.autocontinue,
            msg.param1,
            msg.param2,
            msg.param3,
            msg.param4,
            msg.x,
            msg.y,
            msg.z,
        )

    def has_position(self) -> bool:
        """A NAV_LAND with x = y = 0 lands where the vehicle is (MISSION_ITEM_INT cannot carry NaN)."""
        return self.command in POSITION_COMMANDS and not (self.command == NAV_LAND and self.x == 0 and self.y == 0)

    def local(self, home: Home) -> np.ndarray:
        """Position (3,) ENU in metres from home; z above home."""
        if self.frame in RELATIVE_FRAMES:
            p = geodetic_to_local(self.x, self.y, round(home.alt_m * 1000.0), home)
            p[2] = float(self.z)
            return p
        p = geodetic_to_local(self.x, self.y, 0, home)
        p[2] = float(self.z) - home.alt_m
        return p


def check_item(msg) -> tuple[int, str] | None:
    """None if the MISSION_ITEM_INT can be flown, else (MAV_MISSION_RESULT, why)."""
    cmd, frame = msg.command, msg.frame
    if cmd not in SUPPORTED_COMMANDS:
        return mavlink2.MAV_MISSION_UNSUPPORTED, f"item {msg.seq}: command {cmd} not supported"
    if cmd in POSITION_COMMANDS:
        if frame not in GLOBAL_FRAMES:
            return mavlink2.MAV_MISSION_UNSUPPORTED_FRAME, f"item {msg.seq}: frame {frame}, expected 0, 3, 5 or 6"
        if not -900_000_000 <= msg.x <= 900_000_000:
            return mavlink2.MAV_MISSION_INVALID_PARAM5_X, f"item {msg.seq}: latitude {msg.x} degE7 off the globe"
        if not -1_800_000_000 <= msg.y <= 1_800_000_000:
            return mavlink2.MAV_MISSION_INVALID_PARAM6_Y, f"item {msg.seq}: longitude {msg.y} degE7 off the globe"
        if not math.isfinite(msg.z) and not cmd == NAV_LAND:
            return mavlink2.MAV_MISSION_INVALID_PARAM7, f"item {msg.seq}: altitude {msg.z}"
    elif frame not in GLOBAL_FRAMES | {mavlink2.MAV_FRAME_MISSION}:
        return mavlink2.MAV_MISSION_UNSUPPORTED_FRAME, f"item {msg.seq}: frame {frame}, expected 2 (MISSION)"
    if cmd == NAV_WAYPOINT and msg.param1 < 0:  # hold time, s (NaN: none)
        return mavlink2.MAV_MISSION_INVALID_PARAM1, f"item {msg.seq}: hold time {msg.param1} s"
    if cmd == NAV_DELAY and not (math.isfinite(msg.param1) and msg.param1 >= 0):
        # -1 selects the time-of-day fields (hour, minute, second), which this vehicle has no clock for
        return mavlink2.MAV_MISSION_INVALID_PARAM1, f"item {msg.seq}: delay {msg.param1} s"
    if cmd == DO_CHANGE_SPEED:
        if msg.param1 not in (0, 1, 2, 3):
            return mavlink2.MAV_MISSION_INVALID_PARAM1, f"item {msg.seq}: speed type {msg.param1}"
        if not (msg.param2 in (-1.0, -2.0) or (math.isfinite(msg.param2) and msg.param2 > 0)):
            return mavlink2.MAV_MISSION_INVALID_PARAM2, f"item {msg.seq}: speed {msg.param2} m/s"
    return None


class MissionTransfer:
    """The stored mission and the transfers that read and write it.

    `handle(msg, now)` and `tick(now)` return `(replies, texts)`: messages to send (built with
    `mav`) and STATUSTEXT lines. `version` counts completed uploads and clears, so the owner can
    tell that the mission changed; `locked` (set by the owner while a mission is being flown)
    refuses uploads and clears with MISSION_ACK(DENIED)."""

    def __init__(self, mav, retry_s: float = 0.25, timeout_s: float = 5.0) -> None:
        self.mav = mav
        self.retry_s, self.timeout_s = retry_s, timeout_s
        self.items: list[MissionItem] = []
        self.version = 0
        self.locked = False
        self.ignored = 0
        """Mission items received outside an upload, not answered."""
        self._pending: list[MissionItem] | None = None  # an upload in progress
        self._count = 0
        self._partner = (0, 0)
        self._last_recv = self._last_sent = 0.0
        self._last_done: tuple[tuple[int, int], int] | None = None  # (partner, last seq) of the last upload

    @property
    def uploading(self) -> bool:
        return self._pending is not None

    def _ack(self, to, result: int, mission_type: int = MISSION):
        return self.mav.mission_ack_encode(to[0], to[1], result, mission_type)

    def _request(self, now: float):
        self._last_sent = now
        return self.mav.mission_request_int_encode(*self._partner, len(self._pending), MISSION)

    def _abort(self) -> None:
        self._pending = None

    def handle(self, msg, now: float) -> tuple[list, list[str]]:
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        kind = msg.get_type()
        mission_type = getattr(msg, "mission_type", MISSION)
        if kind == "MISSION_COUNT":
            return self._on_count(msg, src, mission_type, now)
        if kind == "MISSION_ITEM_INT":
            return self._on_item(msg, src, now)
        if kind == "MISSION_ITEM":
            if self.uploading and src == self._partner:
                self._abort()
            return [self._ack(src, mavlink2.MAV_MISSION_UNSUPPORTED, mission_type)], [
                "mission: MISSION_ITEM not supported, use MISSION_ITEM_INT"
            ]
        if kind == "MISSION_REQUEST_LIST":
            count = len(self.items) if mission_type == MISSION else 0
            return [self.mav.mission_count_encode(src[0], src[1], count, mission_type)], []
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            # MISSION_REQUEST is the deprecated float form's request; it is answered in the int form
            if mission_type != MISSION or not 0 <= msg.seq < len(self.items):
                return [self._ack(src, mavlink2.MAV_MISSION_INVALID_SEQUENCE, mission_type)], []
            return [self.item_message(self.items[msg.seq], src)], []
        if kind == "MISSION_ACK":
            # the end of a download needs nothing; an ACK during an upload from its partner cancels it
            if self.uploading and src == self._partner:
                self._abort()
            return [], []
        if kind == "MISSION_CLEAR_ALL":
            if mission_type in (MISSION, mavlink2.MAV_MISSION_TYPE_ALL):
                if self.locked:
                    return [self._ack(src, mavlink2.MAV_MISSION_DENIED, mission_type)], [
                        "mission: clear denied while the mission is flown"
                    ]
                if self.items:
                    self.items = []
                    self.version += 1
            return [self._ack(src, mavlink2.MAV_MISSION_ACCEPTED, mission_type)], []
        raise ValueError(f"not a mission message: {kind}")

    def _on_count(self, msg, src, mission_type: int, now: float) -> tuple[list, list[str]]:
        if mission_type != MISSION:
            result = mavlink2.MAV_MISSION_ACCEPTED if msg.count == 0 else mavlink2.MAV_MISSION_UNSUPPORTED
            return [self._ack(src, result, mission_type)], []
        if self.locked:
            return [self._ack(src, mavlink2.MAV_MISSION_DENIED)], ["mission: upload denied while the mission is flown"]
        if self.uploading and src != self._partner:
            return [self._ack(src, mavlink2.MAV_MISSION_DENIED)], ["mission: another upload is in progress"]
        if msg.count > MAX_ITEMS:
            return [self._ack(src, mavlink2.MAV_MISSION_NO_SPACE)], [f"mission: {msg.count} items, at most {MAX_ITEMS}"]
        if self.uploading and msg.count == self._count and not self._pending:
            self._last_recv = now  # the count again before the first item: ask for item 0 again
            return [self._request(now)], []
        if msg.count == 0:
            self._abort()
            if self.items:
                self.items = []
                self.version += 1
            return [self._ack(src, mavlink2.MAV_MISSION_ACCEPTED)], []
        self._pending, self._count, self._partner = [], msg.count, src
        self._last_recv = now
        return [self._request(now)], []

    def _on_item(self, msg, src, now: float) -> tuple[list, list[str]]:
        if not self.uploading:
            if self._last_done == (src, msg.seq):  # our final ACK was lost: say it again
                return [self._ack(src, mavlink2.MAV_MISSION_ACCEPTED)], []
            self.ignored += 1
            return [], []
        if src != self._partner:
            return [self._ack(src, mavlink2.MAV_MISSION_DENIED)], []
        if getattr(msg, "mission_type", MISSION) != MISSION:
            self._abort()
            return [self._ack(src, mavlink2.MAV_MISSION_UNSUPPORTED, msg.mission_type)], []
        self._last_recv = now
        expected = len(self._pending)
        if msg.seq == expected - 1:  # a repeat: the ground station missed our request
            return [self._request(now)], []
        if msg.seq != expected:
            self._abort()
            return [self._ack(src, mavlink2.MAV_MISSION_INVALID_SEQUENCE)], [
                f"mission: item {msg.seq} received, expected {expected}"
            ]
        bad = check_item(msg)
        if bad is not None:
            self._abort()
            return [self._ack(src, bad[0])], [f"mission refused: {bad[1]}"]
        self._pending.append(MissionItem.from_message(msg))
        if len(self._pending) < self._count:
            return [self._request(now)], []
        self.items, self._pending = self._pending, None
        self.version += 1
        self._last_done = (src, msg.seq)
        return [self._ack(src, mavlink2.MAV_MISSION_ACCEPTED)], []

    def tick(self, now: float) -> tuple[list, list[str]]:
        """Resend an unanswered request; give up on a silent partner."""
        if not self.uploading:
            return [], []
        if now - self._last_recv > self.timeout_s:
            to = self._partner
            self._abort()
            return [self._ack(to, mavlink2.MAV_MISSION_OPERATION_CANCELLED)], ["mission: upload timed out"]
        if now - self._last_sent >= self.retry_s:
            return [self._request(now)], []
        return [], []

    def item_message(self, item: MissionItem, to, current: int = 0):
        return self.mav.mission_item_int_encode(
            to[0],
            to[1],
            item.seq,
            item.frame,
            item.command,
            current,
            item.autocontinue,
            item.param1,
            item.param2,
            item.param3,
            item.param4,
            item.x,
            item.y,
            item.z,
            MISSION,
        )
