"""The `px4-raptor` contract: what PX4's `mc_raptor` module feeds the RAPTOR policy and what it does
with the answer, so that a policy PX4 flies can be flown here unchanged (and one trained here could
be flown by PX4). NumPy only.

The specification is PX4's source, src/modules/mc_raptor/mc_raptor.cpp (`Raptor::observe`,
`Raptor::Run`, `Raptor::reset`), and RLtools' inference executor it calls
(rl_tools/inference/applications/l2f/operations_generic.h, `observe` and `control`;
rl_tools/inference/executor/operations_generic.h, `control`). docs/px4.md has the table.

Frames. PX4 keeps the world in NED and the body in FRD. `Raptor::observe` turns both into RAPTOR's
own frames by negating y and z: the world becomes North-West-Up (x north, y west, z up), the body
FLU, and the attitude quaternion (w, x, y, z) becomes (w, x, −y, −z). Position and velocity errors
(vehicle minus setpoint) are then rotated into the setpoint-yaw frame (the world turned by the
setpoint's yaw) and clipped; the attitude is the rotation of the body relative to that frame. Our
state is ENU/FLU, and the NWU world is ENU turned by −90° about z; a quantity expressed relative to
the setpoint yaw is the same in any world frame with the same up axis, so the same observation comes
from our state as Rz(−ψ)·(p − p_sp), Rz(−ψ)·R, Rz(−ψ)·(v − v_sp) with ψ the setpoint's ENU yaw
(`observation_values`, written once: `observation` runs it on one vehicle's floats,
`observation_batch` on a batch's columns, and `observation_ned` on PX4's topics turned into our
frames; the tests hold it to values worked out by hand from PX4's way of computing it).

Actions. The policy answers 4 values; the executor clamps them to [−1, 1]; mc_raptor keeps them as
the next "previous action" and writes (a + 1)/2 to actuator_motors, remapped from the Crazyflie motor
order the policy was trained in (front-right, back-right, back-left, front-left) to PX4's quad-X
order (front-right, back-left, front-left, back-right): PX4 output i takes policy output
`MOTOR_FROM_POLICY[i]` (`motor_commands`). PX4 calls that value thrust-normalised; what it means to a
rotor is the simulator's business: the RAPTOR policy was trained in RLtools' L2F simulator, where it
sets the rotor speed setpoint between the vehicle's action_limit.min and .max linearly (the thrust a
quadratic in the speed, rotor_thrust_coefficients), and our
simulator and RotorPy's PX4 simulator read HIL_ACTUATOR_CONTROLS the same way (rotor speed =
command · ω_max; ω_min = 0 on the vehicles flown), so the command goes to them unchanged.

Timing (`Executor`). mc_raptor runs the policy on every gyro update, but the policy was trained at
100 Hz and its GRU state must advance at 100 Hz: every `force_sync_native`-th call (IMU_GYRO_RATEMAX
/ 100, integer division: 2 at 250 Hz) is a "native" step that advances the state; the calls between
are "intermediate" steps that evaluate the policy from a copy of the state and discard it. The
previous-action input on a native step is the mean of the actions sent since the last native step
(including the last native step's own), and after a reset it is 0 (RESET_PREVIOUS_ACTION_VALUE).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .frames import rotation_entries, swap_frames_entries
from .observation import ObsField, ObsLayout, heading_turned

MAX_POSITION_ERROR_M = 0.5
"""mc_raptor.hpp `max_position_error`: each component of the position error is clipped to this."""
MAX_VELOCITY_ERROR_M_S = 1.0
"""mc_raptor.hpp `max_velocity_error`."""
STUDENT_SCHEMA = "quadpilot.px4-raptor/1"
"""The schema of the checkpoint `quad-train --contract px4-raptor` writes (`train.raptor.distill`):
torch tensors to export with `quad-export --format px4-raptor`, not a file anything flies."""
TRAINING_RATE_HZ = 100
"""mc_raptor.hpp POLICY_CONTROL_FREQUENCY_TRAINING: the rate the GRU state advances at."""
RESET_PREVIOUS_ACTION = 0.0
"""mc_raptor.hpp RESET_PREVIOUS_ACTION_VALUE: the previous action after a reset."""
MOTOR_FROM_POLICY = (0, 2, 3, 1)
"""PX4 quad-X output i (front-right, back-left, front-left, back-right) ← policy output
MOTOR_FROM_POLICY[i] (Crazyflie order: front-right, back-right, back-left, front-left); mc_raptor.hpp
REMAP_FROM_CRAZYFLIE, applied in `Raptor::Run`."""
OBS_DIM = 22
ACTION_DIM = 4

PX4_RAPTOR_LAYOUT = ObsLayout(
    "px4-raptor",
    (
        ObsField(
            "pos_error",
            3,
            "m",
            "position minus setpoint, setpoint-yaw frame (x forward along the setpoint yaw, y left, z up), "
            f"each component clipped to ±{MAX_POSITION_ERROR_M:g} m",
        ),
        ObsField("rot", 9, "1", "rotation body FLU → setpoint-yaw frame, row-major: Rz(−ψ_sp)·R"),
        ObsField(
            "vel",
            3,
            "m/s",
            "velocity minus setpoint velocity, setpoint-yaw frame, "
            f"each component clipped to ±{MAX_VELOCITY_ERROR_M_S:g}",
        ),
        ObsField("rates", 3, "rad/s", "body rates p, q, r, FLU"),
        ObsField(
            "prev_action",
            ACTION_DIM,
            "1",
            "the previous action in [−1, 1], policy (Crazyflie) motor order; on a 100 Hz step the mean since the last",
        ),
    ),
    heading_frame=True,
)
"""The contract's observation, in the order RAPTOR takes it (its checkpoint's meta says
Position.OrientationRotationMatrix.LinearVelocity.AngularVelocityDelayed(0).ActionHistory(1)).
Not in `core.observation.LAYOUTS`, the layouts an exported model file may declare: the node builds
those with `build_observation`, and this one only a policy that carries the contract builds
(`runtime.raptor`)."""


def observation(
    state,
    target,
    target_vel=None,
    heading: float = 0.0,
    previous_action=(RESET_PREVIOUS_ACTION,) * ACTION_DIM,
) -> np.ndarray:
    """The 22 float32 inputs `Raptor::observe` computes, from our 12-state (ENU/FLU, SI: x, y, z,
    vx, vy, vz, roll, pitch, yaw, p, q, r), the setpoint position (ENU), its velocity (ENU; None:
    0) and its yaw `heading` (rad, ENU: 0 = east), and the previous action (policy order)."""
    x, y, z, vx, vy, vz, roll, pitch, yaw, p, q, r = (float(v) for v in state)
    rot = rotation_entries(math.sin, math.cos, roll, pitch, yaw)
    tx, ty, tz = (float(v) for v in target)
    tvx, tvy, tvz = (0.0, 0.0, 0.0) if target_vel is None else (float(v) for v in target_vel)
    c, s = math.cos(float(heading)), math.sin(float(heading))
    values = observation_values(rot, (x - tx, y - ty, z - tz), (vx - tvx, vy - tvy, vz - tvz), (p, q, r), c, s, _clip)
    return np.array([*values, *(float(a) for a in previous_action)], np.float32)


def observation_batch(state, target, heading, previous_action, out: np.ndarray | None = None) -> np.ndarray:
    """`observation` for N vehicles at once (for training): state (N, 12), target (N, 3), heading
    (N,), previous action (N, 4), the setpoint velocity 0 (hover); returns (N, 22) float32 (into
    `out` if given). `observation_values` on the columns, in float64 as `observation` computes, then
    rounded."""
    s = np.asarray(state, np.float64)
    x, y, z, vx, vy, vz, roll, pitch, yaw, p, q, r = s.T
    tx, ty, tz = np.asarray(target, np.float64).T
    heading = np.asarray(heading, np.float64)
    rot = rotation_entries(np.sin, np.cos, roll, pitch, yaw)
    values = observation_values(
        rot, (x - tx, y - ty, z - tz), (vx, vy, vz), (p, q, r), np.cos(heading), np.sin(heading), _clip_columns
    )
    out = np.empty((len(s), OBS_DIM), np.float32) if out is None else out
    for j, column in enumerate(values):
        out[:, j] = column
    out[:, OBS_DIM - ACTION_DIM :] = previous_action
    return out


def observation_values(rot, position_error, velocity_error, rates, c, s, clip) -> tuple:
    """The contract's first 18 inputs (all but the previous action), written once for plain floats and
    for a batch's columns alike: rotation entries `rot` (body FLU → ENU, `frames.rotation_entries`),
    the position and velocity errors (vehicle minus setpoint, ENU), the body rates (FLU), c and s the
    cosine and sine of the setpoint's ENU yaw, `clip(v, limit)` the clip to ±limit that suits the
    numbers. The errors turned into the setpoint-yaw frame (Rz(−ψ)·e) and clipped, the attitude
    Rz(−ψ)·R (`observation.heading_turned`), the rates."""
    ex, ey, ez = position_error
    wx, wy, wz = velocity_error
    pe, ve = MAX_POSITION_ERROR_M, MAX_VELOCITY_ERROR_M_S
    return (
        clip(c * ex + s * ey, pe),
        clip(-s * ex + c * ey, pe),
        clip(ez, pe),
        *heading_turned(rot, c, s),
        clip(c * wx + s * wy, ve),
        clip(-s * wx + c * wy, ve),
        clip(wz, ve),
        *rates,
    )


def _clip(v: float, limit: float) -> float:
    return limit if v > limit else -limit if v < -limit else v


def _clip_columns(v: np.ndarray, limit: float) -> np.ndarray:
    """`_clip` on an array. Clipped in float64 before the rounding to float32: as ±limit are float32
    numbers and rounding keeps order, the same float32 as clipping after it."""
    return np.clip(v, -limit, limit)


def _qrot(q) -> tuple[tuple[float, float, float], ...]:
    """Rotation matrix (rows) of a unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def observation_ned(
    position_ned,
    velocity_ned,
    q_frd_ned,
    gyro_frd,
    sp_position_ned,
    sp_velocity_ned,
    sp_yaw_ned: float,
    previous_action=(RESET_PREVIOUS_ACTION,) * ACTION_DIM,
) -> np.ndarray:
    """The same 22 inputs from PX4's topics: vehicle_local_position (x, y, z, vx, vy, vz NED),
    vehicle_attitude.q (body FRD → NED, w x y z), vehicle_angular_velocity.xyz (FRD),
    trajectory_setpoint (position, velocity NED, yaw: NED, 0 = north, clockwise seen from above), and
    the previous action. Turned into our frames and observed as `observation` observes
    (`observation_values`): world NED → ENU swaps x and y and negates z (E), body FRD → FLU negates y
    and z (F), the attitude R_ENU←FLU = E·R_NED←FRD·F, the setpoint yaw `heading_from_ned_yaw`."""
    rot = swap_frames_entries(_qrot(tuple(float(v) for v in q_frd_ned)))

    def enu(v, sp) -> tuple[float, float, float]:  # v − sp, NED → ENU
        return float(v[1]) - float(sp[1]), float(v[0]) - float(sp[0]), float(sp[2]) - float(v[2])

    gx, gy, gz = (float(v) for v in gyro_frd)
    heading = heading_from_ned_yaw(sp_yaw_ned)
    values = observation_values(
        rot,
        enu(position_ned, sp_position_ned),
        enu(velocity_ned, sp_velocity_ned),
        (gx, -gy, -gz),
        math.cos(heading),
        math.sin(heading),
        _clip,
    )
    return np.array([*values, *(float(a) for a in previous_action)], np.float32)


