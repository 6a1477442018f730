"""Sensor noise: an IMU (gyroscope and accelerometer) and the output of a state estimator, batched
over N drones, NumPy only. The training environments and the simulator (`simulator`) both use it,
so a policy is trained on the noise it later meets over MAVLink.

IMU, per drone and per axis, the model of Kalibr's "IMU Noise Model" wiki page (Nikolic, ETH) that
PX4's Gazebo IMU plugin implements (PX4-SITL_gazebo-classic `gazebo_imu_plugin.cpp`, from
ethz-asl/rotors_simulator):

    measured = true + b + σ_d·w,      σ_d = noise_density / √dt               (white noise)
    b_{k+1}  = φ·b_k + σ_b·w',        φ = exp(−dt/τ),
                                      σ_b = bias_walk·√(τ/2·(1 − exp(−2dt/τ)))   (Maybeck 1979, 4-114)
    b_0 ~ N(0, turn_on_bias²)

w, w' independent standard normal. With τ → ∞ the bias is a random walk, σ_b = bias_walk·√dt and
std(b_t − b_0) = bias_walk·√t; τ = None means exactly that.

State estimator ("what an EKF would output"), per drone and per axis: the true position, velocity
and attitude plus a slowly varying error (a first-order Gauss-Markov process, the stationary OU
process above with std `drift` and correlation time `tau`) plus white noise. The estimator's body
rates are the (noisy) gyro, as in PX4, where the rate controller runs on the bias-corrected gyro.
The errors of the three quantities are independent here; a real filter correlates them. Attitude
errors are added to the ZYX Euler angles (small angles: equivalent to a small rotation).

Randomness is passed in as a `np.random.Generator`; `SensorNoiseState.step` draws every random
number of one step in a single call, so a seed fixes the whole sequence.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .state import ATT, POS, RATES, VEL

DEG = math.pi / 180.0
G = 9.81  # m/s², as core.params.GRAVITY (kept local: this module imports only core.state)


@dataclass(frozen=True)
class ImuNoise:
    """One IMU's noise, the same on each of the three axes. Units per field."""

    name: str
    """Sensor name."""
    gyro_noise_density: float
    """rad/s/√Hz, gyroscope white noise (per-sample σ = density/√dt)."""
    gyro_bias_walk: float
    """rad/s²/√Hz (= rad/s per √s), diffusion of the gyroscope bias."""
    gyro_bias_tau: float | None
    """s, correlation time of the gyroscope bias; None: a pure random walk."""
    gyro_turn_on_bias: float
    """rad/s, standard deviation of the gyroscope bias at the start of an episode."""
    accel_noise_density: float
    """m/s²/√Hz, accelerometer white noise."""
    accel_bias_walk: float
    """m/s³/√Hz, diffusion of the accelerometer bias."""
    accel_bias_tau: float | None
    """s, correlation time of the accelerometer bias; None: a pure random walk."""
    accel_turn_on_bias: float
    """m/s², standard deviation of the accelerometer bias at the start of an episode."""


@dataclass(frozen=True)
class EstimatorNoise:
    """Errors of a state estimate: white noise plus a first-order Gauss-Markov drift per axis."""

    name: str
    """Estimator name."""
    pos_white: float
    """m, white noise on each position axis."""
    pos_drift: float
    """m, stationary standard deviation of the slowly varying position error, per axis."""
    pos_tau: float
    """s, correlation time of the position error."""
    vel_white: float
    """m/s, white noise on each velocity axis."""
    vel_drift: float
    """m/s, stationary standard deviation of the slowly varying velocity error, per axis."""
    vel_tau: float
    """s, correlation time of the velocity error."""
    tilt_drift: float
    """rad, stationary standard deviation of the roll and pitch errors."""
    yaw_drift: float
    """rad, stationary standard deviation of the yaw error."""
    att_tau: float
    """s, correlation time of the attitude errors."""


