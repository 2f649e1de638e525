"""Physical bounds on a detection: what a road-side sensor can plausibly report.

A finite but absurd value (a velocity of 1e308 m/s, a stamp of 1e300 s) is not noise: fed to
an associator it can pull every other detection into one cluster, or make the solver fail.
The node and the offline CLI both check every detection against one :class:`Bounds` and
reject what falls outside with one of :data:`REASONS`. The node's stamps are ROS times
(``Bounds()``: [0, 2^31 - 1] s); a file's stamps are not (:data:`OFFLINE`: any stamp a clock
gives, such as seconds relative to an event, negative ones included).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Why a detection's values are refused, in the order they are checked.
REASONS = (
    'nan_velocity',
    'inf_velocity',
    'zero_velocity',
    'negative_velocity',
    'speed_out_of_range',
    'stamp_out_of_range',
    'length_out_of_range',
)


@dataclass(frozen=True)
class Bounds:
    """Accepted ranges (inclusive). Defaults cover road traffic, stop-and-go included."""

    min_speed: float = 0.01  # slowest plausible passage [m/s]
    max_speed: float = 150.0  # fastest plausible passage (540 km/h) [m/s]
    min_stamp: float = 0.0  # earliest passage time [s]
    max_stamp: float = 2.0**31 - 1  # latest passage time (int32 seconds of a ROS stamp) [s]
    min_length: float = 0.1  # shortest plausible measured vehicle length [m]
    max_length: float = 100.0  # longest plausible one (oversize transports included) [m]

    def __post_init__(self) -> None:
        values = (
            self.min_speed,
            self.max_speed,
            self.min_stamp,
            self.max_stamp,
            self.min_length,
            self.max_length,
        )
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f'bounds must be finite: {self}')
        if not 0.0 < self.min_speed < self.max_speed:
            raise ValueError(f'need 0 < min_speed < max_speed, got {self}')
        if not self.min_stamp < self.max_stamp:
            raise ValueError(f'need min_stamp < max_stamp, got {self}')
        if not 0.0 < self.min_length < self.max_length:
            raise ValueError(f'need 0 < min_length < max_length, got {self}')

    def refuse(self, stamp: float, velocity: float, length: float = math.nan) -> str | None:
        """The reason one detection (stamp [s], velocity [m/s], measured vehicle length [m],
        NaN or 0 = not measured) is refused, or None."""
        if math.isnan(velocity):
            return 'nan_velocity'
        if math.isinf(velocity):
            return 'inf_velocity'
        if velocity == 0.0:
            return 'zero_velocity'
        if velocity < 0.0:
            return 'negative_velocity'
        if not self.min_speed <= velocity <= self.max_speed:
            return 'speed_out_of_range'
        if not (math.isfinite(stamp) and self.min_stamp <= stamp <= self.max_stamp):
            return 'stamp_out_of_range'
        if not (
            math.isnan(length) or length == 0.0 or self.min_length <= length <= self.max_length
        ):
            return 'length_out_of_range'
        return None

    def refuse_all(
        self, stamps: np.ndarray, velocities: np.ndarray, lengths: np.ndarray | None = None
    ) -> list[str | None]:
        """:meth:`refuse` for every row; the arrays must have the same length."""
        if lengths is None:
            lengths = np.full(len(stamps), math.nan)
        return [
            self.refuse(float(t), float(v), float(n))
            for t, v, n in zip(stamps, velocities, lengths, strict=True)
        ]

    def describe(self, reason: str) -> str:
        """A sentence for users: what the accepted range is for ``reason``."""
        if reason == 'speed_out_of_range':
            return f'velocity outside [{self.min_speed:g}, {self.max_speed:g}] m/s'
        if reason == 'stamp_out_of_range':
            return f'stamp outside [{self.min_stamp:g}, {self.max_stamp:g}] s'
        if reason == 'length_out_of_range':
            return (
                f'vehicle length outside [{self.min_length:g}, {self.max_length:g}] m '
                '(NaN or 0: not measured)'
            )
        return reason.replace('_', ' ')


#: The bounds of a detections file (``mlkm associate``), whose stamps are not ROS times:
#: +-1e12 s (31,700 years) holds any clock's seconds, relative (negative too) or Unix time,
#: while a stamp keeps sub-millisecond resolution in float64 and a stamp like 1e300 s, which
#: would overflow the associators' squared time differences, is refused.
OFFLINE = Bounds(min_stamp=-1e12, max_stamp=1e12)
