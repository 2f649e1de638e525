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
        return self.lane_counts is None or lane < self.lane_counts[s]

    def describe(
        self,
        reason: str,
        sensor_id: int,
        stamp_ns: int,
        velocity: float,
        lane: int = UNKNOWN_LANE,
        length: float = math.nan,
    ) -> str:
        """One line on a refused detection and why."""
        if reason in BOUNDS_REASONS:
            detail = self.bounds.describe(reason)
        elif reason == 'lane_out_of_range':
            s = self.index.get(sensor_id)
            known = self.lane_counts is not None and s is not None
            detail = (
                f'lane must be -1 (unknown) or in [0, {self.lane_counts[s] - 1}]'
                if known
                else 'lane must be -1 (unknown) or >= 0'
            )
        else:
            detail = reason
        return (
            f'sensor {sensor_id}, lane {lane}, stamp {stamp_ns} ns, velocity {velocity!r} '
            f'm/s, length {length!r} m: {detail}'
        )
