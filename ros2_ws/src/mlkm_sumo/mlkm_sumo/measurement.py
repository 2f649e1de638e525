"""Loop-detector passages and the measurement model applied to them.

A passage is what a loop reports: time, station, lane (index from the right), speed and
vehicle length, with the ground truth (the SUMO vehicle) and its ``kind``:

- ``PASSAGE``: the first report of a vehicle at a station;
- ``DOUBLE_REPORT``: a vehicle that changes lane on top of a station is reported again by
  the new lane's loop, as real loops do. It is a false alarm of a known kind: its truth
  target is -1 and the model keeps it (default) or removes it (``double_reports=False``);
- ``FALSE_ALARM``: a report without a vehicle, added by the model.

The model (every effect off by default) adds Gaussian stamp jitter, speed noise and length
noise, drops passages with probability ``miss_rate`` and adds false alarms as a Poisson
process of ``false_alarm_rate`` per station and hour, on a random lane, with a speed and a
length drawn uniformly from ``false_alarm_speed`` and ``false_alarm_length``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

PASSAGE = 0
DOUBLE_REPORT = 1
FALSE_ALARM = 2
KIND_NAMES = ('passage', 'double_report', 'false_alarm')

#: Smallest speed [m/s] and length [m] a noisy measurement is clipped to (loops report
#: positive values).
MIN_SPEED = 0.1
MIN_LENGTH = 0.5
#: Decimals of position_m, stamp_s, velocity_mps and length_m in a written detections CSV
#: (``mlkm_core.csvout``): 1 cm, 0.1 ms, 0.1 mm/s, 1 mm, finer than SUMO's interpolation.
CSV_DECIMALS = (2, 4, 4, 3)


@dataclass(frozen=True)
class MeasurementConfig:
    stamp_jitter: float = 0.0  # standard deviation of the passage time [s]
    speed_noise: float = 0.0  # standard deviation of the speed [m/s]
    length_noise: float = 0.0  # standard deviation of the vehicle length [m]
    miss_rate: float = 0.0  # probability that a passage is not reported [0, 1]
    false_alarm_rate: float = 0.0  # false alarms per station and hour [1/h]
    double_reports: bool = True  # keep the lane-change double reports
    false_alarm_speed: tuple[float, float] = (5.0, 40.0)  # [m/s], uniform
    false_alarm_length: tuple[float, float] = (3.5, 18.0)  # [m], uniform

    def __post_init__(self) -> None:
        for name in ('stamp_jitter', 'speed_noise', 'length_noise', 'false_alarm_rate'):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f'{name} must be finite and >= 0, got {v}')
        if not 0.0 <= self.miss_rate <= 1.0:
            raise ValueError(f'miss_rate must lie in [0, 1], got {self.miss_rate}')
        for name in ('false_alarm_speed', 'false_alarm_length'):
            lo, hi = getattr(self, name)
            if not (0 < lo <= hi and math.isfinite(hi)):
                raise ValueError(f'{name} must be a range 0 < low <= high, got {(lo, hi)}')


def _col(dtype) -> np.ndarray:
    return field(default_factory=lambda: np.zeros(0, dtype))


@dataclass
class Passages:
    """Passages as parallel arrays. ``vehicle`` holds SUMO ids ('' for false alarms);
    ``true_speed`` is the speed before measurement noise (defaults to ``speed``)."""

    time: np.ndarray = _col(float)  # [s]
    station: np.ndarray = _col(np.int64)  # index into the road's stations
    lane: np.ndarray = _col(np.int64)  # index from the right
    speed: np.ndarray = _col(float)  # [m/s]
    length: np.ndarray = _col(float)  # [m]
    vehicle: np.ndarray = _col(object)
    kind: np.ndarray = _col(np.int64)
    true_speed: np.ndarray = _col(float)  # [m/s]

    def __post_init__(self) -> None:
        for f, dt in zip(
            fields(self), (float, np.int64, np.int64, float, float, object, np.int64, float)
        ):
            setattr(self, f.name, np.asarray(getattr(self, f.name), dtype=dt))
        n = self.time.size
        if self.true_speed.size == 0 and n:
            self.true_speed = self.speed.copy()
        if any(getattr(self, f.name).shape != (n,) for f in fields(self)):
            raise ValueError('passage columns must be 1-D of equal length')

    def __len__(self) -> int:
        return int(self.time.size)

    def subset(self, index: np.ndarray) -> Passages:
        return Passages(*(getattr(self, f.name)[index] for f in fields(self)))

    def sorted(self) -> Passages:
        return self.subset(np.argsort(self.time, kind='stable'))

    @staticmethod
    def concatenate(parts: list[Passages]) -> Passages:
        if not parts:
            return Passages()
        return Passages(
            *(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Passages))
        )


@dataclass
class MeasurementStats:
    """What the model did, so that nothing disappears unnoticed."""

    passages: int = 0  # first reports of a vehicle at a station, before misses
    missed: int = 0
    double_reports: int = 0  # seen in SUMO
    double_reports_removed: int = 0
    false_alarms: int = 0


def false_alarms(
    config: MeasurementConfig,
    lanes: np.ndarray,
    t0: float,
    t1: float,
    rng: np.random.Generator,
) -> Passages:
    """False alarms in the window [t0, t1) at stations with ``lanes[i]`` lanes each."""
    lanes = np.asarray(lanes, np.int64)
    if config.false_alarm_rate <= 0 or t1 <= t0 or lanes.size == 0:
        return Passages()
    n = int(rng.poisson(config.false_alarm_rate * lanes.size * (t1 - t0) / 3600.0))
    station = rng.integers(0, lanes.size, n)
    return Passages(
        time=rng.uniform(t0, t1, n),
        station=station,
        lane=rng.integers(0, lanes[station]) if n else np.zeros(0, np.int64),
        speed=rng.uniform(*config.false_alarm_speed, n),
        length=rng.uniform(*config.false_alarm_length, n),
        vehicle=np.full(n, '', object),
        kind=np.full(n, FALSE_ALARM, np.int64),
    )


def apply(
    config: MeasurementConfig,
    passages: Passages,
    lanes: np.ndarray,
    t0: float,
    t1: float,
    rng: np.random.Generator,
    stats: MeasurementStats | None = None,
) -> Passages:
    """Measure the true ``passages`` of the window [t0, t1): misses, double-report
    handling, noise and false alarms. Returns them sorted by (noisy) time."""
    stats = stats if stats is not None else MeasurementStats()
    first = passages.kind == PASSAGE
    double = passages.kind == DOUBLE_REPORT
    stats.passages += int(first.sum())
    stats.double_reports += int(double.sum())
    keep = np.ones(len(passages), bool)
    if config.miss_rate > 0:
        missed = rng.random(len(passages)) < config.miss_rate
        stats.missed += int((missed & first).sum())
        keep &= ~missed
    if not config.double_reports:
        stats.double_reports_removed += int((double & keep).sum())
        keep &= ~double
    out = passages.subset(keep)
    n = len(out)
    if n and config.stamp_jitter > 0:
        out.time = out.time + rng.normal(0.0, config.stamp_jitter, n)
    if n and config.speed_noise > 0:
        out.speed = np.maximum(out.speed + rng.normal(0.0, config.speed_noise, n), MIN_SPEED)
    if n and config.length_noise > 0:
        out.length = np.maximum(out.length + rng.normal(0.0, config.length_noise, n), MIN_LENGTH)
    fa = false_alarms(config, lanes, t0, t1, rng)
    stats.false_alarms += len(fa)
    return Passages.concatenate([out, fa]).sorted()
