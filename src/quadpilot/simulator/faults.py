"""Sensor faults the simulator can inject, at a set simulated time of every episode (seeded: the
episode's start and noise come from its seed as always, and a fault fires at the same step each time).

    quad-sitl --sensor-fault gyro-spike@2s          # one step: the gyro's x axis reads 20 rad/s more
    quad-sitl --sensor-fault pos-freeze@2s+0.5s     # position frozen for 0.5 s
    quad-sitl --sensor-fault baro-step@1s:5,nan@3s:gyro

The spec is `KIND@START[+DURATION][:SIZE]`, several separated by commas; START and DURATION in
seconds of simulated time from the episode's first step (`2`, `2s`, `500ms`). A fault lasts at least
one step. Kinds, with their defaults:

- `gyro-spike` (one step, 20 rad/s): HIL_SENSOR's gyro x axis (roll rate) reads SIZE rad/s more.
- `accel-stuck` (to the end): the accelerometer keeps the reading it had at START: HIL_SENSOR's
  xacc/yacc/zacc and HIL_STATE_QUATERNION's xacc/yacc/zacc.
- `pos-freeze` (0.5 s): a position dropout as a frozen position: HIL_STATE_QUATERNION's and
  HIL_GPS's lat/lon/alt repeat the values of the step before START (velocity, attitude and the rates
  stay true): what an autopilot sees from a receiver that repeats its last fix.
- `state-dropout` (0.5 s): no HIL_STATE_QUATERNION and no HIL_GPS at all; HIL_SENSOR still goes out
  every step.
- `baro-step` (to the end, 5 m): the barometer reads SIZE metres higher (HIL_SENSOR's pressure_alt,
  and abs_pressure and temperature of the ISA at that altitude).
- `nan` (one step, `state`): NaN in one field: `state`, HIL_STATE_QUATERNION's rollspeed; `gyro`,
  HIL_SENSOR's xgyro; `baro`, HIL_SENSOR's abs_pressure.

ODOMETRY (`--estimator-noise`) is not faulted: an estimator's output is not a sensor.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

KINDS = ("gyro-spike", "accel-stuck", "pos-freeze", "state-dropout", "baro-step", "nan")
DEFAULT_DURATION_S = {"pos-freeze": 0.5, "state-dropout": 0.5}
"""s; a kind not listed lasts one step (gyro-spike, nan) or to the end (accel-stuck, baro-step)."""
TO_THE_END = ("accel-stuck", "baro-step")
DEFAULT_SIZE = {"gyro-spike": 20.0, "baro-step": 5.0}
NAN_FIELDS = ("state", "gyro", "baro")
MAX_TIME_S = 3600.0
MAX_SIZE = 1e4
EXPECTED = (
    "expected KIND@START[+DURATION][:SIZE][,...] with KIND one of " + ", ".join(KINDS) + " and times in s or ms, "
    "e.g. gyro-spike@2s, pos-freeze@2s+0.5s, baro-step@1s:5, nan@3s:gyro"
)

# HIL_STATE_QUATERNION's, HIL_SENSOR's and HIL_GPS's positional arguments (`link.wire`'s `*_args`)
STATE_ROLLSPEED, STATE_LAT_LON_ALT, STATE_ACC = 2, slice(5, 8), slice(13, 16)
SENSOR_ACC, SENSOR_XGYRO, SENSOR_PRESSURE, SENSOR_PRESSURE_ALT, SENSOR_TEMPERATURE = slice(1, 4), 4, 10, 12, 13
GPS_LAT_LON_ALT = slice(2, 5)


class FaultSpecError(ValueError):
    """A --sensor-fault spec that cannot be used: one line naming what was wrong and what is expected."""


@dataclass(frozen=True)
class SensorFault:
    kind: str
    start_s: float
    duration_s: float | None  # None: the kind's default
    size: float | str | None = None  # None: the kind's default; nan: the field's name

    def __str__(self) -> str:
        text = f"{self.kind}@{self.start_s:g}s"
        if self.duration_s is not None:
            text += f"+{self.duration_s:g}s"
        if self.size is not None:
            text += f":{self.size:g}" if isinstance(self.size, float) else f":{self.size}"
        return text


_TIME = re.compile(r"^([0-9]+(?:\.[0-9]*)?|\.[0-9]+)(s|ms)?$")


def _seconds(text: str, what: str) -> float:
    m = _TIME.match(text.strip())
    if not m:
        raise FaultSpecError(f"{what} {text!r} is not a time (2, 2s or 500ms)")
    v = float(m.group(1)) * (1e-3 if m.group(2) == "ms" else 1.0)
    if v > MAX_TIME_S:
        raise FaultSpecError(f"{what} {text!r} is beyond {MAX_TIME_S:g} s")
    return v


def _one(item: str) -> SensorFault:
    kind, at, rest = item.partition("@")
    kind = kind.strip().lower()
    if kind not in KINDS:
        raise FaultSpecError(f"unknown fault {kind!r}" if kind else f"{item!r} names no fault")
    if not at:
        raise FaultSpecError(f"{item!r} has no @START")
    rest, colon, size_text = rest.partition(":")
    start_text, plus, dur_text = rest.partition("+")
    start = _seconds(start_text, "start")
    duration = _seconds(dur_text, "duration") if plus else None
    if duration is not None and duration <= 0:
        raise FaultSpecError(f"duration {dur_text!r} must be > 0")
    size: float | str | None = None
    if colon:
        size_text = size_text.strip().lower()
        if kind == "nan":
            if size_text not in NAN_FIELDS:
                raise FaultSpecError(f"nan:{size_text} names no field; expected one of {', '.join(NAN_FIELDS)}")
            size = size_text
        elif kind in DEFAULT_SIZE:
            try:
                size = float(size_text)
            except ValueError:
                size = math.nan
            if not abs(size) <= MAX_SIZE:  # False for NaN too
                raise FaultSpecError(f"{kind} size {size_text!r} is not a number within ±{MAX_SIZE:g}")
        else:
            raise FaultSpecError(f"{kind} takes no :SIZE")
    return SensorFault(kind, start, duration, size)


def parse_faults(text: str) -> tuple[SensorFault, ...]:
    """`gyro-spike@2s,pos-freeze@2s+0.5s` → faults; FaultSpecError in one line otherwise."""
    try:
        if not text.strip():
            raise FaultSpecError("empty spec")
        return tuple(_one(item) for item in text.split(","))
    except FaultSpecError as e:
        raise FaultSpecError(f"--sensor-fault {text!r}: {e}; {EXPECTED}") from None


class FaultPlayer:
    """The faults of one episode at step `n`: `apply` edits one step's message arguments in place."""

    def __init__(self, faults: tuple[SensorFault, ...], dt: float, pressure_at) -> None:
        self.dt = dt
        self._pressure_at = pressure_at  # (altitude m MSL) → (hPa, °C): the simulator's ISA
        self.windows = []
        for f in faults:
            first = round(f.start_s / dt)
            dur = f.duration_s if f.duration_s is not None else DEFAULT_DURATION_S.get(f.kind)
            last = math.inf if dur is None and f.kind in TO_THE_END else first + max(1, round((dur or 0.0) / dt))
            size = f.size if f.size is not None else DEFAULT_SIZE.get(f.kind, "state" if f.kind == "nan" else None)
            self.windows.append((f.kind, first, last, size))
        self.fired: dict[str, int] = {}
        """Steps each kind was active, so far."""
        self._frozen_pos = self._frozen_gps = self._stuck = None
        self._last_pos = self._last_gps = None

    def active(self, n: int) -> list[tuple[str, float | str | None]]:
        return [(k, size) for k, first, last, size in self.windows if first <= n < last]

    def apply(self, n: int, gps: list | None, state: list, sensor: list) -> tuple[list | None, list | None]:
        """Step `n`'s HIL_GPS (None when not sent this step), HIL_STATE_QUATERNION and HIL_SENSOR
        arguments, faulted in place; returns (gps, state) to send, None for a message withheld."""
        kinds = sorted(self.active(n), key=lambda ks: ks[0] == "state-dropout")  # withholding last
        now = {k for k, _ in kinds}
        if "pos-freeze" not in now:  # remember the last true position, to freeze at
            self._frozen_pos = self._frozen_gps = None
            self._last_pos = state[STATE_LAT_LON_ALT]
            if gps is not None:
                self._last_gps = gps[GPS_LAT_LON_ALT]
        if "accel-stuck" not in now:
            self._stuck = None
        for kind, size in kinds:
            self.fired[kind] = self.fired.get(kind, 0) + 1
            if kind == "gyro-spike":
                sensor[SENSOR_XGYRO] += size
            elif kind == "accel-stuck":
                if self._stuck is None:
                    self._stuck = (sensor[SENSOR_ACC], state[STATE_ACC])
                sensor[SENSOR_ACC], state[STATE_ACC] = self._stuck
            elif kind == "pos-freeze":
                if self._frozen_pos is None:
                    self._frozen_pos = self._last_pos or state[STATE_LAT_LON_ALT]
                    self._frozen_gps = self._last_gps
                state[STATE_LAT_LON_ALT] = self._frozen_pos
                if gps is not None and self._frozen_gps is not None:
                    gps[GPS_LAT_LON_ALT] = self._frozen_gps
            elif kind == "state-dropout":
                gps = state = None
            elif kind == "baro-step":
                alt = sensor[SENSOR_PRESSURE_ALT] + size
                sensor[SENSOR_PRESSURE_ALT] = alt
                sensor[SENSOR_PRESSURE], sensor[SENSOR_TEMPERATURE] = self._pressure_at(alt)
            elif kind == "nan":
                if size == "state" and state is not None:
                    state[STATE_ROLLSPEED] = math.nan
                elif size == "gyro":
                    sensor[SENSOR_XGYRO] = math.nan
                elif size == "baro":
                    sensor[SENSOR_PRESSURE] = math.nan
        return gps, state
