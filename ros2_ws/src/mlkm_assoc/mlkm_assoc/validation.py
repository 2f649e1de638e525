"""Validation of single detections against the bounds and the layout (ROS-free).

A detection's velocity, stamp and measured length (NaN = not measured) must lie inside the
physical :class:`~mlkm_core.bounds.Bounds`, its sensor id must be in the layout and its
position match that sensor's, its lane be -1 (unknown) or, where the layout gives the
sensor's lane count, below it; which detections are the same report (a duplicate) is
decided by :func:`mlkm_core.types.duplicate_key`, the one rule of the node and the offline
CLI. The episode bookkeeping (:mod:`mlkm_assoc.assembly`) asks this module and counts the
reasons.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import NamedTuple

import numpy as np

from mlkm_core.bounds import REASONS as BOUNDS_REASONS
from mlkm_core.bounds import Bounds
from mlkm_core.types import UNKNOWN_LANE, Layout

#: Reasons a detection is rejected (not associated).
REJECT_REASONS = (
    *BOUNDS_REASONS,
    'unknown_sensor',
    'position_mismatch',
    'lane_out_of_range',
    'duplicate',
    'outside_episode',
    'after_episode_final',
    'buffer_full',
)
#: Tolerance between a detection's position and its sensor's layout position [m].
POSITION_TOLERANCE = 1e-3
NS_PER_S = 1_000_000_000


class Received(NamedTuple):
    """One detection as received, before it is checked and placed."""

    sensor_id: int
    stamp_ns: int
    position: float  # [m]
    velocity: float  # [m/s]
    lane: int = UNKNOWN_LANE  # -1: unknown
    length: float = math.nan  # measured vehicle length [m]; NaN: not measured
    received: float = 0.0  # monotonic time of arrival [s]


class HoldsEarly:
    """Mixin of the episode assembly and stream mode's ingest: a detection before the layout
    is known is refused with what could be checked without the layout, or as
    ``buffer_full`` without room, else held until the layout comes (counted
    ``before_layout``). The class counts in ``handled`` and refuses with ``_reject``."""

    handled: Counter[str]

    def _reject(self, reason: str, raw: Received) -> None:
        raise NotImplementedError

    def _place(self, raw: Received) -> None:
        raise NotImplementedError

    def _place_held(self, held: list[Received]) -> None:
        """Place the detections that were held, in arrival order (once their layout or
        episode is known)."""
        for raw in held:
            self._place(raw)

    def _hold_early(
        self, raw: Received, reason: str | None, room: bool, hold: list[Received]
    ) -> None:
        if reason is not None:
            self._reject(reason, raw)
        elif not room:
            self._reject('buffer_full', raw)
        else:
            self.handled['before_layout'] += 1
            hold.append(raw)


def same_layout(a: Layout, b: Layout) -> bool:
    """Whether two layouts describe the same road and sensors."""
    return (
        a.road_length == b.road_length
        and a.names == b.names
        and np.array_equal(a.sensor_ids, b.sensor_ids)
        and np.array_equal(a.positions, b.positions)
    )


class DetectionCheck:
    """The bounds and the current layout's sensors: refuses invalid detections with a reason
    of :data:`REJECT_REASONS` and describes it."""

    def __init__(self, bounds: Bounds) -> None:
        self.bounds = bounds
        self.index: dict[int, int] = {}  # sensor id -> sensor index in the layout
        self.positions: list[float] = []
        self.lane_counts: tuple[int, ...] | None = None

    def set_layout(self, layout: Layout, lane_counts: tuple[int, ...] | None) -> None:
        self.index = {int(s): i for i, s in enumerate(layout.sensor_ids)}
        self.positions = [float(p) for p in layout.positions]
        self.lane_counts = lane_counts

    def refuse_unplaced(self, stamp_ns: int, velocity: float, lane: int, length: float):
        """What can be checked before a layout is known; the reason or None."""
        reason = self.bounds.refuse(stamp_ns / NS_PER_S, velocity, length)
        if reason is None and lane < UNKNOWN_LANE:
            reason = 'lane_out_of_range'
        return reason

    def check(self, raw: Received) -> tuple[int, str | None]:
        """(sensor index, None) for a valid detection; (-1, 'unknown_sensor') or (sensor
        index, the reason) for a refused one."""
        s = self.index.get(raw.sensor_id)
        if s is None:
            return -1, 'unknown_sensor'
        return s, self.refuse(s, raw.stamp_ns, raw.position, raw.velocity, raw.lane, raw.length)

    def refuse(
        self, s: int, stamp_ns: int, position: float, velocity: float, lane: int, length: float
    ) -> str | None:
        """The reason to refuse a detection of sensor index ``s``, or None."""
        reason = self.bounds.refuse(stamp_ns / NS_PER_S, velocity, length)
        if reason is None and not abs(position - self.positions[s]) <= POSITION_TOLERANCE:
            reason = 'position_mismatch'
        if reason is None and not self.lane_ok(s, lane):
            reason = 'lane_out_of_range'
        return reason

    def lane_ok(self, s: int, lane: int) -> bool:
        if lane == UNKNOWN_LANE:
            return True
        if lane < 0:
            return False
        # a count of 0: a network's station of unknown lanes (RoadNetwork.station_lanes)
        return self.lane_counts is None or not 0 < self.lane_counts[s] <= lane

    def describe(self, reason: str, raw: Received) -> str:
        """One line on a refused detection and why."""
        if reason in BOUNDS_REASONS:
            detail = self.bounds.describe(reason)
        elif reason == 'lane_out_of_range':
            s = self.index.get(raw.sensor_id)
            known = self.lane_counts is not None and s is not None
            detail = (
                f'lane must be -1 (unknown) or in [0, {self.lane_counts[s] - 1}]'
                if known
                else 'lane must be -1 (unknown) or >= 0'
            )
        else:
            detail = reason
        return (
            f'sensor {raw.sensor_id}, lane {raw.lane}, stamp {raw.stamp_ns} ns, velocity '
            f'{raw.velocity!r} m/s, length {raw.length!r} m: {detail}'
        )