def motor_commands(action, order=MOTOR_FROM_POLICY) -> np.ndarray:
    """The policy's 4 outputs (Crazyflie order, clamped to [−1, 1] as the executor does) → the 4
    motor commands in [0, 1] mc_raptor writes to actuator_motors, PX4 quad-X order: (a + 1)/2.
    `order`: output i takes policy output order[i] (`policy_order` of another rotor numbering)."""
    return _commands(_clamped(np.asarray(action, np.float32).reshape(ACTION_DIM)), np.asarray(order))


_ONE, _TWO = np.float32(1.0), np.float32(2.0)
_LOW, _HIGH = np.full(ACTION_DIM, -1.0, np.float32), np.full(ACTION_DIM, 1.0, np.float32)
_ORDER = np.array(MOTOR_FROM_POLICY)
_POLICY_CORNERS = ((True, True), (False, True), (False, False), (True, False))
"""The policy's motors, Crazyflie order, as (forward, right) in body FRD: front-right, back-right,
back-left, front-left."""
_PX4_SPIN = {(True, True): "ccw", (False, False): "ccw", (True, False): "cw", (False, True): "cw"}
"""PX4 quad-X's spin directions by corner (4001_quad_x: front-right and back-left CCW), the ones
mc_raptor's fixed remap assumes."""


