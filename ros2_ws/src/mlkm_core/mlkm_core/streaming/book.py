"""Bookkeeping of the streaming tracker: detections, tracks, their latest detections and what
one call changed (``mlkm_core.streaming``)."""

from __future__ import annotations

import heapq

import numpy as np

from mlkm_core.streaming.config import CONFIRMED, FINAL, TENTATIVE, StreamUpdate, TrackUpdate
from mlkm_core.types import Detections

COUNTERS = (
    'pushed',
    'linked',
    'started',
    'late',
    'reordered',
    'rejected',
    'solves',
    'degraded',
    'failed_solves',
    'executor_errors',
    'committed',
    'assigned',
    'false_alarms',
    'revised',
    'final_tracks',
    'skipped_solves',
    'forced_commits',
)


class Det:
    __slots__ = ('key', 'sensor', 'stamp', 'velocity', 'lane', 'length', 'track', 'first')

    def __init__(self, key, sensor, stamp, velocity, lane, length) -> None:
        self.key, self.sensor, self.stamp, self.velocity = key, sensor, stamp, velocity
        self.lane, self.length = lane, length
        self.track = -1  # current track id (tentative or committed)
        self.first = -1  # key of the detection it was first linked after, -1: it started a track


def as_detections(rows: list[Det]) -> Detections:
    """The rows as Detections, with lane and length where any is known."""
    lane = np.array([d.lane for d in rows], np.int64)
    length = np.array([d.length for d in rows])
    return Detections(
        np.array([d.sensor for d in rows], np.int64),
        np.array([d.stamp for d in rows]),
        np.array([d.velocity for d in rows]),
        lane=lane if np.any(lane >= 0) else None,
        length=length if np.any(np.isfinite(length)) else None,
    )


def canon(d: Det) -> tuple[int, float, float, int]:
    return d.sensor, d.stamp, d.velocity, d.key


class TrackBook:
    """Tracks as sets of detection keys, the most downstream detection of each, and the
    changes of the current call (reported by ``_end``)."""

    def __init__(self, n_sensors: int, confirm_count: int) -> None:
        self._confirm = confirm_count
        self._dets: dict[int, Det] = {}
        self._tracks: dict[int, set[int]] = {}  # id -> keys of its detections
        self._n_committed: dict[int, int] = {}
        self._pending: set[int] = set()
        self._tails: list[set[int]] = [set() for _ in range(n_sensors)]
        self._tail_of: dict[int, tuple[int, int]] = {}  # track -> (key, station) of its tail
        # (stamp after which a tail can take no new detection, track, tail key): tails whose
        # time is up leave ``_tails`` (the immediate link's candidates) before their track
        # is finalised, which waits for the window solves
        self._sleepers: list[tuple[float, int, int]] = []
        self._next_id = 0
        self._committed_until = -np.inf
        self._begin()

    def _begin(self) -> None:
        self._changed: set[int] = set()
        self._gone: dict[int, np.ndarray] = {}
        self._unassigned: list[int] = []
        self._committed: list[tuple[int, int]] = []

    def _end(self) -> StreamUpdate:
        tracks = [TrackUpdate(t, FINAL, keys) for t, keys in sorted(self._gone.items())]
        for t in sorted(self._changed - set(self._gone)):
            if t in self._tracks:
                tracks.append(TrackUpdate(t, self._status(t), self._keys(t)))
        return StreamUpdate(
            tracks,
            np.array(self._unassigned, np.int64),
            self._committed_until,
            np.array(self._committed, np.int64).reshape(-1, 2),
        )

    def _status(self, tid: int) -> int:
        return CONFIRMED if len(self._tracks[tid]) >= self._confirm else TENTATIVE

    def _keys(self, tid: int) -> np.ndarray:
        dets = sorted((self._dets[k] for k in self._tracks[tid]), key=lambda d: (d.stamp, d.key))
        return np.array([d.key for d in dets], np.int64)

    def _new_track(self) -> int:
        tid = self._next_id
        self._next_id += 1
        self._tracks[tid] = set()
        self._n_committed[tid] = 0
        return tid

    def _drop_track(self, tid: int, keys: np.ndarray) -> None:
        self._tracks.pop(tid)
        self._n_committed.pop(tid)
        self._untail(tid)
        self._gone[tid] = keys
        self._changed.discard(tid)

    def _move(self, d: Det, tid: int) -> None:
        """Put ``d`` into track ``tid`` (-1: out of every track)."""
        old = d.track
        if old == tid:
            return
        if old >= 0:
            self._tracks[old].discard(d.key)
            self._changed.add(old)
        d.track = tid
        if tid >= 0:
            self._tracks[tid].add(d.key)
            self._changed.add(tid)

    def _untail(self, tid: int) -> None:
        tail = self._tail_of.pop(tid, None)
        if tail is not None:
            self._tails[tail[1]].discard(tid)

    def _retail(self, tid: int) -> None:
        """Recompute the most downstream detection of ``tid`` (drops the track when empty)."""
        self._untail(tid)
        members = self._tracks.get(tid)
        if members is None:
            return
        if not members:
            self._drop_track(tid, np.zeros(0, np.int64))
            return
        tail = max((self._dets[k] for k in members), key=lambda d: (d.sensor, d.stamp))
        self._tail_of[tid] = (tail.key, tail.sensor)
        self._tails[tail.sensor].add(tid)
        heapq.heappush(self._sleepers, (self._tail_due(tail), tid, tail.key))

    def _tail_due(self, tail: Det) -> float:
        """Stamp after which no new detection can be linked after ``tail`` (inf: never)."""
        return float('inf')

    def _sleep_tails(self, before: float) -> None:
        """Take the tails whose time was up before ``before`` out of the link candidates."""
        heap = self._sleepers
        while heap and heap[0][0] < before:
            _, tid, key = heapq.heappop(heap)
            tail = self._tail_of.get(tid)
            if tail is not None and tail[0] == key:
                self._tails[tail[1]].discard(tid)