@dataclass(frozen=True)
class SensorNoise:
    """What a vehicle's sensors add: an IMU model and an estimator model (either may be None)."""

    name: str
    """Preset name, as given to `get_sensor_noise`."""
    imu: ImuNoise | None
    """Gyroscope and accelerometer noise; None: exact IMU."""
    estimator: EstimatorNoise | None
    """Position, velocity and attitude estimate errors; None: the estimate is the truth."""

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> SensorNoise:
        imu, est = d.get("imu"), d.get("estimator")
        return cls(
            name=d["name"],
            imu=ImuNoise(**imu) if imu is not None else None,
            estimator=EstimatorNoise(**est) if est is not None else None,
        )

    def scaled(self, k: float) -> SensorNoise:
        """A copy with every noise amplitude (densities, walks, turn-on biases, white and drift
        standard deviations) multiplied by k and the correlation times kept: a robustness grid."""
        keep = {"name", "gyro_bias_tau", "accel_bias_tau", "pos_tau", "vel_tau", "att_tau"}

        def scale(part):
            if part is None:
                return None
            return dataclasses.replace(
                part, **{f.name: getattr(part, f.name) * k for f in dataclasses.fields(part) if f.name not in keep}
            )

        return dataclasses.replace(
            self, name=f"{self.name}x{k:g}", imu=scale(self.imu), estimator=scale(self.estimator)
        )

    def with_parts(self, imu: bool = True, estimator: bool = True) -> SensorNoise:
        """A copy with the IMU and/or the estimator part switched off."""
        return dataclasses.replace(self, imu=self.imu if imu else None, estimator=self.estimator if estimator else None)


# ADIS16448: the defaults of PX4's Gazebo IMU plugin (PX4-SITL_gazebo-classic
# include/gazebo_imu_plugin.h, kDefaultAdis*, from ethz-asl/rotors_simulator), which PX4 SITL flies with.
ADIS16448 = ImuNoise(
    name="adis16448",
    gyro_noise_density=2.0 * 35.0 / 3600.0 * DEG,  # rad/s/√Hz ≈ 3.39e-4, kDefaultAdisGyroscopeNoiseDensity
    gyro_bias_walk=2.0 * 4.0 / 3600.0 * DEG,  # rad/s²/√Hz ≈ 3.88e-5, kDefaultAdisGyroscopeRandomWalk
    gyro_bias_tau=1.0e3,  # s, kDefaultAdisGyroscopeBiasCorrelationTime
    gyro_turn_on_bias=0.5 * DEG,  # rad/s ≈ 8.7e-3, kDefaultAdisGyroscopeTurnOnBiasSigma
    accel_noise_density=2.0 * 2.0e-3,  # m/s²/√Hz, kDefaultAdisAccelerometerNoiseDensity
    accel_bias_walk=2.0 * 3.0e-3,  # m/s³/√Hz, kDefaultAdisAccelerometerRandomWalk
    accel_bias_tau=300.0,  # s, kDefaultAdisAccelerometerBiasCorrelationTime
    accel_turn_on_bias=20.0e-3 * 9.8,  # m/s² (20 mg), kDefaultAdisAccelerometerTurnOnBiasSigma
)

# BMI088, the IMU of the Crazyflie 2.1. White noise and offsets: Bosch Sensortec BMI088 data sheet
# (BST-BMI088-DS001), typical values. The data sheet gives no bias random walk: PX4's ADIS16448
# defaults are assumed (over a 5 s episode they move the bias by ~1e-4 rad/s, far below the offsets).
BMI088 = ImuNoise(
    name="bmi088",
    gyro_noise_density=0.014 * DEG,  # rad/s/√Hz ≈ 2.44e-4, data sheet: rate noise density 0.014 °/s/√Hz
    gyro_bias_walk=2.0 * 4.0 / 3600.0 * DEG,  # rad/s²/√Hz, assumed (PX4's ADIS16448 default)
    gyro_bias_tau=1.0e3,  # s, assumed (PX4's ADIS16448 default)
    # rad/s: the data sheet's zero-rate offset is ±1 °/s, but the Crazyflie firmware measures the gyro
    # bias while the vehicle stands still before it flies; 0.1 °/s is an assumed residual
    gyro_turn_on_bias=0.1 * DEG,
    accel_noise_density=175e-6 * G,  # m/s²/√Hz ≈ 1.7e-3, data sheet: 175 µg/√Hz
    accel_bias_walk=2.0 * 3.0e-3,  # m/s³/√Hz, assumed (PX4's ADIS16448 default)
    accel_bias_tau=300.0,  # s, assumed (PX4's ADIS16448 default)
    accel_turn_on_bias=20e-3 * G,  # m/s² (20 mg), data sheet zero-g offset ±20 mg taken as 1 σ
)