def policy_order(vehicle) -> tuple[int, ...]:
    """For a vehicle's rotors (output order, `VehicleParams.rotors`, None: PX4's quad-X), the policy
    output each output takes: mc_raptor's remap (`MOTOR_FROM_POLICY`) for PX4's quad-X numbering, the
    same corners for any other numbering of a quad-X (RotorPy's Hummingbird numbers them front-left
    first). ValueError, one line, for a frame whose rotors are not one per corner with PX4's spins:
    the policy cannot fly it."""
    rotors = getattr(vehicle, "rotors", None)
    if rotors is None:
        return MOTOR_FROM_POLICY
    corners = [(r.x > 0, r.y > 0) for r in rotors]
    if len(rotors) != ACTION_DIM or any(r.x == 0 or r.y == 0 for r in rotors) or len(set(corners)) != ACTION_DIM:
        raise ValueError(
            f"vehicle {getattr(vehicle, 'name', '?')!r}: the px4-raptor contract flies a quad-X, one rotor per "
            "corner; this frame is not one"
        )
    for r, corner in zip(rotors, corners, strict=True):
        if r.spin != _PX4_SPIN[corner]:
            raise ValueError(
                f"vehicle {getattr(vehicle, 'name', '?')!r}: the rotor at x={r.x:g}, y={r.y:g} spins {r.spin}; the "
                f"px4-raptor contract needs PX4 quad-X's spins (front-right and back-left ccw)"
            )
    return tuple(_POLICY_CORNERS.index(c) for c in corners)


