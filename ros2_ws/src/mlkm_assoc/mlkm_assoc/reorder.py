"""Detections from many topics back into stamp order, before they reach the stream tracker.

Each sensor's topic delivers in stamp order, but an executor takes one message per ready
topic in turn: with a backlog (a source publishing as fast as it can), the i-th message of
every sensor comes in together, so a downstream sensor's detections arrive up to a travel
time ahead of the upstream ones. The tracker only tolerates a small reordering, so this
buffer holds a detection while some sensor is still draining older ones (ROS-free):

* a sensor *blocks* a detection stamped ``t`` when its latest detection is stamped before
  ``t - margin``, arrived less than ``wait`` seconds (wall time) ago, and lagged behind the
  newest stamp seen by more than ``margin`` when it arrived: its topic is busy draining a
  backlog and may still hold older detections. A sensor that has been quiet for ``wait``
  seconds has nothing older in flight; one that was in step with the others when it last
  delivered (a source paced in real time, or faster) has nothing older either. A sensor
  counts as lagging until its second detection (its first tells nothing: the others may be
  ahead of it already), and one that has sent nothing yet counts as heard at the first
  detection (so the first ones wait ``wait`` for the other topics to start);
* the oldest held detection is released when no sensor blocks it, or after ``max_hold``
  seconds whatever happens.

Times are the receiving node's clock (arrival times, and its ticks while nothing arrives),
never the clock of whoever reads the buffer: a reader that fell behind, or a node whose
executor stalled, does not make a busy topic look quiet.

At real time, or at any pace the node keeps up with, every topic is in step, no sensor lags
by ``margin``, and a detection passes at once; reordering smaller than ``margin`` is left to
the tracker's own tolerance (1 s).
"""

from __future__ import annotations

import heapq
import math
from typing import Any


class ReorderBuffer:
    def __init__(
        self, n_sensors: int, margin: float = 0.8, wait: float = 0.05, max_hold: float = 1.0
    ) -> None:
        # [s] stamp time; below the tracker's reorder tolerance (1 s), and wide enough that a
        # short burst of the node at a high real-time factor, which spans several tenths of a
        # second of stamps, does not hold detections needlessly (docs/benchmarks.md)
        self.margin = margin
        self.wait = wait  # [s] wall time
        self.max_hold = max_hold  # [s] wall time
        self._last_stamp = [-math.inf] * n_sensors
        self._last_rx = [-math.inf] * n_sensors
        self._lagging = [True] * n_sensors  # behind the newest stamp at its last arrival
        self._heard = [False] * n_sensors
        self._newest = -math.inf
        self._heap: list[tuple[float, int, float, Any]] = []
        self._seq = 0
        self._started = False
        self.released_by_timeout = 0

    def __len__(self) -> int:
        return len(self._heap)

    def add(self, item: Any, sensor: int, stamp: float, rx: float) -> None:
        if not self._started:
            self._started = True
            self._last_rx = [rx] * len(self._last_rx)
        if stamp >= self._last_stamp[sensor]:
            self._last_stamp[sensor] = stamp
            self._lagging[sensor] = not self._heard[sensor] or stamp < self._newest - self.margin
            self._heard[sensor] = True
        self._newest = max(self._newest, stamp)
        self._last_rx[sensor] = max(self._last_rx[sensor], rx)
        heapq.heappush(self._heap, (stamp, self._seq, rx, item))
        self._seq += 1

    def release(self, now: float) -> list[Any]:
        """The detections that may go to the tracker now, in stamp order."""
        heap = self._heap
        if not heap:
            return []
        busy = [
            st
            for st, rx, lagging in zip(self._last_stamp, self._last_rx, self._lagging)
            if lagging and now - rx < self.wait
        ]
        floor = (min(busy) if busy else math.inf) + self.margin
        out = []
        while heap:
            stamp, _, rx, item = heap[0]
            if stamp > floor:
                if now - rx < self.max_hold:
                    break
                self.released_by_timeout += 1
            heapq.heappop(heap)
            out.append(item)
        return out

    def drain(self) -> list[Any]:
        """Everything held, in stamp order (the road went quiet, or a new road)."""
        out = [entry[3] for entry in sorted(self._heap)]
        self._heap.clear()
        return out