# A centimetre-level estimate, as a filter fusing the IMU with RTK GNSS (u-blox ZED-F9P data sheet:
# RTK horizontal accuracy 0.01 m + 1 ppm CEP), motion capture or a Lighthouse system would give.
# The numbers are assumed orders of magnitude (centimetre level), not identified from logs.
EKF_CM = EstimatorNoise(
    name="ekf_cm",
    pos_white=0.005,  # m, assumed
    pos_drift=0.01,  # m, assumed: slowly wandering 1 cm per axis
    pos_tau=2.0,  # s, assumed
    vel_white=0.01,  # m/s, assumed
    vel_drift=0.01,  # m/s, assumed
    vel_tau=1.0,  # s, assumed
    tilt_drift=0.5 * DEG,  # rad, assumed: roll and pitch within about a degree
    yaw_drift=1.0 * DEG,  # rad, assumed: heading from a magnetometer is worse than tilt
    att_tau=1.0,  # s, assumed
)

SENSOR_NOISE_PRESETS: dict[str, SensorNoise] = {
    "seed": SensorNoise("seed", ADIS16448, EKF_CM),
    "crazyflie": SensorNoise("crazyflie", BMI088, EKF_CM),
}
"""Per airframe preset (`core.params`): its IMU and a cm-level estimator."""


def get_sensor_noise(name: str) -> SensorNoise:
    """The preset called `name` (an airframe preset name); a clear error names the known ones."""
    try:
        return SENSOR_NOISE_PRESETS[name]
    except KeyError:
        raise ValueError(
            f"unknown sensor noise preset {name!r}; known presets: {sorted(SENSOR_NOISE_PRESETS)}"
        ) from None


def ou_coefficients(diffusion: float, tau: float | None, dt: float) -> tuple[float, float]:
    """(φ, σ) of the exact one-step discretisation x ← φ·x + σ·w of dx = −x/τ·dt + diffusion·dW
    (Maybeck 1979, eq. 4-114); τ None: the random walk, (1, diffusion·√dt)."""
    if tau is None or math.isinf(tau):
        return 1.0, diffusion * math.sqrt(dt)
    if not tau > 0:
        raise ValueError(f"correlation time must be > 0 or None, got {tau!r}")
    phi = math.exp(-dt / tau)
    return phi, diffusion * math.sqrt(-0.5 * tau * math.expm1(-2.0 * dt / tau))  # expm1: exact for long τ


def gauss_markov_coefficients(std: float, tau: float, dt: float) -> tuple[float, float]:
    """(φ, σ) of a first-order Gauss-Markov process with stationary std `std` and correlation time
    `tau`, sampled every dt: the OU process with diffusion std·√(2/τ)."""
    phi = math.exp(-dt / tau)
    return phi, std * math.sqrt(-math.expm1(-2.0 * dt / tau))


# Columns of the per-step draw, three each: the slow processes, then the white noises.
_SLOW = ("gyro_bias", "accel_bias", "pos_err", "vel_err", "att_err")
_WHITE = ("gyro_white", "accel_white", "pos_white", "vel_white")