def _clamped(a: np.ndarray) -> np.ndarray:
    """float32 (4,) clamped to [−1, 1], a new array (np.minimum/np.maximum: np.clip costs several
    times more on 4 values)."""
    return np.minimum(np.maximum(a, _LOW), _HIGH)


def _commands(clamped: np.ndarray, order: np.ndarray = _ORDER) -> np.ndarray:
    out = clamped[order]
    out += _ONE
    out /= _TWO
    return out


def heading_from_ned_yaw(yaw_ned: float) -> float:
    """A trajectory_setpoint yaw (NED) as our heading (ENU yaw): π/2 − ψ_NED, wrapped to (−π, π]."""
    return math.remainder(math.pi / 2 - float(yaw_ned), 2 * math.pi)


def force_sync_native(gyro_rate_hz: float) -> int:
    """Calls per native (100 Hz) step at this gyro rate: IMU_GYRO_RATEMAX / 100 in integers, as
    `Raptor::init` sets it (0 below 100 Hz: then every call is native, as the executor's time rule
    at 10 ms or more per call makes it)."""
    return round(gyro_rate_hz) // TRAINING_RATE_HZ


Step = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""A recurrent policy step: (observation (22,) float32, state) → (raw action (4,), new state)."""


class Executor:
    """mc_raptor's use of RLtools' inference executor for one vehicle: which calls advance the
    policy's recurrent state, and the previous-action input.

        ex = Executor(step, initial_state, force_sync=2)   # 250 Hz gyro
        ex.reset()                                         # Raptor::reset
        obs = observation(state, target, None, heading, ex.previous_action_input())
        motors = ex.control(obs)                           # PX4 quad-X commands in [0, 1]

    `control` is `rl_tools::control` followed by `Raptor::Run`'s output: on a native call (every
    `force_sync`-th, counted from the reset; every call when force_sync is 0 or 1) the state
    advances; otherwise the policy runs on a copy. The raw action is clamped to [−1, 1] and kept as
    the previous action."""

    def __init__(self, step: Step, initial_state: np.ndarray, force_sync: int = 1, order=MOTOR_FROM_POLICY) -> None:
        self.step = step
        self.order = np.asarray(order)
        """Output i of `control` takes policy output order[i] (`policy_order`)."""
        self.initial_state = np.asarray(initial_state, np.float32)
        self.force_sync = int(force_sync)
        self.reset()

    def reset(self) -> None:
        self.state = self.initial_state.copy()
        self.previous_action = np.full(ACTION_DIM, RESET_PREVIOUS_ACTION, np.float32)
        self.history = self.previous_action.copy()  # L2F's action_history[0]
        self.since_native = 0  # L2F's steps_since_original_control_step
        self.calls = 0  # the executor's intermediate_step
        self.last_native = True

    def previous_action_input(self) -> np.ndarray:
        """The prev_action this call's observation carries: the previous action on the call after a
        native one (and after a reset), else the running mean of the previous actions since
        (L2F `control`: action_history[0])."""
        k = self.since_native
        if k == 0:
            return self.previous_action.copy()
        return ((self.history * np.float32(k) + self.previous_action) / np.float32(k + 1)).astype(np.float32)

    def control(self, obs: np.ndarray) -> np.ndarray:
        """One call (one gyro update): the policy on `obs` (whose prev_action must be
        `previous_action_input()`), the state advanced on native calls; returns the motor commands."""
        obs = np.asarray(obs, np.float32)
        self.history = obs[OBS_DIM - ACTION_DIM :].copy()
        native = self.force_sync <= 1 or self.calls % self.force_sync == 0
        action, new_state = self.step(obs, self.state)
        if native:
            self.state = new_state
        self.calls += 1
        self.since_native = 0 if native else self.since_native + 1
        self.last_native = native
        self.previous_action = _clamped(np.asarray(action, np.float32))
        return _commands(self.previous_action, self.order)


def fallback_observation(obs: np.ndarray) -> np.ndarray:
    """A px4-raptor observation as the version-2 hover layout's 18 values (`core.observation`:
    position error and velocity in the body frame, attitude relative to the commanded heading,
    rates), for the classical fallback: with Rh = Rz(−ψ)·R, a body vector is Rhᵀ·(heading-frame
    vector). The errors stay clipped as the policy saw them."""
    o = np.asarray(obs, np.float64)
    rh = o[3:12].reshape(3, 3)
    return np.concatenate([rh.T @ o[0:3], rh.T @ o[12:15], o[3:12], o[15:18]]).astype(np.float32)
