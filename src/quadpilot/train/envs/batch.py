"""`QuadBatch`: N drones of one task stepped together, the engine under `envs.QuadEnv` and
`envs.QuadVectorEnv` (and `evaluate`, the studies, the export's parity data).

It samples initial states, steps the `core` dynamics, builds observations with `core`'s
`ObservationBuilder` and computes rewards and terminations with `core.reward.StepTerms`, all in
place: a step allocates no array. Terminated (crash, leaving the flight area) and truncated (time
limit) are kept apart everywhere.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from quadpilot.core import dynamics
from quadpilot.core.mission import window_success, wrap_angle
from quadpilot.core.observation import ObservationBuilder
from quadpilot.core.params import ParamBatch
from quadpilot.core.randomization import Randomizer
from quadpilot.core.reward import StepTerms, circle_errors
from quadpilot.core.sensor_noise import SensorNoiseState
from quadpilot.core.start import sample_ball, sample_start_states
from quadpilot.core.state import STATE_DIM, YAW
from quadpilot.core.timing import DelayLine

try:  # the ufunc np.clip calls, without np.clip's dispatch (a microsecond a call); the same values
    from numpy._core.umath import clip as _clip
except ImportError:  # pragma: no cover - a NumPy that moved it
    _clip = np.clip


class _Rows:
    """An (N, k) array that a batch keeps as rows (k, N), the layout its step computes on.

    `rows` is where the step works. `get()` hands out the (N, k) array; after a step it is a new
    array (as when the step made new arrays), so an array taken before a step keeps that step's
    inputs. `set(value)` puts in an array as an attribute assignment does. An array handed out or
    put in may be written by its holder (`batch.state[:] = ...`), so `sync()` copies it back into the
    rows before they are next used; a loop that never asks for the array (the vector environment)
    never transposes."""

    def __init__(self, rows: np.ndarray) -> None:
        self.rows = rows
        self.array = np.ascontiguousarray(rows.T)
        self.stale = False  # the rows are newer than `array`
        self.lent = False  # `array` was handed out or put in since the rows last took it in

    def get(self) -> np.ndarray:
        if self.stale:
            self.array = np.ascontiguousarray(self.rows.T)
            self.stale = False
        self.lent = True
        return self.array

    def set(self, value: np.ndarray) -> None:
        self.array = value
        self.stale = False
        self.lent = True

    def sync(self) -> np.ndarray:
        """The rows, with any change made through the (N, k) array taken in."""
        if self.lent:
            np.copyto(self.rows, self.array.T)
            self.lent = False
        return self.rows

    def set_rows(self, idx: np.ndarray, values) -> None:
        """rows[:, idx] = values.T (values (k, K) or broadcasting to it), and the (N, k) array too
        unless a step has made it out of date (a reset writes into the array it has, as it always did)."""
        self.sync()
        values = np.asarray(values)
        self.rows[:, idx] = values.T if values.ndim == 2 else values
        if not self.stale:
            self.array[idx] = values


class QuadBatch:
    """N drones of one task: state, targets, episode bookkeeping. Pure NumPy, no Python loop
    over drones. `reset(mask, rng)` re-samples the selected drones; `step(action)` advances all.

    A step allocates no array: the state and rotor speeds are kept as rows (12, N) and (M, N) and
    advanced in place (`core.dynamics.Stepper`), the observation is written into `obs`
    (`core.observation.ObservationBuilder`), and the reward and termination terms land in arrays
    made once (`core.reward.StepTerms`). Each computes what `core.dynamics.step`,
    `core.observation.build_observation` and `core.reward` compute, bit for bit
    (tests/core/test_inplace_equivalence.py compares them with the allocating code on any machine;
    tests/train/test_env_bit_identity.py pinned the outputs of the allocating code this replaced,
    and pins today's since deliberate changes of the dynamics; tests/train/test_env_allocation.py
    holds the step to no allocation). Two options still allocate
    per step: sensor noise (NumPy buffers the (N, 15) and (N, 27) updates of
    `SensorNoiseState.step`) and domain randomisation (a new ParamBatch, and pushes' forces, from
    `core.randomization`). A reset draws its drones' new episodes in arrays of their number.
    `state`, `rotor` and `target` read and write as (N, 12), (N, M) and (N, 3) arrays (`_Rows`); the
    target is kept as rows (3, N) so that the reward's and the observation's position errors are one
    subtraction over contiguous rows each.

    `QuadVectorEnv` steps through `step_autoreset`, which also resets the drones whose episode
    ended and builds every observation of the step in one go."""

    def __init__(self, cfg: Any, n: int, params: ParamBatch | None = None) -> None:
        """cfg: an `envs.EnvConfig` (not imported here: envs imports this module); n drones;
        params: their plant (None: n copies of the configuration's vehicle)."""
        self.cfg, self.n = cfg, n
        self.dtype = np.dtype(cfg.dtype)
        self.nominal = cfg.params
        self.params = (params or ParamBatch.from_preset(self.nominal, n)).astype(self.dtype)
        if self.params.n != n:
            raise ValueError(f"params hold {self.params.n} drones, expected {n}")
        m = self.params.n_rotors
        self.u_hover = self.dtype.type(self.nominal.hover_command)
        self.home = np.asarray(cfg.home, dtype=self.dtype)
        self.target_radius = cfg.target_radius
        self._state = _Rows(np.zeros((STATE_DIM, n), self.dtype))
        self._rotor = _Rows(np.full((m, n), self.u_hover, self.dtype))
        self._target = _Rows(np.ascontiguousarray(np.tile(self.home, (n, 1)).T))
        self._homes = np.tile(self.home, (n, 1))  # start points of a reset, never written
        self.target_vel = np.zeros((n, 3), self.dtype)
        self.phase = np.zeros(n)  # circle: angle of the target point at t = 0
        self.steps = np.zeros(n, np.int64)
        self.ep_return = np.zeros(n)
        self.err_sum = np.zeros(n)  # position error summed over the success window
        self.heading = np.zeros(n, self.dtype)  # rad, the commanded heading (start yaw + offset)
        self.yaw_rate_sum = np.zeros(n)  # |yaw rate| summed over the success window, rad/s
        self.heading_err_sum = np.zeros(n)  # |heading error| summed over the success window, rad
        self.obs = np.zeros((n, cfg.layout.dim), np.float32)
        self._omega = cfg.circle_speed / cfg.circle_radius
        self.noise_spec = cfg.noise
        self.noise: SensorNoiseState | None = None  # built at the first reset, from its rng
        # domain randomisation: plant parameters and disturbances redrawn per reset
        self.randomizer = (
            Randomizer(cfg.randomization, self.nominal, n, cfg.dt, self.dtype) if cfg.randomization else None
        )
        # the loop's timing: commands and states delayed per drone (None: none, as before it existed)
        timing = cfg.timing if cfg.timing is not None and cfg.timing.active else None
        self.delay = DelayLine(timing, n, m, STATE_DIM, cfg.dt, self.dtype) if timing is not None else None
        if self.randomizer is not None and cfg.randomization.airframes:
            # a drawn airframe per drone: the motor map uses the hover command of each drone's own
            # vehicle file, (N,) against the commands' (M, N) rows, kept up to date by the randomizer
            self.u_hover = self.randomizer.u_hover
        # what a step computes in, allocated once
        self._stepper = dynamics.Stepper(n, m, self.dtype)
        self._observer = ObservationBuilder(2 * n, self.dtype)
        self._reset_observer = ObservationBuilder(n, self.dtype)  # keeps `_observer`'s arrays for the next step
        self._terms = StepTerms(n, self.dtype)
        # Without sensor noise the observation is built from the true state, so `_observer` holds the
        # sines, cosines and thrust direction of the state the next step starts from, which the
        # dynamics computes first (the same operations on the same numbers): handed over while valid
        # (a reset refreshes its drones' columns; a state written through `state` makes it invalid).
        self._trig_valid = False
        self._trig: tuple = ()
        self._command = np.empty((m, n), self.dtype)
        # `step_autoreset` builds the observations of n + k states, everyone's after the reset and
        # the last ones of the k drones that ended, from (12, n + k) rows laid on flat storage (a
        # contiguous block whatever k is)
        self._ext_state = np.zeros(STATE_DIM * 2 * n, self.dtype)
        self._estimate = np.zeros(STATE_DIM * 2 * n, self.dtype)  # rows of the noisy state estimate
        self._ext_target = np.zeros(3 * 2 * n, self.dtype)  # (3, n + k) target rows
        self._ext_target_vel = np.zeros((2 * n, 3), self.dtype)
        self._ext_heading = np.zeros(2 * n, self.dtype)
        self._ext_cache: dict = {}
        self._wide = np.empty((3, n))  # float64 rows: the reward, error and yaw errors widened for the sums
        self._wide_rows = tuple(self._wide)
        self._window_from = cfg.episode_steps - cfg.success_steps  # the success window: steps past this
        self._window, self._truncated, self._alive, self._done = np.empty((4, n), bool)
        self._one = self.dtype.type(1.0)
        self._heading_offset = np.radians(cfg.heading_offset_deg)  # rad, the widest commanded offset
        self._angle, self._cos, self._sin, self._tmp = np.empty((4, n))  # circle target, float64
        # circle: the target's constant z and vertical speed, as _circle_target computes them
        # (home_z + radius·0 and speed·0, in float64, cast)
        self._circle_z = self.dtype.type(np.float64(self.home[2]) + np.float64(cfg.circle_radius) * 0.0)
        self._circle_vz = self.dtype.type(np.float64(cfg.circle_speed) * 0.0)

    state = property(
        lambda self: self._state.get(),
        lambda self, value: self._state.set(value),
        doc="(N, 12) states, `core.state` layout.",
    )
    rotor = property(
        lambda self: self._rotor.get(),
        lambda self, value: self._rotor.set(value),
        doc="(N, M) normalised rotor speeds.",
    )
    target = property(
        lambda self: self._target.get(),
        lambda self, value: self._target.set(value),
        doc="(N, 3) target positions, m (ENU).",
    )

    @property
    def obs_heading(self) -> np.ndarray | None:
        """The heading the observation is relative to: the commanded one (version 2), else None
        (version 1: the world frame)."""
        return self.heading if self.cfg.obs_version == 2 else None

    # --- targets -------------------------------------------------------------------------
    def _circle_target(self, idx) -> tuple[np.ndarray, np.ndarray]:
        c = self.cfg
        ang = self.phase[idx] + self._omega * c.dt * self.steps[idx]
        ca, sa = np.cos(ang), np.sin(ang)
        pos = self.home + c.circle_radius * np.stack([ca, sa, np.zeros_like(ca)], axis=1)
        vel = c.circle_speed * np.stack([-sa, ca, np.zeros_like(ca)], axis=1)
        return pos.astype(self.dtype), vel.astype(self.dtype)

    def _circle_target_all(self) -> None:
        """`_circle_target` of every drone, into `target` and `target_vel`: the same float64
        operations in the same order, cast to the state dtype."""
        c = self.cfg
        ang, ca, sa, tmp = self._angle, self._cos, self._sin, self._tmp
        np.copyto(ang, self.steps)  # phase + ω·dt·steps (steps made float64 as the product makes them)
        np.multiply(ang, self._omega * c.dt, out=ang)
        np.add(self.phase, ang, out=ang)
        np.cos(ang, out=ca)
        np.sin(ang, out=sa)
        target = self._target.sync()  # written whole here, as rows
        for j, v in enumerate((ca, sa)):  # home + radius·(cos, sin, 0)
            np.multiply(c.circle_radius, v, out=tmp)
            np.add(self.home[j], tmp, out=tmp)
            np.copyto(target[j], tmp, casting="same_kind")
        target[2] = self._circle_z
        self._target.stale = True
        np.negative(sa, out=tmp)  # speed·(−sin, cos, 0)
        np.multiply(c.circle_speed, tmp, out=tmp)
        np.copyto(self.target_vel[:, 0], tmp, casting="same_kind")
        np.multiply(c.circle_speed, ca, out=tmp)
        np.copyto(self.target_vel[:, 1], tmp, casting="same_kind")
        self.target_vel[:, 2] = self._circle_vz

    # --- API -----------------------------------------------------------------------------
    def reset(self, mask: np.ndarray, rng: np.random.Generator, observe: bool = True) -> None:
        """Re-sample the drones of `mask` (a new episode each) from `rng`, and build their
        observations into `obs` (observe=False leaves that to the caller: `step_autoreset`)."""
        self._reset(np.flatnonzero(mask), rng, observe)

    def _reset(self, idx: np.ndarray, rng: np.random.Generator, observe: bool) -> None:
        """`reset` of the drones `idx` (ascending indices, as np.flatnonzero gives them)."""
        k = idx.size
        if k == 0:
            return
        c = self.cfg
        start = self._homes[:k]  # np.tile(home, (k, 1))
        if c.task == "waypoint":
            self._target.set_rows(idx, self.home + sample_ball(rng, k, self.target_radius))
        elif c.task == "circle":
            self.phase[idx] = rng.uniform(-np.pi, np.pi, k)
            self.steps[idx] = 0
            start, self.target_vel[idx] = self._circle_target(idx)
            self._target.set_rows(idx, start)
        starts = sample_start_states(rng, start, c.init_pos_radius, c.init_vel, c.init_tilt_deg, c.init_rate)
        starts = starts.astype(self.dtype)
        self._sync_state()
        self._state.set_rows(idx, starts)
        # the commanded heading, drawn next to the start state (before any plant draw, so that a
        # randomised and a plain batch from one seed start alike), from the start yaw as the state holds it
        offset = rng.uniform(-1.0, 1.0, k) * self._heading_offset if c.heading_offset_deg else 0.0
        self.heading[idx] = wrap_angle(starts[:, YAW] + offset)
        if self.randomizer is not None:  # a new ParamBatch (dynamics re-derives its constants)
            self.params = self.randomizer.resample(self.params, idx, rng, c.episode_steps)
        u_hover = self.u_hover if np.ndim(self.u_hover) == 0 else self.u_hover[idx][:, None]
        if c.init_rotor == "hover":
            self._rotor.set_rows(idx, u_hover)
        elif c.init_rotor == "rest":
            self._rotor.set_rows(idx, self.dtype.type(0.0))
        else:  # "random": drawn only with this option, so the default draws what it always drew
            speeds = (np.reshape(u_hover, -1) * rng.random(k)).astype(self.dtype)
            self._rotor.set_rows(idx, np.broadcast_to(speeds[:, None], (k, self._rotor.rows.shape[0])))
        self.steps[idx] = 0
        self.ep_return[idx] = 0.0
        self.err_sum[idx] = 0.0
        self.yaw_rate_sum[idx] = 0.0
        self.heading_err_sum[idx] = 0.0
        if self.noise_spec is not None:  # the noise stream continues from a seed drawn here
            seed = int(rng.integers(2**63))
            if self.noise is None:
                self.noise = SensorNoiseState(self.noise_spec, self.n, c.dt, np.random.default_rng(seed))
            else:
                self.noise.rng = np.random.default_rng(seed)
            self.noise.reset(idx)
        if self.delay is not None:  # drawn last, so that the draws above are what they were without it
            self.delay.reset(idx, rng, self._rotor.rows[:, idx], self._state.rows[:, idx])
        if not observe:  # the caller builds every observation, and with them the trigonometry
            self._trig_valid = False
            return
        true = self._state.rows[:, idx]  # (12, k)
        sensed = true if self.noise is None else np.ascontiguousarray(self.noise.estimate(true.T, idx).T)
        ob = self._reset_observer
        obs = np.empty((k, self.obs.shape[1]), np.float32)
        ob.build(
            sensed,
            None,
            obs,
            self.target_vel[idx] if c.task == "circle" else None,
            heading=None if self.obs_heading is None else self.obs_heading[idx],
            target_rows=self._target.sync()[:, idx],
        )
        self.obs[idx] = obs
        if self._trig_valid:  # the reset drones' columns, from their new state
            for rows, new in zip(self._trig, (ob.last.sin, ob.last.cos, ob.last.rot[:, 2]), strict=True):
                for row, value in zip(rows, new, strict=True):
                    row[idx] = value

    def step(
        self,
        action: np.ndarray,
        commands: bool = False,
        force: np.ndarray | None = None,
        torque: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Advance all drones one control step. action (N, M) in [−1, 1].
        Returns (obs, reward, terminated, truncated, pos_error_norm): `obs` is the batch's own
        array, the others are arrays the batch reuses, overwritten by the next step (copy what
        must outlive it).

        For a controller that is not a policy (`studies.robustness`): commands=True takes `action`
        as rotor commands ω/ω_max, held as they are (the plant clips them to [ω_min/ω_max, 1]);
        force (N, 3), N world ENU, and torque (N, 3), N·m body FLU, in the state dtype, are added
        for this step to the randomisation's external force and moment."""
        self._advance(action, commands, force, torque)
        circle = self.cfg.task == "circle"
        s = self._seen_rows()
        sensed = s if self.noise is None else self.noise.estimate_rows(s, self._estimate_rows(self.n))
        self._observe(sensed, self._target.rows, self.obs, self.target_vel if circle else None, self.obs_heading)
        # without noise or delay the observation's position error is the true one
        exact = self.noise is None and self.delay is None
        t, truncated = self._finish(self._observer.last.vec if exact else None, norms=True)
        return self.obs, t.reward, t.crash, truncated, t.err

    def _observe(self, sensed, target_rows, out, target_vel, heading) -> None:
        """The observations of the states whose rows are `sensed` (`ObservationBuilder`), their
        targets' rows `target_rows`; the first n are the batch's drones now, whose trigonometry the
        next step can take when it is of the true state."""
        ob = self._observer
        ob.build(sensed, None, out, target_vel, heading=heading, target_rows=target_rows)
        self._trig = ob.last.trig(self.n)
        self._trig_valid = self.noise is None and self.delay is None  # the state the next step starts from

    def _seen_rows(self) -> np.ndarray:
        """The state rows the observation is built from: the state now, or without delay the state
        as old as each drone's observation delay (`core.timing.DelayLine.observed`)."""
        s = self._state.rows
        return s if self.delay is None else self.delay.observed(s)

    def _ext_rows(self, k: int) -> np.ndarray:
        return self._ext_views(k)[0]

    def _ext_target_rows(self, k: int) -> np.ndarray:
        return self._ext_views(k)[2]

    def _estimate_rows(self, k: int) -> np.ndarray:
        return self._ext_views(k)[1]

    def _ext_views(self, k: int) -> tuple:
        """(state rows (12, k), estimate rows (12, k), target rows (3, k)) on the flat storage, the
        same view objects for the same k (the observation builder keeps its views of a state array)."""
        views = self._ext_cache.get(k)
        if views is None:
            if len(self._ext_cache) >= 256:
                self._ext_cache.clear()
            views = self._ext_cache[k] = (
                self._ext_state[: STATE_DIM * k].reshape(STATE_DIM, k),
                self._estimate[: STATE_DIM * k].reshape(STATE_DIM, k),
                self._ext_target[: 3 * k].reshape(3, k),
            )
        return views

    def step_autoreset(self, action: np.ndarray, rng: np.random.Generator) -> tuple:
        """`step`, then `reset` of the drones whose episode ended, as `QuadVectorEnv` does, with one
        observation build for both: the last observations of the ended episodes are built next to
        everyone's observation after the reset (the same numbers: a reset changes only its drones).
        Returns (reward, terminated, truncated, done, ended), the first three the batch's arrays;
        `done` and `ended` None if no episode ended, else new arrays: done (N,) bool, and ended
        (final_obs (N, dim): `obs` before the reset, ep_return, steps and `success` of that moment)."""
        self._advance(action)
        t, truncated = self._finish(None, norms=False)  # the error norm is not returned here
        done = np.logical_or(t.crash, truncated, self._done)
        n, c = self.n, self.cfg
        circle, head = c.task == "circle", self.obs_heading is not None
        s = self._state.rows
        seen = self._seen_rows()
        if not np.count_nonzero(done):  # (done.any(), at half the cost)
            s = seen
            sensed = s if self.noise is None else self.noise.estimate_rows(s, self._estimate_rows(n))
            self._observe(sensed, self._target.rows, self.obs, self.target_vel if circle else None, self.obs_heading)
            return t.reward, t.crash, truncated, None, None
        done = done.copy()
        # `truncated` is already "and not crashed": the episodes that ended well (`success`)
        ended = (self.ep_return.copy(), self.steps.copy(), self._success(truncated))
        idx = done.nonzero()[0]  # np.flatnonzero(done); the reset below takes these too
        k = idx.size
        # columns n .. n + k − 1: the ended drones as they ended (state, estimate, target, heading)
        ext, est, target = self._ext_views(n + k)
        ext[:, n:] = seen[:, idx]
        if self.noise is not None:
            est[:, n:] = self.noise.estimate(ext[:, n:].T, idx).T
        target_vel, heading = self._ext_target_vel, self._ext_heading
        target[:, n:] = self._target.rows[:, idx]
        if circle:
            target_vel[n : n + k] = self.target_vel[idx]
        if head:
            heading[n : n + k] = self.heading[idx]
        self._reset(idx, rng, observe=False)
        # columns 0 .. n − 1: every drone after the reset
        np.copyto(target[:, :n], self._target.rows)
        if circle:
            np.copyto(target_vel[:n], self.target_vel)
        if head:
            np.copyto(heading[:n], self.heading)
        if seen is not s:  # the drones just reset are seen at their start
            seen[:, idx] = s[:, idx]
        np.copyto(ext[:, :n], seen)
        if self.noise is None:
            sensed = ext
        else:
            self.noise.estimate_rows(seen, est[:, :n])
            sensed = est
        last = np.empty((k, self.obs.shape[1]), np.float32)
        self._observe(
            sensed,
            target,
            (self.obs, last),
            target_vel[: n + k] if circle else None,
            heading[: n + k] if head else None,
        )
        final_obs = self.obs.copy()
        final_obs[idx] = last
        return t.reward, t.crash, truncated, done, (final_obs, *ended)

    def _advance(self, action: np.ndarray, commands: bool = False, force=None, torque=None) -> None:
        """The part of a step before the observation: actions to rotor commands, the plant, the step
        count, the circle's target, the sensor noise processes (`step` for the arguments)."""
        c = self.cfg
        s, w, u = self._sync_state(), self._rotor.sync(), self._command
        self._target.sync()  # what was written through `target`, for the reward and the observation
        action = np.asarray(action)
        if action.shape != (self.n, u.shape[0]):
            raise ValueError(f"action must have shape ({self.n}, {u.shape[0]}), got {action.shape}")
        # dynamics.action_to_command: clip to [−1, 1], u_hover·√(1 + a), clip to [0, 1]
        np.copyto(u, action.T, casting="unsafe")  # cast first, as np.asarray(action, dtype) does
        if not commands:
            _clip(u, -1.0, 1.0, u)
            np.add(u, self._one, u)
            np.sqrt(u, u)
            np.multiply(self.u_hover, u, u)
        # the last clip to [0, 1] is the Stepper's to [u_min, 1]: clip(clip(x, 0, 1), u_min, 1) is
        # clip(x, u_min, 1) for 0 ≤ u_min < 1, the same bits
        if self.delay is not None:  # what reaches the rotors: the commands sent earlier
            np.copyto(u, self.delay.command(u))
        if self.randomizer is not None:
            f, t = self.randomizer.external(self.steps)
            force, torque = _plus(f, force), _plus(t, torque)
        trig = self._trig if self._trig_valid else None
        self._stepper.step(s, w, u, self.params, c.dt, c.substeps, force=force, torque=torque, trig=trig)
        self._state.stale = self._rotor.stale = True
        self._trig_valid = False
        self.steps += 1
        if c.task == "circle":
            self._circle_target_all()
        if self.noise is not None:
            self.noise.step()

    def _finish(self, pos_err: np.ndarray | None, norms: bool) -> tuple[StepTerms, np.ndarray]:
        """Reward and termination of the step (`core.reward.StepTerms`), the episode sums, truncation.
        norms: the caller needs the position error's norm (`StepTerms.err`); the sums need it (and
        |yaw rate|) only while a drone's success window is open."""
        c, t = self.cfg, self._terms
        window = self._window
        np.greater(self.steps, self._window_from, window)
        summing = np.count_nonzero(window) > 0
        t.compute(
            self._state.rows,
            None,
            self.heading,
            c.reward,
            pay_heading=c.obs_version == 2,  # version 1: no heading term in the reward
            circle=(self.home, c.circle_radius, c.circle_speed) if c.task == "circle" else None,
            pos_err=pos_err,
            target_rows=self._target.rows,
            norms=norms or summing,
        )
        # the float64 sums take the step's numbers widened first (exactly, by a copy: NumPy would
        # otherwise allocate a buffer to cast them in)
        wide, wide_value, _ = self._wide_rows
        np.copyto(wide, t.reward)
        np.add(self.ep_return, wide, self.ep_return)
        if summing:  # (an addition of 0 where the window is closed leaves the sums as they are)
            for total, value in ((self.err_sum, t.err), (self.yaw_rate_sum, t.rate), (self.heading_err_sum, t.head)):
                np.copyto(wide_value, value)
                np.add(total, wide_value, total, where=window)  # += where(window, value, 0)
        truncated = self._truncated  # (steps ≥ episode_steps) & ~crash
        np.greater_equal(self.steps, c.episode_steps, truncated)
        np.logical_not(t.crash, self._alive)
        np.logical_and(truncated, self._alive, truncated)
        return t, truncated

    def _sync_state(self) -> np.ndarray:
        """The state rows, with what was written through `state` taken in (which makes the
        observation's trigonometry of the state out of date)."""
        if self._state.lent:
            self._trig_valid = False
        return self._state.sync()

    def sensed(self, idx=None) -> np.ndarray:
        """The 12-states the observation is built from: the true state (the array itself) without
        sensor noise, else the noisy estimate of drones `idx` (None: all)."""
        if self.noise is None:
            return self.state if idx is None else self.state[idx]
        return self.noise.estimate(self.state if idx is None else self.state[idx], idx)

    def success(self, terminated: np.ndarray, truncated: np.ndarray) -> np.ndarray:
        """(N,) bool: ended by the time limit with mean error over the window within tolerance and
        the start heading held (`core.mission.window_success`, the rule SITL judges by)."""
        return self._success(truncated & ~terminated)

    def _success(self, ended_well: np.ndarray) -> np.ndarray:
        """`success` of the drones whose episode ended well (ended_well (N,) bool)."""
        out = np.zeros(ended_well.shape, bool)  # the rule is false wherever the episode did not end well
        if not np.count_nonzero(ended_well):  # (most steps: no episode reached its time limit)
            return out
        k = self.cfg.success_steps
        idx = np.flatnonzero(ended_well)  # so it is judged where it did (the same numbers: elementwise, by drone)
        means = (self.err_sum[idx] / k, self.yaw_rate_sum[idx] / k, self.heading_err_sum[idx] / k)
        out[idx] = window_success(True, *means, self.cfg.success_tolerance)
        return out

    def circle_metrics(self) -> tuple[np.ndarray, np.ndarray]:
        """(radius error, tangential-speed error), each (N,), for the circle task."""
        return circle_errors(self.state, self.home, self.cfg.circle_radius, self.cfg.circle_speed)


def _plus(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    """a + b, where None is nothing to add."""
    return b if a is None else a if b is None else a + b