class SensorNoiseState:
    """The noise processes of N drones for one `SensorNoise`, advanced every dt.

    `reset(idx)` starts the selected drones' processes afresh (turn-on biases, stationary estimator
    errors, new white noise); `step()` advances every drone one dt and draws that step's white
    noise. The measurement methods then add the current noise to true values; they draw nothing,
    so a step's gyro, accelerometer and estimate are all consistent, whatever is asked for."""

    def __init__(self, spec: SensorNoise, n: int, dt: float, rng: np.random.Generator) -> None:
        if n < 1 or not dt > 0:
            raise ValueError(f"need n ≥ 1 drones and dt > 0, got n={n}, dt={dt}")
        self.spec, self.n, self.dt, self.rng = spec, int(n), float(dt), rng
        imu, est = spec.imu, spec.estimator
        z3 = np.zeros(3)
        # per-step transition φ, kick σ, white σ and start σ, each (15,) over the 5 slow triples
        phi, kick, start = [], [], []
        white = []
        if imu is not None:
            for dens, walk, tau, on in (
                (imu.gyro_noise_density, imu.gyro_bias_walk, imu.gyro_bias_tau, imu.gyro_turn_on_bias),
                (imu.accel_noise_density, imu.accel_bias_walk, imu.accel_bias_tau, imu.accel_turn_on_bias),
            ):
                p, s = ou_coefficients(walk, tau, dt)
                phi.append(z3 + p)
                kick.append(z3 + s)
                start.append(z3 + on)
                white.append(z3 + dens / math.sqrt(dt))
        else:
            for _ in range(2):
                phi.append(z3 + 1.0)
                kick.append(z3)
                start.append(z3)
                white.append(z3)
        if est is not None:
            for std, tau in ((est.pos_drift, est.pos_tau), (est.vel_drift, est.vel_tau)):
                p, s = gauss_markov_coefficients(std, tau, dt)
                phi.append(z3 + p)
                kick.append(z3 + s)
                start.append(z3 + std)
            att = np.array([est.tilt_drift, est.tilt_drift, est.yaw_drift])
            p, unit_kick = gauss_markov_coefficients(1.0, est.att_tau, dt)
            phi.append(z3 + p)
            kick.append(att * unit_kick)
            start.append(att)
            white += [z3 + est.pos_white, z3 + est.vel_white]
        else:
            for _ in range(3):
                phi.append(z3 + 1.0)
                kick.append(z3)
                start.append(z3)
            white += [z3, z3]
        self._phi = np.concatenate(phi)
        self._kick = np.concatenate(kick)
        self._start = np.concatenate(start)
        self._white_std = np.concatenate(white)
        self.slow = np.zeros((self.n, 15))
        """(N, 15): gyro bias, accel bias, position error, velocity error, attitude error (3 each)."""
        self.white = np.zeros((self.n, 12))
        """(N, 12): this step's white noise: gyro, accel, position, velocity (3 each)."""
        self._draw: np.ndarray | None = None  # (N, 27) standard normals of a step, made at the first
        self._sum: np.ndarray | None = None  # (2, N) float64 scratch of `estimate_rows`

    # --- processes ---------------------------------------------------------------------------
    def reset(self, idx=None) -> None:
        """Start the processes of drones `idx` (index array, boolean mask or None: all) afresh."""
        rows = np.arange(self.n)[slice(None) if idx is None else idx]
        k = rows.size
        if k == 0:
            return
        z = self.rng.standard_normal((k, 27))
        self.slow[rows] = self._start * z[:, :15]
        self.white[rows] = self._white_std * z[:, 15:]

    def step(self) -> None:
        """Advance every drone's processes by dt and draw this step's white noise. The draw fills
        one (N, 27) array kept from step to step (`Generator.standard_normal(out=)` draws what
        `standard_normal((N, 27))` draws) and the updates are in place, in the same order as the
        allocating code had them (NumPy still buffers the products of a per-column constant with
        the (N, 15) and (N, 12) blocks)."""
        z = self._draw
        if z is None:
            z = self._draw = np.empty((self.n, 27))
        self.rng.standard_normal(out=z)
        self.slow *= self._phi
        kicks = z[:, :15]
        np.multiply(self._kick, kicks, out=kicks)  # slow += kick·z
        self.slow += kicks
        np.multiply(self._white_std, z[:, 15:], out=self.white)

    # --- measurements ------------------------------------------------------------------------
    def gyro(self, rates: np.ndarray, idx=None) -> np.ndarray:
        """Gyroscope readings (k, 3) rad/s FLU for true body rates (k, 3) of drones `idx`."""
        s = slice(None) if idx is None else idx
        return rates + self.slow[s, 0:3] + self.white[s, 0:3]

    def accel(self, specific_force: np.ndarray, idx=None) -> np.ndarray:
        """Accelerometer readings (k, 3) m/s² FLU for the true specific force (k, 3)."""
        s = slice(None) if idx is None else idx
        return specific_force + self.slow[s, 3:6] + self.white[s, 3:6]

    def estimate(self, state: np.ndarray, idx=None) -> np.ndarray:
        """What the estimator reports for true 12-states (k, 12) (`core.dynamics` layout): a new
        array, position, velocity and attitude with their errors, body rates from the gyro."""
        s = slice(None) if idx is None else idx
        out = np.array(state, copy=True)
        out[:, POS] += self.slow[s, 6:9] + self.white[s, 6:9]
        out[:, VEL] += self.slow[s, 9:12] + self.white[s, 9:12]
        out[:, ATT] += self.slow[s, 12:15]
        out[:, RATES] = self.gyro(state[:, RATES], idx)
        return out

    def estimate_rows(self, s: np.ndarray, out: np.ndarray) -> np.ndarray:
        """`estimate` of every drone in place: s (12, N) true state rows, out (12, N) rows of the
        estimate in the same dtype. The same operations as `estimate` in the same order (each error
        summed in float64, then added to the state and cast to its dtype, as `+=` on the copy does;
        the rates ((true + bias) + white) in float64, then cast), so the same bits."""
        if self._sum is None:
            self._sum = np.empty((2, self.n))
        err, x = self._sum
        slow, white, add, copy = self.slow, self.white, np.add, np.copyto

        def plus(row: int, err: np.ndarray) -> None:  # out[row] = s[row] + err, in float64, cast
            copy(x, s[row])
            add(x, err, x)
            copy(out[row], x, casting="same_kind")

        # column by column, and float32 widened by copies: a transposed (3, N) operand or a mixed-type
        # ufunc would make NumPy allocate a buffer
        for i in range(3):
            add(slow[:, 6 + i], white[:, 6 + i], err)  # out[:, POS] += slow[6:9] + white[6:9]
            plus(POS.start + i, err)
            add(slow[:, 9 + i], white[:, 9 + i], err)  # out[:, VEL] += slow[9:12] + white[9:12]
            plus(VEL.start + i, err)
            plus(ATT.start + i, slow[:, 12 + i])  # out[:, ATT] += slow[12:15]
            copy(x, s[RATES.start + i])  # gyro: rates + slow[0:3] + white[0:3]
            add(x, slow[:, i], x)
            add(x, white[:, i], x)
            copy(out[RATES.start + i], x, casting="same_kind")
        return out

    @property
    def gyro_noise_std(self) -> float:
        """rad/s, per-sample white noise of the gyroscope (0 without an IMU model)."""
        return float(self._white_std[0])

    @property
    def accel_noise_std(self) -> float:
        """m/s², per-sample white noise of the accelerometer (0 without an IMU model)."""
        return float(self._white_std[3])

    # --- checkpoints -------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Arrays (copies) and the generator state: JSON-able data and arrays only."""
        return {"slow": self.slow.copy(), "white": self.white.copy(), "rng": self.rng.bit_generator.state}

    def load_state_dict(self, d: dict) -> None:
        slow, white = np.asarray(d["slow"], np.float64), np.asarray(d["white"], np.float64)
        if slow.shape != self.slow.shape or white.shape != self.white.shape:
            raise ValueError(f"noise state for {slow.shape[0]} drones, this one has {self.n}")
        self.slow, self.white = slow.copy(), white.copy()
        kind = d["rng"]["bit_generator"]
        bitgen = getattr(np.random, kind)()
        bitgen.state = d["rng"]
        self.rng = np.random.Generator(bitgen)
