"""The vehicle's command logic: a PX4-like commander and navigator for the subset a ground station uses.

Pure logic: no sockets, no clock of its own. The owner (the node) calls
- `handle(msg, now)` with each parsed MAVLink message from the ground station → messages to send;
- `step(state, home, now, thrust)` once per control step with the vehicle's 12-state (ENU/FLU,
  position relative to home), home, the time and the collective thrust last commanded → messages
  to send (telemetry, events), after which `setpoint` is what the policy flies to;
and sends what they return. Every message it builds comes from its own pymavlink MAVLink instance
(system and component id of the vehicle, 1 and 1 by default): the owner sends them with its
link's `mav.send(msg)`.

The rules, and where they come from (commands: `commands`):
- HEARTBEAT as PX4 sends it (src/modules/mavlink/streams/HEARTBEAT.hpp): MAV_TYPE_QUADROTOR,
  MAV_AUTOPILOT_PX4, base_mode CUSTOM_MODE_ENABLED (+ SAFETY_ARMED when armed, + the AUTO or POSCTL
  flags), custom_mode = main << 16 | sub << 24 (src/modules/commander/px4_custom_mode.h: AUTO = 4
  with sub-modes 2 TAKEOFF, 3 LOITER (Hold), 4 MISSION, 5 RTL, 6 LAND; POSCTL = 3), system_status
  STANDBY disarmed, ACTIVE armed, CRITICAL in a failsafe. Sent at 1 Hz and at once on a change.
- Auto-disarm (commander_params.yaml): COM_DISARM_LAND s after landing, COM_DISARM_PRFLT s after
  arming without taking off. The motors idle (`Setpoint.motors_enabled` False) while landed and not
  taking off, and from ground contact on during a landing: PX4's position controller idles once the
  land detector says maybe-landed; a policy has no thrust ramp-down of its own, and on the ground
  with a descent commanded (see `setpoint`) the vehicle cannot be anywhere but on the ground.
- Missions (navigator/mission.cpp): started in the air at the current item, on the ground with a
  take-off first; MISSION_CURRENT on every change and at 1 Hz, MISSION_ITEM_REACHED per item (a
  land or return item at touchdown), repeated with MISSION_CURRENT up to 10 times
  (mavlink_mission.cpp); leaving Mission mode pauses it, Mission mode again resumes it; the end
  holds (or stays landed). Uploads and clears are refused while it is flown.
- Ground-station link loss (commander_params.yaml COM_DL_LOSS_T, NAV_DLL_ACT, COM_FAIL_ACT_T; PX4's
  failsafe framework holds for COM_FAIL_ACT_T "for the user to realize" before the action): no
  message from the ground station for COM_DL_LOSS_T s while flying → Hold; still none after
  COM_FAIL_ACT_T s more → NAV_DLL_ACT (1 Hold, 2 Return, 3 Land). A message during the hold
  resumes what was being flown; after the action the ground station takes over with a new command.
  Which clock: the one the owner passes (simulated time, which runs with the wall clock in a
  real-time simulation).
Parameters: `param_protocol`; files (MAVLink FTP): `ftp_protocol`; missions: `mission_protocol` (the
transfer) and `modes.Mission` (where the flight is in it); the flight modes: `modes`, their legs
flown by `navigator`; the moving target and the land detector: `setpoint`; telemetry: `streams`.
Message dispatch: `Commander.HANDLERS`, a table of functions, as the node's (`flight.Flight.HANDLERS`);
commands: `commands.COMMANDS`, likewise.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.core.state import POS, RATES, STATE_DIM, VEL, YAW, Z
from quadpilot.link.frames import Home

from . import commands, ftp_protocol, mission_protocol, policy_upload, streams
from .commands import ACCEPTED, DENIED, TEMP_REJECTED, enu_yaw
from .modes import HOLD, MISSION, MODE_NAMES, POSCTL, Land, Mission, Mode, Return
from .navigator import Navigator
from .param_protocol import NAV_DLL_LAND, NAV_DLL_RETURN, ParamTable, param_pack
from .setpoint import LandDetector, LandLimits, Mover

M = mavlink2
_AUTO_FLAGS = M.MAV_MODE_FLAG_AUTO_ENABLED | M.MAV_MODE_FLAG_STABILIZE_ENABLED | M.MAV_MODE_FLAG_GUIDED_ENABLED
_POSCTL_FLAGS = (
    M.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | M.MAV_MODE_FLAG_STABILIZE_ENABLED | M.MAV_MODE_FLAG_GUIDED_ENABLED
)


class BadVehicleState(ValueError):
    """`step` was given a state, thrust or time that cannot be one (the node passes only states that
    passed link.wire's checks; this guards the target the policy flies to against anything else)."""


@dataclass(frozen=True)
class CommanderConfig:
    """How the commander behaves where PX4 has no parameter for it."""

    lead_m: float = 0.75
    """m, the furthest the target runs ahead of the vehicle (setpoint.Mover): inside the 1 m ball the
    policies were trained to fly in from (core.mission.HOVER_START_RADIUS), with a margin."""
    arrival_dwell_s: float = 0.5
    """s the vehicle must stay within the acceptance radii before a goal counts as reached."""
    ground_alt_max_m: float | None = 0.5
    """m above home below which the vehicle may be on the ground (arming, land detection); the
    ground is where home is. None: no altitude check (uneven ground)."""
    land_trigger_s: float = 1.0
    """LNDMC_TRIG_TIME (PX4 land_detector_params_mc.c default); each detector stage takes a third."""
    repeat_window_s: float = 2.0
    """s during which a resent COMMAND_LONG (confirmation > 0) gets the first answer again."""
    params: dict = field(default_factory=dict)
    """Parameter values other than PX4's defaults, e.g. MPC_THR_HOVER of the vehicle."""
    system_id: int = 1
    component_id: int = 1  # MAV_COMP_ID_AUTOPILOT1
    flight_sw_version: int = 0
    uid: int = 0


@dataclass(frozen=True)
class Setpoint:
    """What the policy flies to: position (3,) and velocity (3,) ENU m from home, yaw rad ENU (the
    heading a version-2 policy holds, `core.observation`), armed, and whether the
    motors run (False: idle, on the ground or after touchdown)."""

    position: np.ndarray
    velocity: np.ndarray
    yaw: float
    armed: bool
    motors_enabled: bool


class Commander:
    """See the module docstring; `setpoint` is the policy's target after each `step`."""

    def __init__(self, cfg: CommanderConfig | None = None) -> None:
        self.cfg = cfg = cfg or CommanderConfig()
        self.mav = M.MAVLink(None, srcSystem=cfg.system_id, srcComponent=cfg.component_id)
        self.params = ParamTable(self.mav, cfg.params)
        self.missions = mission_protocol.MissionTransfer(self.mav)
        self.streams = streams.Streams()
        self.mover = Mover(cfg.lead_m)
        self.nav = Navigator(self.mover, self.params, cfg.arrival_dwell_s)
        self.detector = LandDetector()
        self.armed, self.mode, self.landed, self.motors = False, HOLD, True, False
        self.state: np.ndarray | None = None
        self.home: Home | None = None
        self.now = 0.0
        self._last_step: float | None = None
        self.yaw = 0.0
        self.armed_at = self.landed_at = 0.0
        self.flown = False  # left the ground since arming
        self.mission = Mission(self.missions, self.mav)
        self.last_gcs: float | None = None
        self.failsafe: str | None = None  # None, "hold" (waiting COM_FAIL_ACT_T), "action" or "motors cut"
        self.failsafe_at = 0.0
        self.dropped: Counter = Counter()
        self.new_policy = None
        """A policy.tar uploaded and checked (`policy_upload`), for the owner to fly when disarmed."""
        self.policies: list[dict] = []
        """Each policy.tar uploaded: when, what the ground station was told, its SHA-256 if good."""
        self._text_id = 0
        self.ftp = ftp_protocol.FtpServer(self.mav, lambda defaults: param_pack(self.params, defaults), self.dropped)
        self.received = 0
        self.recent_commands: dict = {}  # (source, command, is COMMAND_INT) → (arguments, result, time)
        self._out: list = []

    # --- outputs ---------------------------------------------------------------------------------
    @property
    def setpoint(self) -> Setpoint:
        return Setpoint(self.mover.ref.copy(), self.mover.velocity.copy(), self.yaw, self.armed, self.motors)

    @property
    def landed_state(self) -> int:
        if not self.armed or self.landed:
            return M.MAV_LANDED_STATE_ON_GROUND
        if self.nav.taking_off:
            return M.MAV_LANDED_STATE_TAKEOFF
        if self.nav.landing:
            return M.MAV_LANDED_STATE_LANDING
        return M.MAV_LANDED_STATE_IN_AIR

    @property
    def mission_state(self) -> int:
        return self.mission.state

    @property
    def mission_seq(self) -> int:
        return self.mission.seq

    def send(self, msg) -> None:
        """Queue a message for the owner to send with the answer of this `handle` or `step`."""
        self._out.append(msg)

    def text(self, text: str, severity: int = M.MAV_SEVERITY_INFO) -> None:
        self._out.append(self.mav.statustext_encode(severity, text.encode()[:50]))

    def long_text(self, text: str, severity: int = M.MAV_SEVERITY_INFO) -> None:
        """A text longer than one STATUSTEXT in chunks of 50 characters sharing an id (MAVLink's
        STATUSTEXT id and chunk_seq, which MAVSDK puts back together); the last chunk is shorter."""
        raw = text.encode("ascii", "replace")[: 50 * 20]
        if len(raw) <= 50:
            self._out.append(self.mav.statustext_encode(severity, raw))
            return
        self._text_id = self._text_id % 0xFFFF + 1
        chunks = [raw[i : i + 50] for i in range(0, len(raw), 50)]
        if len(chunks[-1]) == 50:
            chunks.append(b"")
        for k, chunk in enumerate(chunks):
            self._out.append(self.mav.statustext_encode(severity, chunk, self._text_id, k))

    def heartbeat(self):
        main, sub = self.mode
        base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (_POSCTL_FLAGS if main == 3 else _AUTO_FLAGS)
        if self.armed:
            base |= M.MAV_MODE_FLAG_SAFETY_ARMED
        status = M.MAV_STATE_CRITICAL if self.failsafe else (M.MAV_STATE_ACTIVE if self.armed else M.MAV_STATE_STANDBY)
        return self.mav.heartbeat_encode(
            M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, base, main << 16 | sub << 24, status
        )

    def set_mode(self, mode: tuple) -> None:
        if mode != self.mode:
            self.mode = mode
            self._out.append(self.heartbeat())

    def message(self, msg_id: int):
        """The message `msg_id` now, or None when it needs a state or home not known yet."""
        s, home, mav, now = self.state, self.home, self.mav, self.now
        if msg_id == streams.HEARTBEAT:
            return self.heartbeat()
        if msg_id == streams.AUTOPILOT_VERSION:
            return streams.autopilot_version(mav, self.cfg.flight_sw_version, self.cfg.uid)
        if msg_id == streams.SYS_STATUS:
            return streams.sys_status(
                mav, self.armable() is None or self.armed, sum(self.dropped.values()), self.received
            )
        if msg_id == streams.EXTENDED_SYS_STATE:
            return streams.extended_sys_state(mav, self.landed_state)
        if msg_id == streams.MISSION_CURRENT:
            return self.mission.current(self.mode == MISSION)
        if s is None or home is None:
            return None
        if msg_id == streams.HOME_POSITION:
            return streams.home_position(mav, home, now)
        if msg_id == streams.GPS_RAW_INT:
            return streams.gps_raw_int(mav, s, home, now)
        if msg_id == streams.GLOBAL_POSITION_INT:
            return streams.global_position_int(mav, s, home, now)
        if msg_id == streams.ATTITUDE:
            return streams.attitude(mav, s, now)
        if msg_id == streams.ATTITUDE_QUATERNION:
            return streams.attitude_quaternion(mav, s, now)
        if msg_id == streams.LOCAL_POSITION_NED:
            return streams.local_position_ned(mav, s, now)
        raise ValueError(f"message {msg_id} cannot be built")

    # --- input ---------------------------------------------------------------------------------------
    def handle(self, msg, now: float) -> list:
        """One message from the ground station → the messages to send in answer."""
        self.now = now
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.dropped["bad_data"] += 1
            return []
        target = getattr(msg, "target_system", 0)
        comp = getattr(msg, "target_component", 0)
        if target not in (0, self.cfg.system_id) or comp not in (0, self.cfg.component_id):
            self.dropped["not_for_us"] += 1
            return []
        self.received += 1
        self._link_alive(now)
        handler = self.HANDLERS.get(kind)
        if handler is None:
            self.dropped[f"unexpected_{kind.lower()}"] += 1
        else:
            handler(self, msg)
        out, self._out = self._out, []
        return out

    def _on_heartbeat(self, msg) -> None:
        """Only proof of life: the link-loss clock was restarted in `handle`."""

    def _on_ping(self, msg) -> None:
        """PING with target 0 is a request (MAVLink common.xml, PING): answered with the same time
        and sequence, addressed to the sender. MAVSDK sends them to measure the link."""
        if msg.target_system == 0:
            self._out.append(self.mav.ping_encode(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()))

    def _on_params(self, msg) -> None:
        replies, texts = self.params.handle(msg)
        self._out += replies
        for t in texts:
            self.text(t, M.MAV_SEVERITY_WARNING)

    def _on_mission(self, msg) -> None:
        replies, texts = self.missions.handle(msg, self.now)
        self._out += replies
        for t in texts:
            self.text(t, M.MAV_SEVERITY_WARNING)
        self._mission_changed()

    def _on_ftp(self, msg) -> None:
        self._out += self.ftp.handle(msg, self.now)
        for path in self.ftp.finished:
            if path == ftp_protocol.POLICY_PATH and path in self.ftp.card.files:
                tar, said = policy_upload.check_upload(bytes(self.ftp.card.files[path]))
                self.long_text(said, M.MAV_SEVERITY_INFO if tar else M.MAV_SEVERITY_ERROR)
                self.policies.append({"at_s": self.now, "text": said, "sha256": tar and tar.sha256})
                self.new_policy = tar or self.new_policy
        self.ftp.finished.clear()

    # --- arming, modes, missions --------------------------------------------------------------------
    def armable(self) -> str | None:
        """Why the vehicle may not arm now, or None."""
        if self.state is None or self.home is None:
            return "no position yet"
        g = self.cfg.ground_alt_max_m
        if g is not None and self.state[Z] > g:
            return f"not on the ground ({self.state[Z]:.1f} m above home)"
        if self.failsafe:
            return "failsafe active"
        return None

    def arm(self) -> None:
        self.armed, self.flown, self.armed_at = True, False, self.now
        self.mover.reset(self.state[POS])
        self.yaw = float(self.state[YAW])
        self.nav.hold()
        if self.mode == MISSION and self.mission.items:
            self.start_mission(None)
        elif self.mode != POSCTL:
            self.mode = HOLD
        self._out.append(self.heartbeat())

    def disarm(self) -> None:
        self.armed, self.motors = False, False
        self.nav.hold()
        if self.state is not None:
            self.mover.reset(self.state[POS])
        self._leave_mission()
        self.failsafe = None
        self.nav.freeze(False)
        self.mode = HOLD  # a new flight starts from Hold (MAVSDK arms from there)
        self._out.append(self.heartbeat())

    def fly(self, mode: Mode) -> None:
        """Switch to a navigator mode (not Mission: `start_mission`; not a plain Hold: `hold`) and
        fly its legs from the reference; a mission being flown is paused."""
        self._leave_mission()
        self.nav.start(mode.legs(self.mover.ref, self.params), keep_speed=mode.keep_speed)
        self.set_mode(mode.custom_mode)

    def hold(self, mode: tuple = HOLD) -> None:
        """Hold (or Position, which holds here too): stop the reference where it is."""
        self._leave_mission()
        if self.armed:
            self.nav.hold()
        self.set_mode(mode)

    def arm_in_air(self, state=None) -> None:
        """Start armed and holding where the vehicle is (a simulator that starts in the air): at the
        state of the last `step`, or at `state` (12,) given before the first step, so that the first
        heartbeat a ground station hears already says armed."""
        if state is not None:
            s = np.asarray(state, np.float64)
            if s.shape != (STATE_DIM,) or not np.all(np.isfinite(s)):
                raise BadVehicleState(f"vehicle state {s.tolist()}: expected 12 finite numbers (link.wire checks them)")
            self.state = s
        if self.state is None:
            raise ValueError("arm_in_air needs the vehicle's state: a first step(), or state=")
        self.arm()
        self.landed, self.flown, self.motors = False, True, True
        self.detector.landed_h.state = self.detector.maybe_landed.state = self.detector.ground_contact.state = False

    def motors_cut(self, reason: str) -> list:
        """The owner has cut the motors on its own (its failsafe, e.g. the simulator link lost): say
        so as PX4 reports a failsafe, disarmed with system status CRITICAL and a STATUSTEXT, so that a
        ground station does not go on showing an armed vehicle. Returns the messages to send."""
        if self.armed:
            self.disarm()
            self._out.pop()  # disarm's heartbeat: the one below says the same, and CRITICAL
        self.failsafe = "motors cut"  # heartbeats say CRITICAL until the next step while disarmed
        self.text(f"Failsafe: {reason}", M.MAV_SEVERITY_CRITICAL)
        self._out.append(self.heartbeat())
        out, self._out = self._out, []
        return out

    def _mission_changed(self) -> None:
        if self.mission.changed():
            self._out.append(self.mission.current(self.mode == MISSION))

    def start_mission(self, first: int | None) -> tuple[int, str | None]:
        """Mission mode, from item `first` or where the mission was paused; flown once armed."""
        mission = self.mission
        why = mission.refusal(self.home, self.params)
        if why is not None:
            return (TEMP_REJECTED if mission.items and self.home is None else DENIED), why
        mission.begin(first)
        self.set_mode(MISSION)
        if not self.armed:  # PX4: the mode can be chosen on the ground; the mission starts when armed
            return ACCEPTED, None
        self.nav.start(mission.legs(self.mover.ref, self.params, self.home, self.landed))
        self._item_started(mission.seq)
        self._out.append(mission.current(True))
        return ACCEPTED, None

    def _item_started(self, seq: int) -> None:
        heading = self.mission.item_yaw(seq)
        if heading is not None:
            self.yaw = enu_yaw(heading)

    def _leave_mission(self) -> None:
        if self.mission.pause():
            self._out.append(self.mission.current(self.mode == MISSION))

    def _item_reached(self, seq: int) -> None:
        """MISSION_ITEM_REACHED, then the next item, or the end (Hold, unless it ended on the ground)."""
        mission = self.mission
        self._out.append(self.mav.mission_item_reached_encode(seq))
        what = mission.item_reached(seq)
        if what == "finished":
            self.text("Mission finished")
            if not self.landed:
                self.hold()
        elif what == "wait":  # wait here until told to go on (DO_SET_MODE MISSION)
            self.hold()
        else:
            self.nav.start(mission.next_legs(self.mover.ref, self.home, self.params), keep_speed=True)
            self._item_started(mission.seq)
        self._out.append(mission.current(self.mode == MISSION))

    # --- the control step ----------------------------------------------------------------------------
    def step(self, state, home: Home, now: float, thrust: float) -> list:
        """One control step: the vehicle's state (12,) ENU/FLU relative to home, home, the time (s)
        and the collective thrust fraction last commanded (setpoint.collective_thrust). Returns the
        messages to send; `setpoint` is then the target for the policy."""
        s = np.asarray(state, np.float64)
        if s.shape != (STATE_DIM,) or not np.all(np.isfinite(s)):
            raise BadVehicleState(f"vehicle state {s.tolist()}: expected 12 finite numbers (link.wire checks them)")
        if not math.isfinite(thrust) or not math.isfinite(now):
            raise BadVehicleState(f"thrust {thrust}, time {now}: expected finite numbers")
        dt = 0.0 if self._last_step is None else max(0.0, now - self._last_step)
        self._last_step, self.now, self.state, self.home = now, now, s, home
        p = self.params
        if not self.armed:
            self.mover.reset(s[POS])
        limits = LandLimits(
            p["MPC_THR_MIN"],
            p["MPC_THR_HOVER"],
            p["LNDMC_Z_VEL_MAX"],
            p["LNDMC_XY_VEL_MAX"],
            math.radians(p["LNDMC_ROT_MAX"]),
            self.cfg.ground_alt_max_m,
            self.cfg.land_trigger_s,
        )
        was = self.landed
        self.landed = self.detector.update(
            now, self.armed, float(s[Z]), s[VEL], s[RATES], thrust if self.motors else 0.0, self.nav.landing, limits
        )
        if self.armed and was and not self.landed:
            self.flown = True
            self.text("Takeoff detected")
        elif self.armed and self.landed and not was:
            self.landed_at = now
            self.text("Landing detected")
        for tag in self.nav.update(now, dt, s[POS], self.landed):
            if tag == "takeoff":
                self.set_mode(HOLD)
            elif isinstance(tag, tuple) and tag[0] == "item":
                self._item_reached(tag[1])
        self._auto_disarm(now)
        self._link_check(now)
        self.motors = self.armed and not (self.landed and not self.nav.taking_off)
        self.motors = self.motors and not (self.nav.landing and self.detector.contact)
        self.missions.locked = self.armed and self.mode == MISSION and self.mission.active
        self.ftp.tick(now)
        replies, texts = self.missions.tick(now)
        self._out += replies
        for t in texts:
            self.text(t, M.MAV_SEVERITY_WARNING)
        for msg_id in self.streams.due(now):
            msg = self.message(msg_id)
            if msg is not None:
                self._out.append(msg)
            if msg_id == streams.MISSION_CURRENT and (again := self.mission.repeat_reached()) is not None:
                self._out.append(again)
        out, self._out = self._out, []
        return out

    def _auto_disarm(self, now: float) -> None:
        if not self.armed or not self.landed or self.nav.taking_off:
            return
        p = self.params
        if self.flown and p["COM_DISARM_LAND"] > 0 and now - self.landed_at >= p["COM_DISARM_LAND"]:
            self.disarm()
            self.text("Disarmed by landing")
        elif not self.flown and p["COM_DISARM_PRFLT"] > 0 and now - self.armed_at >= p["COM_DISARM_PRFLT"]:
            self.disarm()
            self.text("Disarmed by auto preflight disarming")

    def _link_alive(self, now: float) -> None:
        self.last_gcs = now
        if self.failsafe in ("hold", "action"):  # a link-loss failsafe, not the owner's `motors_cut`
            if self.failsafe == "hold":
                self.nav.freeze(False)  # resume what was being flown
            self.failsafe = None
            self.text("Ground station connection regained")
            self._out.append(self.heartbeat())

    def _link_check(self, now: float) -> None:
        p = self.params
        act = int(p["NAV_DLL_ACT"])
        if self.failsafe is None:
            flying = self.armed and not self.landed
            if flying and act and self.last_gcs is not None and now - self.last_gcs > p["COM_DL_LOSS_T"]:
                self.failsafe, self.failsafe_at = "hold", now
                self.nav.freeze(True)
                self.text("Connection to ground station lost", M.MAV_SEVERITY_CRITICAL)
                self._out.append(self.heartbeat())
            return
        if self.failsafe == "hold" and now - self.failsafe_at >= p["COM_FAIL_ACT_T"]:
            self.failsafe = "action"
            self.nav.freeze(False)
            self._leave_mission()
            if act == NAV_DLL_RETURN and not self.landed:
                self.fly(Return())
            elif act == NAV_DLL_LAND:
                self.fly(Land(self.mover.ref[0:2]))
            else:  # NAV_DLL_HOLD (or Return once on the ground)
                self.hold()
            self.text(f"Failsafe activated: {MODE_NAMES[self.mode]}", M.MAV_SEVERITY_CRITICAL)
        if not self.armed:
            self.failsafe = None

    HANDLERS = {
        "HEARTBEAT": _on_heartbeat,
        "PING": _on_ping,
        "COMMAND_LONG": commands.on_command,
        "COMMAND_INT": commands.on_command,
        "SET_MODE": commands.on_set_mode,
        "PARAM_REQUEST_LIST": _on_params,
        "PARAM_REQUEST_READ": _on_params,
        "PARAM_SET": _on_params,
        "MISSION_COUNT": _on_mission,
        "MISSION_ITEM_INT": _on_mission,
        "MISSION_ITEM": _on_mission,
        "MISSION_REQUEST_LIST": _on_mission,
        "MISSION_REQUEST_INT": _on_mission,
        "MISSION_REQUEST": _on_mission,
        "MISSION_ACK": _on_mission,
        "MISSION_CLEAR_ALL": _on_mission,
        "FILE_TRANSFER_PROTOCOL": _on_ftp,
    }
    """Message type → handler (a function of the commander and the message), as the node dispatches
    (`flight.Flight.HANDLERS`); types not here are counted as dropped (`unexpected_<type>`)."""
