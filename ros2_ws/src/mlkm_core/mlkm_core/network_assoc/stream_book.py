"""The track book of the network stream: which held detection is in which track, and what a
window solve, a commit and the end of a track do to it.

``TrackBook`` keeps the held detections, the open tracks (their keys in stamp order), the
commits and the calibration history, and turns each change into the ``StreamUpdate`` the
stream's contract promises (``Changes``). The tracker (``network_assoc.stream``) decides
what to link and when; the book applies it:

* **Stitching.** Committed links never change. A window track holding committed detections
  continues the committed track of its latest one, if that track has not been continued by
  a later committed detection; its uncommitted detections join it. A window track without
  committed detections keeps the id its detections had (no other group claimed it) or gets
  a new one. A detection a window leaves alone is committed unassigned; until its commit it
  keeps the track of its own it started (its vehicle may be seen next after the boundary).
* **Commit and end.** Detections older than the horizon are committed with their track. A
  track whose detections are all committed and whose last one is more than a lag older than
  the horizon is FINAL; committed detections older than the context are forgotten (they
  stay in the calibration history).
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

from mlkm_core.network_assoc.stream_window import Row
from mlkm_core.streaming.config import CONFIRMED, FINAL, TENTATIVE, StreamUpdate, TrackUpdate


@dataclass(frozen=True)
class NetworkStreamConfig:
    """Settings of :class:`NetworkStreamTracker`; every time is stamp time [s]."""

    lag: float = 15.0  # [s] the shortest commit lag (one road's default)
    lag_factor: float = 2.0  # [-] the lag grows to this times the p95 link travel time
    solve_interval: float = 10.0  # [s] a window is solved at every multiple of this
    reorder_tolerance: float = 1.0  # [s] pushes may come this much out of stamp order
    context: float = 120.0  # [s] committed detections given to each window before the lag
    calibration_size: int = 2000  # committed detections the model is fitted on [-]
    calibration_every: int = 6  # solves between two fits of the model [-]
    # rows the model must have been fitted on before anything is committed: the first
    # windows of a road filling up hold too few links to fit the hops and junctions [-]
    warmup_rows: int = 500
    confirm_count: int = 2  # detections that make a track CONFIRMED [-]

    def __post_init__(self) -> None:
        for name in ('lag', 'solve_interval'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f'{name} must be a finite number > 0, got {value!r}')
        for name in ('lag_factor', 'reorder_tolerance', 'context'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f'{name} must be a finite number >= 0, got {value!r}')
        if (
            min(self.calibration_size, self.warmup_rows) < 0
            or min(self.calibration_every, self.confirm_count) < 1
        ):
            raise ValueError(f'counts out of range: {self!r}')


class TrackBook:
    """The held detections and open tracks of the network stream (module docstring)."""

    def __init__(self, config: NetworkStreamConfig) -> None:
        self.config = config
        self._det: dict[int, Row] = {}  # the detections still held, by key
        self._track: dict[int, int] = {}  # key -> its track, -1 unassigned (held ones)
        self._alone: set[int] = set()  # held keys in no track and not committed
        self._members: dict[int, list[int]] = {}  # open track -> its keys, stamp order
        self._last_committed: dict[int, int] = {}  # open track -> its latest committed key
        self._committed: set[int] = set()  # held keys whose link is committed
        self._revised: set[int] = set()  # held keys moved after their first track
        self._history: deque = deque(maxlen=config.calibration_size)
        self._counts: Counter[str] = Counter()
        self._next_id = 0
        self.committed_until = -math.inf
        self.lag = config.lag

    def _set_track(self, key: int, tid: int) -> None:
        self._track[key] = tid
        if tid < 0 and key not in self._committed:
            self._alone.add(key)
        else:
            self._alone.discard(key)

    # --- windows: snapshot, solve (here or beside), apply ---------------------------------
    def _leave(self, key: int, out: Changes) -> None:
        """Take a detection out of its track (a track left empty ends)."""
        tid = self._track[key]
        self._members[tid].remove(key)
        self._set_track(key, -1)
        if self._members[tid]:
            out.tracks[tid] = self._view(tid)
        else:
            self._drop(tid, out)

    def _drop(self, tid: int, out: Changes) -> None:
        """A track every detection of which moved elsewhere: reported FINAL with no keys."""
        self._members.pop(tid, None)
        self._last_committed.pop(tid, None)
        out.tracks[tid] = TrackUpdate(tid, FINAL, np.zeros(0, np.int64))

    def _stitch(
        self, keys: list[int], labels: np.ndarray, horizon: float, out: Changes
    ) -> set[int]:
        """Move the window's uncommitted detections to the tracks of its solve (module
        docstring); the tracks that changed. A detection the window leaves alone that is
        not committed at ``horizon`` [s] keeps a track of its own where it has one: the
        vehicle's next detection may come after the window's boundary."""
        groups: dict[int, list[int]] = {}
        for k, lab in zip(keys, labels.tolist(), strict=True):
            if k not in self._committed:
                groups.setdefault(lab, []).append(k)
        anchors: dict[int, int] = {}  # window label -> its latest committed key
        for k, lab in zip(keys, labels.tolist(), strict=True):
            if k in self._committed and lab >= 0:
                anchors[lab] = k  # keys are in stamp order
        claimed: set[int] = set()
        moves: dict[int, int] = {}
        for lab, free in sorted(groups.items(), key=lambda g: self._det[g[1][0]][1]):
            tid = -1
            if lab >= 0:
                anchor = anchors.get(lab)
                if anchor is not None:
                    own = self._track[anchor]
                    if self._last_committed.get(own) == anchor and own not in claimed:
                        tid = own
                if tid < 0:
                    before = self._track[free[0]]
                    reusable = before >= 0 and before not in claimed
                    tid = before if reusable and before not in self._last_committed else -1
                    if tid < 0:
                        tid, self._next_id = self._next_id, self._next_id + 1
                claimed.add(tid)
            for k in free:
                moves[k] = tid
        for k in groups.get(-1, []):  # alone in the window but not committed yet: a start
            old = self._track[k]
            if self._det[k][1] >= horizon and old >= 0 and old not in claimed:
                others = [m for m in self._members[old] if m != k]
                if all(m in moves and moves[m] != old for m in others):
                    moves[k] = old  # stays a track of its own (TENTATIVE), its id kept
        touched = set()
        for k, tid in moves.items():
            old = self._track[k]
            if old != tid:
                if old >= 0:
                    self._revised.add(k)
                    self._members[old].remove(k)
                    touched.add(old)
                if tid >= 0:
                    self._members.setdefault(tid, []).append(k)
                    touched.add(tid)
                else:
                    out.unassigned.append(k)
                self._set_track(k, tid)
        for tid in touched:
            keys_of = self._members.get(tid, [])
            if not keys_of:  # every detection moved elsewhere: the track is gone
                self._drop(tid, out)
                continue
            keys_of.sort(key=lambda k: (self._det[k][1], k))
            out.tracks[tid] = self._view(tid)
        return touched

    def _view(self, tid: int, status: int | None = None) -> TrackUpdate:
        keys_of = self._members[tid]
        if status is None:
            status = CONFIRMED if len(keys_of) >= self.config.confirm_count else TENTATIVE
        return TrackUpdate(tid, status, np.array(keys_of, np.int64))

    def _commit(self, horizon: float, out: Changes) -> None:
        self.committed_until = max(self.committed_until, horizon)
        for k, row in list(self._det.items()):
            if row[1] < horizon and k not in self._committed:
                self._committed.add(k)
                self._alone.discard(k)
                tid = self._track[k]
                out.commit(k, tid)
                self._counts['committed'] += 1
                self._counts['revised'] += k in self._revised
                self._counts['false_alarms'] += tid < 0
                self._revised.discard(k)
                if tid >= 0:
                    self._last_committed[tid] = k
        context_from = horizon - self.config.context
        for tid in list(self._members):
            keys_of = self._members[tid]
            if all(k in self._committed for k in keys_of):
                if self._det[keys_of[-1]][1] < horizon - self.lag:
                    self._end(tid, out)
        for k in [k for k in self._committed if self._det[k][1] < context_from]:
            if self._track[k] < 0 or self._track[k] not in self._members:
                self._forget(k)

    def _end(self, tid: int, out: Changes) -> None:
        out.tracks[tid] = self._view(tid, FINAL)
        self._counts['final_tracks'] += 1
        for k in self._members.pop(tid):
            if k in self._committed:
                self._forget(k)
        self._last_committed.pop(tid, None)

    def _forget(self, k: int) -> None:
        """Drop a committed detection; it stays in the calibration history."""
        row = self._det.pop(k, None)
        if row is not None:
            self._history.append(row)
        self._track.pop(k, None)
        self._committed.discard(k)
        self._alone.discard(k)


class Changes:
    """The updates of one push or flush, merged."""

    def __init__(self) -> None:
        self.tracks: dict[int, TrackUpdate] = {}
        self.unassigned: list[int] = []
        self.committed: list[tuple[int, int]] = []

    def commit(self, key: int, track: int) -> None:
        self.committed.append((key, track))

    def update(self, committed_until: float) -> StreamUpdate:
        pairs = np.array(self.committed, np.int64).reshape(-1, 2)
        return StreamUpdate(
            tracks=list(self.tracks.values()),
            unassigned=np.array(self.unassigned, np.int64),
            committed_until=committed_until,
            committed=pairs,
        )
