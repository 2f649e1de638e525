"""Stream mode's input: every detection is checked as in episodes mode (the physical bounds,
a known sensor at its position, a lane the station has; ``validation.DetectionCheck``) and
for duplicates among the detections not yet committed, numbered and sent to the tracker
process. ROS-free and cheap per detection.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable

from mlkm_assoc.validation import NS_PER_S, DetectionCheck, HoldsEarly, Received
from mlkm_core.bounds import REASONS as BOUNDS_REASONS
from mlkm_core.bounds import Bounds
from mlkm_core.types import Layout, duplicate_key

#: Reasons a detection is rejected in stream mode (a subset of episodes mode's).
REJECT_REASONS = (
    *BOUNDS_REASONS,
    'unknown_sensor',
    'position_mismatch',
    'lane_out_of_range',
    'duplicate',
    'buffer_full',
)


class StreamIngest(HoldsEarly):
    """Validation, numbering and duplicate detection (ROS-free, cheap per detection)."""

    def __init__(
        self,
        bounds: Bounds,
        max_buffered: int,
        send: Callable[[tuple], None],
        on_reject: Callable[[str, str], None] | None = None,
    ) -> None:
        self._check = DetectionCheck(bounds)
        self._max_buffered = max_buffered
        self._send = send
        self._on_reject = on_reject
        self.layout: Layout | None = None
        self._held: list[Received] = []
        # duplicate keys of the detections not yet committed, oldest first
        self._seen: set[tuple] = set()
        self._seen_order: deque[tuple[int, tuple]] = deque()
        self.next_key = 0
        self.received = 0
        self.accepted = 0
        self.rejected: Counter[str] = Counter()
        self.handled: Counter[str] = Counter()
        self.last_rx: float | None = None

    @property
    def bounds(self) -> Bounds:
        return self._check.bounds

    @bounds.setter
    def bounds(self, bounds: Bounds) -> None:
        """New bounds (live parameter changes), from the next detection on."""
        self._check.bounds = bounds

    def set_layout(
        self,
        layout: Layout,
        lane_counts: tuple[int, ...] | None,
        entries: tuple[float, ...],
        exits: tuple[float, ...],
        shard=None,
    ) -> None:
        """``shard``: the tracker is a shard of a longer road (a ``ShardRole``) and
        ``layout`` its region."""
        self.layout = layout
        self._check.set_layout(layout, lane_counts)
        self._seen.clear()
        self._seen_order.clear()
        self._send(('layout', layout, entries, exits, shard))
        held, self._held = self._held, []
        self._place_held(held)

    def add(
        self,
        sensor_id: int,
        stamp_ns: int,
        position: float,
        velocity: float,
        lane: int,
        length: float,
        now: float,
    ) -> None:
        self.received += 1
        self.last_rx = now
        raw = Received(sensor_id, stamp_ns, position, velocity, lane, length, now)
        if self.layout is None:
            # the bounds only: the lane is checked once the layout says the station's lanes
            reason = self.bounds.refuse(stamp_ns / NS_PER_S, velocity, length)
            self._hold_early(raw, reason, len(self._held) < self._max_buffered, self._held)
            return
        self._place(raw)

    def committed(self, committed_until_ns: int) -> None:
        """Forget the duplicate keys of detections stamped before ``committed_until_ns``:
        a repeat of one of them reaches the tracker, which leaves it unassigned (late)."""
        order, seen = self._seen_order, self._seen
        while order and order[0][0] < committed_until_ns:
            seen.discard(order.popleft()[1])

    @property
    def held(self) -> int:
        return len(self._held)

    def _place(self, raw: Received) -> None:
        s, reason = self._check.check(raw)
        if s < 0:
            self._reject(reason, raw)
            return
        sensor_id, stamp_ns, position, velocity, lane, length, now = raw
        if reason is None:
            dup = duplicate_key(sensor_id, lane, stamp_ns, velocity)
            if dup in self._seen:
                reason = 'duplicate'
            else:
                self._seen.add(dup)
                self._seen_order.append((stamp_ns, dup))
        if reason is not None:
            self._reject(reason, raw)
            return
        length = math.nan if length == 0.0 else length
        item = ('det', self.next_key, s, sensor_id, stamp_ns, velocity, position, lane, length)
        if self._send((*item, now)) is False:  # the tracker process's queue is full
            self._seen.discard(dup)
            self._reject('buffer_full', raw)
            return
        self.accepted += 1
        self.next_key += 1

    def _reject(self, reason: str, raw: Received) -> None:
        self.rejected[reason] += 1
        if self._on_reject is not None:
            detail = self.bounds.describe(reason) if reason in BOUNDS_REASONS else reason
            self._on_reject(
                reason,
                f'sensor {raw.sensor_id}, stamp {raw.stamp_ns} ns, velocity {raw.velocity!r} '
                f'm/s: {detail}',
            )
