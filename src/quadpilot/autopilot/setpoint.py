"""The target the policy flies to, moved at bounded speed, and the land detector.

`Mover` carries a reference position towards a goal at bounded horizontal and vertical speeds (the
PX4 speed parameters the caller passes in) and never lets the reference run further than `lead_m`
ahead of the vehicle. The policies here were trained to reach a target from offsets within 1 m
(core.mission.HOVER_START_RADIUS); a reference kept within `lead_m` < 1 m of the vehicle keeps every
observation in that range whatever the distance flown, and the states along the way (moving towards a
target under a metre away) are the ones the policy saw while recovering from its training starts.
The rule is PX4's trajectory limiter (MPC_XY_ERR_MAX, src/modules/mc_pos_control/
multicopter_autonomous_params.yaml: "Trajectory integration slows linearly with position error;
stops when error >= this"): the reference advances at `speed · (1 − e / lead_m)`, e the distance
from vehicle to reference, and stops at e ≥ lead_m.

`LandDetector` follows PX4's multicopter land detector (src/modules/land_detector/
MulticopterLandDetector.cpp), in its three stages, each entered only after its condition has held
for a third of the trigger time (LNDMC_TRIG_TIME, 1 s in land_detector_params_mc.c) and left at once:
- ground contact: low collective thrust (below 60 % of the range from MPC_THR_MIN to MPC_THR_HOVER:
  PX4's relaxed threshold for a valid hover-thrust estimate, which the vehicle model gives exactly),
  a commanded descent (until landed), no vertical movement (|vz| ≤ LNDMC_Z_VEL_MAX, ×2.5 once maybe
  landed), no horizontal movement (≤ LNDMC_XY_VEL_MAX), and, where PX4 would use a distance sensor,
  the altitude above home below `ground_alt_max_m` (the ground is where home is);
- maybe landed: thrust below 10 % of that range, no roll/pitch rotation beyond LNDMC_ROT_MAX
  (×2.5 once maybe landed), and ground contact;
- landed: maybe landed. Disarmed is always landed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def collective_thrust(motors) -> float:
    """Collective thrust as a fraction of the maximum, from motor commands u = ω/ω_max (thrust ∝ ω²):
    mean(u²). What the land detector compares with MPC_THR_HOVER (= hover_command² of the vehicle)."""
    u = np.clip(np.asarray(motors, np.float64), 0.0, 1.0)
    return float(np.mean(u * u))


class Mover:
    """A reference position (3,) ENU moving towards `goal` at bounded speeds, within `lead_m` of the
    vehicle. `update(dt, vehicle_pos)` → the new reference; `velocity` is its last rate of change."""

    def __init__(self, lead_m: float) -> None:
        if not (math.isfinite(lead_m) and lead_m > 0.0):
            raise ValueError(f"lead distance {lead_m} m: expected a positive number of metres")
        self.lead_m = lead_m
        self.ref = np.zeros(3)
        self.goal = np.zeros(3)
        self.velocity = np.zeros(3)
        self.speed_xy, self.speed_up, self.speed_down = 1.0, 1.0, 1.0

    def reset(self, position) -> None:
        """Reference and goal at `position` (the vehicle's, on arming or disarming)."""
        self.ref = np.array(position, np.float64)
        self.goal = self.ref.copy()
        self.velocity = np.zeros(3)

    def set_goal(self, goal, speed_xy: float, speed_up: float, speed_down: float) -> None:
        """Move towards `goal` from wherever the reference is now (no jump)."""
        self.goal = np.array(goal, np.float64)
        self.speed_xy, self.speed_up, self.speed_down = speed_xy, speed_up, speed_down

    def stop(self) -> None:
        """Hold the reference where it is (PX4 Hold: stop, and hold where stopped)."""
        self.goal = self.ref.copy()

    @property
    def at_goal(self) -> bool:
        return bool(np.array_equal(self.ref, self.goal))

    def update(self, dt: float, vehicle_pos) -> np.ndarray:
        d = self.goal - self.ref
        dist_xy, dist_z = math.hypot(d[0], d[1]), abs(d[2])
        if dt <= 0.0 or (dist_xy == 0.0 and dist_z == 0.0):
            self.velocity = np.zeros(3)
            return self.ref
        speed_z = self.speed_up if d[2] > 0 else self.speed_down
        # time to the goal with each axis group at its limit; moving along the straight line at the
        # slower of the two keeps both within their limits and makes them arrive together
        t_goal = max(dist_xy / self.speed_xy, dist_z / speed_z)
        e = float(np.linalg.norm(self.ref - np.asarray(vehicle_pos, np.float64)))
        scale = min(1.0, max(0.0, 1.0 - e / self.lead_m))
        frac = min(1.0, dt * scale / t_goal)
        step = d * frac
        self.ref = self.goal.copy() if frac >= 1.0 else self.ref + step
        self.velocity = step / dt
        return self.ref


@dataclass(frozen=True)
class LandLimits:
    """The thresholds of one land-detector update (PX4 parameter values, SI units)."""

    thr_min: float
    thr_hover: float
    z_vel_max: float
    xy_vel_max: float
    rot_max: float
    """rad/s."""
    ground_alt_max_m: float | None
    """m above home below which the vehicle may be on the ground; None: no altitude check."""
    trigger_s: float = 1.0
    """LNDMC_TRIG_TIME (land_detector_params_mc.c, default 1 s); each stage takes a third of it."""


class _Hysteresis:
    """True only after the condition has held for `delay` s; false as soon as it fails (PX4's
    systemlib::Hysteresis with set_hysteresis_time_from(false, delay))."""

    def __init__(self, state: bool) -> None:
        self.state = state
        self.since: float | None = None

    def update(self, condition: bool, now: float, delay: float) -> bool:
        if not condition:
            self.state, self.since = False, None
        elif not self.state:
            if self.since is None:
                self.since = now
            if now - self.since >= delay:
                self.state = True
        return self.state


class LandDetector:
    """ON the ground or not, from state and commanded thrust; see the module docstring."""

    def __init__(self) -> None:
        self.ground_contact = _Hysteresis(True)
        self.maybe_landed = _Hysteresis(True)
        self.landed_h = _Hysteresis(True)

    @property
    def landed(self) -> bool:
        return self.landed_h.state

    @property
    def contact(self) -> bool:
        return self.ground_contact.state

    def reset_landed(self) -> None:
        for h in (self.ground_contact, self.maybe_landed, self.landed_h):
            h.state, h.since = True, None

    def update(
        self,
        now: float,
        armed: bool,
        altitude: float,
        velocity,
        body_rates,
        thrust: float,
        in_descend: bool,
        lim: LandLimits,
    ) -> bool:
        """One update; returns `landed`. `altitude` m above home, `velocity` (3,) ENU m/s,
        `body_rates` (3,) FLU rad/s, `thrust` the collective thrust fraction commanded."""
        if not armed:  # "When not armed, consider to be landed"
            self.reset_landed()
            return True
        delay = lim.trigger_s / 3.0
        span = lim.thr_hover - lim.thr_min
        vx, vy, vz = (float(v) for v in velocity)
        maybe = self.maybe_landed.state
        z_limit = lim.z_vel_max * (2.5 if maybe else 1.0)
        contact = (
            thrust <= lim.thr_min + 0.6 * span
            and abs(vz) <= z_limit
            and math.hypot(vx, vy) <= lim.xy_vel_max
            and (lim.ground_alt_max_m is None or altitude <= lim.ground_alt_max_m)
        )
        if not maybe and not self.landed_h.state:
            contact = contact and in_descend  # "ground contact requires commanded descent until landed"
        self.ground_contact.update(contact, now, delay)
        rot_limit = lim.rot_max * (2.5 if maybe else 1.0)
        p, q = float(body_rates[0]), float(body_rates[1])
        maybe_now = thrust <= lim.thr_min + 0.1 * span and math.hypot(p, q) <= rot_limit and self.ground_contact.state
        self.maybe_landed.update(maybe_now, now, delay)
        return self.landed_h.update(self.maybe_landed.state, now, delay)


def land_speed(altitude: float, down: float, land: float, alt1: float, alt2: float) -> float:
    """Descent speed of a landing at `altitude` m above home: MPC_Z_V_AUTO_DN (`down`) above
    MPC_LAND_ALT1, MPC_LAND_SPEED (`land`) below MPC_LAND_ALT2, linear between
    (multicopter_takeoff_land_params.yaml)."""
    hi, lo = max(alt1, alt2), min(alt1, alt2)
    if altitude <= lo:
        return land
    if altitude >= hi:
        return down
    return land + (altitude - lo) / (hi - lo) * (down - land)
