"""What the node flies while the state stream is silent: an estimate, a hold, then a landing.

When a step's HIL_SENSOR arrives without its HIL_STATE_QUATERNION, the node no longer drops the step:
it starts an `InertialEstimate` (`autopilot.dead_reckoning`) from the last valid state and flies on
it, in phases measured from that last state, as PX4 does when its position estimate is lost:

1. `policy`, for `StateLossConfig.policy_s`: the policy flies on the estimate, as if it were the
   state (PX4 waits COM_POS_FS_DELAY, 1 s by default, before it calls a position lost).
2. `hold`, until `descend_s`: the classical fallback holds the attitude level and the height the
   vehicle had (`runtime.fallback.FallbackController.track_velocity`), with no horizontal position
   to hold any more: the dead-reckoned horizontal position is no longer trusted.
3. `descend`: a controlled descent at `descent_speed` (PX4's MPC_LAND_SPEED is 0.7 m/s), level,
   holding the heading. This phase is a failsafe and latches: states that return now are flown
   on (they are a better estimate), but the landing goes on, as PX4's Land mode does.
4. `landed`: the land detector saw the vehicle stop descending (|vertical speed| below
   `land_speed` for `land_time_s`, while commanded down; after PX4's land detector, LNDMC_Z_VEL_MAX
   and LNDMC_TRIG_TIME). Only now do the motors stop: the node disarms and answers every step with
   zero commands. It never stops the motors in the air.

States that return in phase 1 or 2 end the loss: in phase 1 the policy simply flies on them; in
phase 2 the safety monitor hands back to the policy by its usual rule (`runtime.safety`: valid
states inside the recovery envelope for HAND_BACK_HOLD_S).

An implausible estimate (`InertialEstimate.plausible` False) skips to the descent at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from quadpilot.core.frames import euler_to_rotmat
from quadpilot.core.params import NUM_MOTORS, VehicleParams
from quadpilot.core.state import PITCH, RATES, ROLL, VEL, YAW, Z
from quadpilot.runtime.fallback import FallbackController

from .dead_reckoning import ImuCalibration, InertialEstimate, baro_from_hil_sensor

PHASES = ("policy", "hold", "descend", "landed")
LAND_ARM_S = 3.0
"""s of descent after which the land detector listens even if the vehicle was never seen descending
(it was standing already); before, only once it has descended faster than `land_speed`."""


@dataclass(frozen=True)
class StateLossConfig:
    """The phases' timing and the landing (seconds of simulated time from the last valid state)."""

    policy_s: float = 1.0
    """s the policy flies on the estimate (PX4's COM_POS_FS_DELAY default)."""
    descend_s: float = 2.0
    """s after which the node lands (from `policy_s` to here the fallback holds attitude and height)."""
    descent_speed: float = 0.7
    """m/s, the descent (PX4's MPC_LAND_SPEED default)."""
    land_speed: float = 0.25
    """m/s: slower than this, while commanded down, is no longer descending (ground contact)."""
    land_time_s: float = 0.5
    """s of not descending before the land detector says landed."""
    arm_wait_s: float = 1.0
    """s of HIL_SENSOR without any state before the node refuses to arm."""

    def __post_init__(self) -> None:
        for name in ("policy_s", "descend_s", "land_time_s", "arm_wait_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v <= 3600.0):
                raise ValueError(f"{name} must be a number of seconds in [0, 3600], got {v!r}")
        if self.policy_s > self.descend_s:
            raise ValueError(f"policy_s ({self.policy_s:g} s) must not exceed descend_s ({self.descend_s:g} s)")
        if not (0.05 <= self.descent_speed <= 1.0):
            raise ValueError(f"descent_speed must be in [0.05, 1] m/s, got {self.descent_speed!r}")
        if not (0.0 < self.land_speed < self.descent_speed):
            raise ValueError(f"land_speed must be in (0, descent_speed), got {self.land_speed!r}")


def parse_state_loss(text: str) -> StateLossConfig:
    """`POLICY_S,DESCEND_S` (quad-sitl --state-loss) → StateLossConfig; ValueError in one line otherwise."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError(f"{text!r} is not two numbers")
        return StateLossConfig(policy_s=float(parts[0]), descend_s=float(parts[1]))
    except ValueError as e:
        raise ValueError(
            f"{e}; expected POLICY_S,DESCEND_S in seconds with 0 <= POLICY_S <= DESCEND_S, e.g. 1,2"
        ) from None


class StateLoss:
    """One loss of the state stream: its estimate, its phase and the commands of its hold and descent."""

    def __init__(
        self,
        cfg: StateLossConfig,
        vehicle: VehicleParams,
        last_state: list,
        last_state_us: int,
        sensor,
        step_s: float,
        calibration: ImuCalibration | None = None,
    ) -> None:
        self.cfg = cfg
        self.vehicle = vehicle
        self.since_us = int(last_state_us)
        baro = baro_from_hil_sensor(sensor)
        self.estimate = InertialEstimate(last_state, last_state_us, vehicle.gravity, baro, calibration)
        self.phase = "policy"
        self.hold_z = float(last_state[Z])
        self.step_s = float(step_s)
        self.controller: FallbackController | None = None
        self._still_us: int | None = None  # since when the descent has not been descending
        self._descend_us: int | None = None  # when the descent began
        self._descending = False  # it has been seen descending faster than land_speed
        self.changes: list[tuple[int, str, str]] = []
        """(time_usec, phase, why) of every phase change, in order."""

    def update(self, sensor) -> str:
        """A step with no state: propagate the estimate, move on through the phases; the phase."""
        self.estimate.update(sensor)
        elapsed = (int(sensor.time_usec) - self.since_us) * 1e-6
        if self.phase in ("policy", "hold"):
            if not self.estimate.plausible:
                self._enter("descend", int(sensor.time_usec), f"estimate implausible: {self.estimate.implausible}")
            elif elapsed >= self.cfg.descend_s:
                self._enter("descend", int(sensor.time_usec), f"no state for {self.cfg.descend_s:g} s")
            elif self.phase == "policy" and elapsed >= self.cfg.policy_s:
                self._enter("hold", int(sensor.time_usec), f"no state for {self.cfg.policy_s:g} s")
        return self.phase

    def _enter(self, phase: str, t_us: int, why: str) -> None:
        self.phase = phase
        self.changes.append((t_us, phase, why))
        if phase in ("hold", "descend") and self.controller is None:
            self.controller = FallbackController(self.vehicle, self.step_s)

    @property
    def latched(self) -> bool:
        """Descending or landed: states that return do not end it."""
        return self.phase in ("descend", "landed")

    def command(self, state: list, t_us: int) -> np.ndarray:
        """Motor commands for the hold or the descent, flown on `state` (the estimate, or returned
        states once descending); zeros once landed."""
        if self.phase == "landed":
            return np.zeros(NUM_MOTORS, np.float32)
        s = np.asarray(state, np.float64)
        rot = euler_to_rotmat(s[ROLL], s[PITCH], s[YAW])
        vz = float(s[VEL][2])
        if self.phase == "hold":
            v_sp = (0.0, 0.0, self.controller.gains.pos_p * (self.hold_z - float(s[Z])))
        else:
            v_sp = (0.0, 0.0, -self.cfg.descent_speed)
            if self._descend_us is None:
                self._descend_us = t_us
            self._descending |= vz < -self.cfg.land_speed
            # the detector listens once the descent has begun to move (or after LAND_ARM_S, for a
            # vehicle that was already standing): the first moments of a descent from a hover are slow
            armed = self._descending or (t_us - self._descend_us) * 1e-6 >= LAND_ARM_S
            if armed and abs(vz) < self.cfg.land_speed:
                if self._still_us is None:
                    self._still_us = t_us
                elif (t_us - self._still_us) * 1e-6 >= self.cfg.land_time_s:
                    self._enter("landed", t_us, f"not descending for {self.cfg.land_time_s:g} s: landed, motors off")
                    return np.zeros(NUM_MOTORS, np.float32)
            else:
                self._still_us = None
        # no horizontal velocity to trust: level (zero horizontal acceleration asked), vertical held
        return self.controller.track_velocity(rot, (0.0, 0.0, vz), s[RATES], v_sp)

    def estimate_state(self) -> list:
        return self.estimate.state()
