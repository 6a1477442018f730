"""Reward and termination maths, pure and batched over a leading drone axis.

Shapes follow the course brief: a large penalty on a crash (altitude < 0 or |roll|, |pitch| > 60°), a
Gaussian reward on position error, a small penalty on angular rate. Circle adds the ENPM 667 project's radius
and tangential-speed errors. Every per-step reward is bounded above by the sum of its Gaussians' weights.
A heading term (a Gaussian on the heading error and a yaw-rate penalty) is added where the caller
gives the heading error: a hover holds its heading too.

Why Gaussian and not a linear distance penalty: with a linear penalty and an alive bonus, a drone
far from the target earns less by staying alive than by crashing, and learns to crash on purpose;
with a positive bounded reward every step alive is worth something. Measured on hover: adding
velocity and tilt penalties on top slowed learning (error 0.20 m against 0.08 m at 1.2 M steps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .state import PITCH, POS, RATES, ROLL, ROLL_PITCH, VX, VY, YAW, R, X, Y, Z


@dataclass(frozen=True)
class RewardConfig:
    pos_coarse_weight: float = 0.5
    """Weight of the wide Gaussian on position error; it pulls from up to a few metres away."""
    pos_coarse_sigma: float = 1.0
    """m, width of the wide Gaussian exp(−d²/σ²). Measured on hover: σ = 0.5 m gave almost no
    signal from 1 m starts and drones drifted out of the flight area."""
    pos_fine_weight: float = 1.0
    """Weight of the narrow Gaussian on position error; it pays for the last centimetres. Measured
    on hover: weight 1.0 ended at 1.5 cm mean error where 0.5 ended at 3.5 cm (one seed, 1 M steps)."""
    pos_fine_sigma: float = 0.1
    """m, width of the narrow Gaussian."""
    rate_weight: float = 0.01
    """Penalty per (rad/s)² of body rate, |ω|²."""
    tilt_soft_deg: float = 40.0
    """deg, roll or pitch beyond this is penalised (see `tilt_weight`); well above what hovering
    and the circle need (< 25°), below the 60° crash limit."""
    tilt_weight: float = 0.0
    """Penalty per rad² of |roll| or |pitch| beyond `tilt_soft_deg` (the larger of the two); 0 is
    off. The waypoint task defaults to 50 (`envs.make_config`). Measured on waypoint at 2 m (400
    episodes): without it the policy raced to far targets at up to 57° and crossed the 60° crash
    limit in 4–4.5 % of episodes; 5 beyond 45°: 2.5 %; 50 beyond 40°: 0.5 %. On hover, where it is
    never needed, 50 slowed learning (95 % success at 0.82 M steps instead of 0.49 M, one seed)."""
    heading_weight: float = 0.3
    """Weight of the Gaussian on heading error (yaw minus the commanded heading, wrapped): a hover
    holds its heading too (`core.mission`'s yaw rule). Only where the caller gives a heading error."""
    heading_sigma: float = 0.5
    """rad, width of the heading Gaussian: about 29°, so a start up to the environments' heading
    offset (30°) is still well inside its slope."""
    yaw_rate_weight: float = 0.02
    """Penalty per (rad/s)² of yaw rate r, on top of `rate_weight`'s (only with a heading error)."""
    crash_penalty: float = 10.0
    """Paid once on the step that ends in a crash or leaves the flight area."""
    max_tilt_deg: float = 60.0
    """deg, |roll| or |pitch| above this is a crash (the course brief)."""
    max_distance: float = 5.0
    """m, leaving this distance from the target ends the episode like a crash."""
    radius_weight: float = 0.5
    """Circle: weight of the Gaussian on radius error (the ENPM 667 project's distance error)."""
    radius_sigma: float = 0.1
    """m, circle: width of the radius-error Gaussian."""
    speed_weight: float = 0.5
    """Circle: weight of the Gaussian on tangential-speed error (the ENPM 667 project's velocity error)."""
    speed_sigma: float = 0.2
    """m/s, circle: width of the speed-error Gaussian."""

    @property
    def max_tilt(self) -> float:
        """rad."""
        return math.radians(self.max_tilt_deg)


def gaussian(err_sq: np.ndarray, sigma: float) -> np.ndarray:
    return np.exp(-err_sq / (sigma * sigma))


def crashed(state: np.ndarray, pos_error: np.ndarray, cfg: RewardConfig) -> np.ndarray:
    """(N,) bool: altitude below ground, tilt beyond the limit, or outside the flight area."""
    dist_sq = np.einsum("ij,ij->i", pos_error, pos_error)
    return (
        (state[:, Z] < 0.0)
        | (np.abs(state[:, ROLL]) > cfg.max_tilt)
        | (np.abs(state[:, PITCH]) > cfg.max_tilt)
        | ~(dist_sq <= cfg.max_distance**2)  # NaN counts as out
    )


def hover_reward(
    state: np.ndarray, pos_error: np.ndarray, crash: np.ndarray, cfg: RewardConfig, heading_error=None
) -> np.ndarray:
    """(N,) reward for reaching and holding a point. state (N, 12), pos_error (N, 3), crash (N,);
    heading_error (N,) rad, wrapped: yaw minus the commanded heading (None: no heading to hold, the
    reward of the version-1 policies)."""
    d2 = np.einsum("ij,ij->i", pos_error, pos_error)
    w2 = np.einsum("ij,ij->i", state[:, RATES], state[:, RATES])
    over = np.maximum(
        np.maximum(np.abs(state[:, ROLL]), np.abs(state[:, PITCH])) - math.radians(cfg.tilt_soft_deg), 0.0
    )
    r = (
        cfg.pos_coarse_weight * gaussian(d2, cfg.pos_coarse_sigma)
        + cfg.pos_fine_weight * gaussian(d2, cfg.pos_fine_sigma)
        - cfg.rate_weight * w2
        - cfg.tilt_weight * over * over
    )
    if heading_error is not None:
        r = (
            r
            + cfg.heading_weight * gaussian(heading_error * heading_error, cfg.heading_sigma)
            - cfg.yaw_rate_weight * state[:, R] * state[:, R]
        )
    return np.where(crash, r - cfg.crash_penalty, r)


def circle_errors(state: np.ndarray, center: np.ndarray, radius, speed) -> tuple[np.ndarray, np.ndarray]:
    """The ENPM 667 project's circle errors: (radius error, tangential-speed error), each (N,).

    radius error = ρ − R with ρ the horizontal distance to the centre; tangential speed is
    (r × v)_z / ρ, positive counter-clockwise seen from above, so the error is that minus the
    desired speed (the ENPM 667 project writes x·v_y − y·x_v − R·v, the same up to the factor ρ)."""
    dx, dy = state[:, X] - center[..., 0], state[:, Y] - center[..., 1]
    rho = np.sqrt(dx * dx + dy * dy)
    v_tan = (dx * state[:, VY] - dy * state[:, VX]) / np.maximum(rho, 1e-6)
    return rho - radius, v_tan - speed


def circle_reward(
    state: np.ndarray,
    pos_error: np.ndarray,
    crash: np.ndarray,
    center,
    radius,
    speed,
    cfg: RewardConfig,
    heading_error=None,
) -> np.ndarray:
    """(N,) reward for following a circle: the hover reward towards the moving target point, plus
    the ENPM 667 project's radius and tangential-speed terms."""
    e_r, e_v = circle_errors(state, center, radius, speed)
    r = hover_reward(state, pos_error, crash, cfg, heading_error)
    return (
        r
        + cfg.radius_weight * gaussian(e_r * e_r, cfg.radius_sigma)
        + cfg.speed_weight * gaussian(e_v * e_v, cfg.speed_sigma)
    )


def einsum_dot3_rows(a: np.ndarray, out: np.ndarray, squares: np.ndarray, rows: tuple | None = None) -> np.ndarray:
    """np.einsum("ij,ij->i", a.T, a.T) in place for rows a (3, N), into out (N,); squares (3, N) scratch,
    rows: its three rows if the caller keeps them (taking an array apart costs more than a NumPy
    call on a small row).

    The order matters for the last bit, and np.einsum sums the squares of a float32 triple in order,
    (x² + y²) + z², and of a float64 one as (x² + z²) + y² (two SIMD lanes); this does the same
    (tests/core/test_inplace_equivalence.py compares the two bit for bit)."""
    np.multiply(a, a, squares)
    x2, y2, z2 = squares if rows is None else rows
    if a.dtype == np.float64:
        np.add(x2, z2, out)
        return np.add(out, y2, out)
    np.add(x2, y2, out)
    return np.add(out, z2, out)


class StepTerms:
    """One environment step's position error, termination, yaw errors and reward, computed in place
    from state rows (12, N) into arrays allocated here once: `crashed`, `core.mission.yaw_errors`,
    `hover_reward` or `circle_reward`, and the norm of the position error, as the environments use
    them, with the same operations in the same order (so the same bits;
    tests/core/test_inplace_equivalence.py checks each against its function). After `compute`:

        pos_err (3, N) rows of state[:, POS] − target; dist_sq (N,) its squared norm; err (N,) its norm;
        crash (N,) bool; rate (N,) |yaw rate|; head (N,) |heading error|; reward (N,).

    They are overwritten by the next `compute`; err and rate only by a `compute` asked for them
    (`norms`): nothing else needs them, and a vector environment's step asks only while a success
    window is open."""

    def __init__(self, n: int, dtype) -> None:
        self.n, self.dtype = int(n), np.dtype(dtype)
        rows = lambda k: np.empty((k, self.n), self.dtype)  # noqa: E731
        self.pos_err, self.squares = rows(3), rows(3)
        self.tilt = rows(2)  # |roll|, |pitch|
        self.dist_sq, self.err, self.rate, self.head, self.reward = rows(5)
        self.rates_sq, self.over, self.g, self.t, self.u = rows(5)
        self.crash, self.flag, self.flags = np.empty(self.n, bool), np.empty(self.n, bool), np.empty((2, self.n), bool)
        self._consts: tuple | None = None  # (cfg, its numbers in the state dtype)
        # rows as views made once (taking a row of an array costs about a fifth of a small NumPy call)
        self._squares_rows, self._tilt_rows, self._flag_rows = tuple(self.squares), tuple(self.tilt), tuple(self.flags)
        self._state_views: tuple = (None, None)  # (state rows, the views of them read), made once

    def _numbers(self, cfg: RewardConfig) -> dict:
        """cfg's numbers as the arithmetic below meets them: Python floats cast to the state dtype
        (NEP 50), once per configuration instead of at every ufunc call."""
        if self._consts is None or self._consts[0] is not cfg:
            t = self.dtype.type
            sq = lambda sigma: t(sigma * sigma)  # noqa: E731
            self._consts = (
                cfg,
                {
                    "coarse_w": t(cfg.pos_coarse_weight),
                    "coarse_s2": sq(cfg.pos_coarse_sigma),
                    "fine_w": t(cfg.pos_fine_weight),
                    "fine_s2": sq(cfg.pos_fine_sigma),
                    "rate_w": t(cfg.rate_weight),
                    "tilt_w": t(cfg.tilt_weight),
                    "soft": t(math.radians(cfg.tilt_soft_deg)),
                    "heading_w": t(cfg.heading_weight),
                    "heading_s2": sq(cfg.heading_sigma),
                    "yaw_rate_w": t(cfg.yaw_rate_weight),
                    "penalty": t(cfg.crash_penalty),
                    "radius_w": t(cfg.radius_weight),
                    "radius_s2": sq(cfg.radius_sigma),
                    "speed_w": t(cfg.speed_weight),
                    "speed_s2": sq(cfg.speed_sigma),
                    "two_pi": t(2.0 * math.pi),
                    "zero": t(0.0),
                    "rho_min": t(1e-6),
                    # the limits stay Python floats, as `crashed` compares with them
                    "max_tilt": cfg.max_tilt,
                    "max_distance_sq": cfg.max_distance**2,
                },
            )
        return self._consts[1]

    def compute(
        self,
        s: np.ndarray,
        target: np.ndarray,
        heading: np.ndarray,
        cfg: RewardConfig,
        pay_heading: bool = True,
        circle: tuple | None = None,
        pos_err: np.ndarray | None = None,
        target_rows: np.ndarray | None = None,
        norms: bool = True,
    ) -> None:
        """s (12, N) true state rows; target (N, 3) m; heading (N,) the commanded heading in rad;
        pay_heading: the reward has the heading term (False: version 1); circle (center (3,), radius,
        speed) for the circle reward, None for hover's. pos_err: the rows s[POS] − target.T if the
        caller has them (an `ObservationBuilder` of the true state does), else None. target_rows:
        target.T as a contiguous (3, N) block if the caller keeps it so (then target may be None):
        one subtraction over contiguous rows instead of three reading a (N, 3) array's columns at a
        stride, the same bits. norms: compute `err` and `rate` (False leaves them as they were)."""
        mul, add, sub = np.multiply, np.add, np.subtract
        k = self._numbers(cfg)
        if self._state_views[0] is not s:
            self._state_views = (s, (s[POS], s[ROLL_PITCH], s[RATES], s[X], s[Y], s[Z], s[VX], s[VY], s[YAW], s[R]))
        pos, tilt_rows, rates, x, y, z, vx, vy, yaw, r_rate = self._state_views[1]
        d2, crash, flag, t, g = self.dist_sq, self.crash, self.flag, self.t, self.g
        if pos_err is not None:
            e = pos_err
        elif target_rows is not None:
            e = self.pos_err
            sub(pos, target_rows, e)
        else:
            e, target = self.pos_err, np.asarray(target)
            for i in range(3):  # by column: a transposed (3, N) operand would make NumPy allocate a buffer
                sub(pos[i], target[:, i], e[i])
        einsum_dot3_rows(e, d2, self.squares, self._squares_rows)
        if norms:
            np.sqrt(d2, self.err)
        tilt, flags = self.tilt, self.flags
        np.abs(tilt_rows, tilt)
        # crashed: (z < 0) | (|roll| > max_tilt) | (|pitch| > max_tilt) | ~(dist_sq <= max_distance²)
        np.less(z, 0.0, crash)
        np.greater(tilt, k["max_tilt"], flags)
        flag_roll, flag_pitch = self._flag_rows
        np.logical_or(crash, flag_roll, crash)
        np.logical_or(crash, flag_pitch, crash)
        np.less_equal(d2, k["max_distance_sq"], flag)
        np.logical_not(flag, flag)
        np.logical_or(crash, flag, crash)
        # core.mission.yaw_errors: |r|, and d = |ψ − ψ_cmd| wrapped as min(d, 2π − d)
        if norms:
            np.abs(r_rate, self.rate)
        sub(yaw, heading, t)
        np.abs(t, t)
        sub(k["two_pi"], t, self.head)
        np.minimum(t, self.head, out=self.head)
        # hover_reward
        r = self.reward
        einsum_dot3_rows(rates, self.rates_sq, self.squares, self._squares_rows)
        over = self.over
        np.maximum(*self._tilt_rows, out=over)
        sub(over, k["soft"], over)
        np.maximum(over, k["zero"], out=over)
        neg_d2 = self.u  # gaussian: exp(−d²/σ²), the −d² shared by both widths
        np.negative(d2, neg_d2)
        np.divide(neg_d2, k["coarse_s2"], g)
        np.exp(g, g)
        mul(k["coarse_w"], g, r)
        np.divide(neg_d2, k["fine_s2"], g)
        np.exp(g, g)
        mul(k["fine_w"], g, g)
        add(r, g, r)
        mul(k["rate_w"], self.rates_sq, g)
        sub(r, g, r)
        mul(k["tilt_w"], over, g)
        mul(g, over, g)
        sub(r, g, r)
        if pay_heading:
            mul(self.head, self.head, t)
            _gaussian(t, k["heading_s2"], g)
            mul(k["heading_w"], g, g)
            add(r, g, r)
            mul(k["yaw_rate_w"], r_rate, g)
            mul(g, r_rate, g)
            sub(r, g, r)
        sub(r, k["penalty"], r, where=crash)  # np.where(crash, r − penalty, r)
        if circle is not None:  # circle_reward: + radius and speed Gaussians on circle_errors
            center, radius, speed = circle
            dx, dy, u = self.over, self.t, self.u  # `over` is spent
            sub(x, center[..., 0], dx)
            sub(y, center[..., 1], dy)
            mul(dx, dx, g)  # rho = √(dx·dx + dy·dy)
            mul(dy, dy, u)
            add(g, u, g)
            np.sqrt(g, g)
            mul(dx, vy, dx)  # v_tan = (dx·vy − dy·vx) / max(rho, 1e-6)
            mul(dy, vx, dy)
            sub(dx, dy, dx)
            np.maximum(g, k["rho_min"], out=u)
            np.divide(dx, u, dx)
            sub(g, self.dtype.type(radius), g)  # e_r = rho − radius
            sub(dx, self.dtype.type(speed), dx)  # e_v = v_tan − speed
            mul(g, g, u)
            _gaussian(u, k["radius_s2"], u)
            mul(k["radius_w"], u, u)
            add(r, u, r)
            mul(dx, dx, u)
            _gaussian(u, k["speed_s2"], u)
            mul(k["speed_w"], u, u)
            add(r, u, r)


def _gaussian(err_sq: np.ndarray, sigma_sq, out: np.ndarray) -> np.ndarray:
    """`gaussian` into out (which may be err_sq itself): exp(−err_sq/σ²), σ² given."""
    np.negative(err_sq, out)
    np.divide(out, sigma_sq, out)
    return np.exp(out, out)
