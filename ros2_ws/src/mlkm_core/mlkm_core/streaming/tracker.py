"""``StreamTracker``: the fixed-lag streaming associator (mechanism in ``mlkm_core.streaming``)."""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Sequence

import numpy as np

from mlkm_core.associators import make_associator
from mlkm_core.associators.motion import MotionParams
from mlkm_core.streaming.book import COUNTERS, Det, TrackBook, as_detections, canon
from mlkm_core.streaming.config import (
    StreamConfig,
    StreamUpdate,
)
from mlkm_core.streaming.motion import calibrate_on, link_weights, overdue_at
from mlkm_core.streaming.window import owners, solve_window
from mlkm_core.types import UNKNOWN_LANE, Layout

#: the counters of ``StreamTracker.stats``
#: methods given the detections of recently ended tracks as context (they calibrate their
#: motion model on their input; the K-means methods would cluster the context too)
CONTEXT_METHODS = ('assignment', 'multiframe', 'mlkm_robust')
#: ``anchor_track`` of a context row in a window solve
CONTEXT = -2


class StreamTracker(TrackBook):
    """Associates an endless stream of detections into tracks with a fixed commit lag."""

    def __init__(
        self,
        layout: Layout,
        config: StreamConfig = StreamConfig(),  # noqa: B008  (frozen, immutable)
        entries: Sequence[float] = (),
        exits: Sequence[float] = (),
    ) -> None:
        super().__init__(layout.n_sensors, config.confirm_count)
        self.layout = layout
        self.config = config
        self._associator = make_associator(config.method, config.associator_config())
        pos = layout.positions
        n_s = layout.n_sensors
        # a station right after an on-ramp (or the first) may see births; a station right
        # before an off-ramp may be the last one a vehicle passes
        self._after_entry = np.zeros(n_s, bool)
        self._after_entry[0] = True
        self._before_exit = np.zeros(n_s, bool)
        self._before_exit[-1] = True
        for name, values in (('entries', entries), ('exits', exits)):
            for x in values:
                if not math.isfinite(float(x)):
                    raise ValueError(f'{name} positions must be finite, got {x!r}')
        for x in entries:
            s = int(np.searchsorted(pos, float(x)))
            if s < n_s:
                self._after_entry[s] = True
        for x in exits:
            s = int(np.searchsorted(pos, float(x))) - 1
            if s >= 0:
                self._before_exit[s] = True
        self._context: deque = deque(maxlen=config.context_size)
        self._history: deque = deque(maxlen=config.calibration_size)
        self._params = MotionParams()
        self._calibrated_at: int | None = None
        self._next_k: int | None = None
        self._solved = False
        self._newest = -math.inf
        self._stats: Counter = Counter()

    # ----------------------------------------------------------------- public surface
    @property
    def working_set(self) -> int:
        """Detections held: uncommitted ones and those of tracks not yet final."""
        return len(self._dets)

    @property
    def committed_until(self) -> float:
        return self._committed_until

    @property
    def params(self) -> MotionParams:
        """The motion model calibrated on the stream so far."""
        return self._params

    def stats(self) -> dict:
        """Counters: pushed, linked, started, late, reordered, committed, assigned,
        false_alarms, revised, solves, degraded, final_tracks, rejected; and the gauges
        working_set, open_tracks and revision_rate: revised / committed, the share of
        committed detections whose link first published (the detection it followed in its
        track, or none) changed before the commit."""
        out = {name: self._stats[name] for name in COUNTERS}
        out['working_set'] = self.working_set
        out['open_tracks'] = len(self._tracks)
        out['revision_rate'] = out['revised'] / out['committed'] if out['committed'] else 0.0
        return out

    def push(
        self,
        key: int,
        sensor_index: int,
        stamp: float,
        velocity: float,
        lane: int = UNKNOWN_LANE,
        length: float = math.nan,
    ) -> StreamUpdate:
        """Link one detection at once; revise and commit what its stamp lets (module doc)."""
        key, sensor_index, stamp, velocity = self._validate(key, sensor_index, stamp, velocity)
        self._stats['pushed'] += 1
        self._begin()
        if stamp < self._committed_until:
            self._stats['late'] += 1
            self._unassigned.append(key)
            self._committed.append((key, -1))
            return self._end()
        if self._solved and stamp < (self._next_k - 1) * self.config.solve_interval:
            self._stats['reordered'] += 1  # a solve that should have seen it is done
        first_k = math.floor(stamp / self.config.solve_interval) + 1
        if not self._solved:
            self._next_k = first_k if self._next_k is None else min(self._next_k, first_k)
        self._newest = max(self._newest, stamp)
        self._advance()
        d = Det(key, sensor_index, stamp, velocity, int(lane), float(length))
        self._dets[key] = d
        self._pending.add(key)
        tid, d.first = self._link_now(d)
        if tid >= 0:
            self._stats['linked'] += 1
        else:
            self._stats['started'] += 1
            tid = self._new_track()
        self._move(d, tid)
        self._retail(tid)
        return self._end()

    def flush(self) -> StreamUpdate:
        """Commit everything and finalise every track (the road fell quiet, or input ended)."""
        self._begin()
        if self._dets:
            self._solve(None)
        self._committed_until = max(self._committed_until, self._newest)
        if math.isfinite(self._newest):
            self._next_k = math.floor(self._newest / self.config.solve_interval) + 1
            self._solved = True
        return self._end()

    # ----------------------------------------------------------------- input
    def _validate(self, key, sensor_index, stamp, velocity) -> tuple[int, int, float, float]:
        problem = None
        try:
            key, sensor_index = int(key), int(sensor_index)
            stamp, velocity = float(stamp), float(velocity)
        except (TypeError, ValueError) as exc:
            problem = f'not a number: {exc}'
        else:
            if key in self._dets:
                problem = f'key {key} is already held'
            elif not 0 <= sensor_index < self.layout.n_sensors:
                problem = (
                    f'sensor_index {sensor_index} outside the layout '
                    f'(0..{self.layout.n_sensors - 1})'
                )
            elif not math.isfinite(stamp):
                problem = f'stamp must be finite, got {stamp!r}'
            elif not (math.isfinite(velocity) and velocity > 0):
                problem = f'velocity must be finite and > 0, got {velocity!r}'
        if problem:
            self._stats['rejected'] += 1
            raise ValueError(f'detection refused: {problem}')
        return key, sensor_index, stamp, velocity

    # ----------------------------------------------------------------- immediate link
    def _link_now(self, d: Det) -> tuple[int, int]:
        """(track, key of the detection ``d`` follows in it) by the gated pairwise prediction,
        or (-1, -1) for a new track. Candidates: the open tracks whose latest detection lies
        1 to 1 + max_skip stations upstream, and those whose latest detection lies up to that
        far downstream but that have no detection at d's station (stamps out of road order
        under noise, or a miss filled in), predicted from their detection just upstream."""
        p = self._params
        s = d.sensor
        cands = []
        for j in range(max(0, s - 1 - p.max_skip), min(self.layout.n_sensors, s + 2 + p.max_skip)):
            for tid in self._tails[j] if j != s else ():
                if j < s:
                    prev = self._dets[self._tail_of[tid][0]]
                    if prev.stamp < d.stamp:
                        cands.append((tid, prev))
                    continue
                members = [self._dets[k] for k in self._tracks[tid]]
                if any(m.sensor == s for m in members):
                    continue
                up = [m for m in members if m.sensor < s]
                if up:
                    cands.append((tid, max(up, key=lambda m: (m.sensor, m.stamp))))
        if not cands:
            return -1, -1
        tails = tuple([getattr(t, f) for _, t in cands] for f in ('sensor', 'stamp', 'velocity'))
        birth = p.miss_cost if self._after_entry[s] else p.new_cost
        w = link_weights(p, self.layout, tails, s, d.stamp, d.velocity, birth)
        best = int(np.argmin(w))
        return (cands[best][0], cands[best][1].key) if w[best] < 0 else (-1, -1)

    # ----------------------------------------------------------------- revision and commit
    def _advance(self) -> None:
        """Solve every boundary the newest stamp has passed by the reorder tolerance.

        Boundaries whose window is empty only end tracks; a run of them is skipped to the
        first one with a window (or the last passed), ending first the tracks that the
        skipped boundaries would have ended, so the outcome is that of solving each.
        """
        c = self.config
        if self._next_k is None:
            return
        last_k = math.floor((self._newest - c.reorder_tolerance) / c.solve_interval)
        while self._next_k <= last_k:
            oldest = min((self._dets[k].stamp for k in self._pending), default=math.inf)
            first_k = math.floor(oldest / c.solve_interval) + 1 if oldest < math.inf else last_k
            target = min(max(first_k, self._next_k), last_k)
            if target > self._next_k:
                skipped = (target - 1) * c.solve_interval
                self._committed_until = max(self._committed_until, skipped - c.lag)
                self._finalize(skipped, False)
                self._next_k = target
            self._solve(self._next_k)
            self._next_k += 1

    def _anchors(self) -> list[tuple[Det, int, bool]]:
        """(detection, track, is the track's last) of each open track's last committed ones."""
        out = []
        depth = self.config.anchor_depth
        for tid, members in self._tracks.items():
            if not self._n_committed[tid]:
                continue
            done = sorted(
                (self._dets[k] for k in members if k not in self._pending),
                key=lambda d: (d.sensor, d.stamp),
            )[-depth:]
            out += [(d, tid, i == len(done) - 1) for i, d in enumerate(done)]
        return out

    def _solve(self, k: int | None) -> None:
        """Re-solve the window below boundary k (None: everything, at a flush), commit what
        fell out of the lag and finalise the tracks that ended."""
        c = self.config
        final = k is None
        bound = math.inf if final else k * c.solve_interval
        cutoff = math.inf if final else bound - c.lag
        window = sorted(
            (self._dets[key] for key in self._pending if self._dets[key].stamp < bound),
            key=canon,
        )
        self._solved = True
        if window:
            self._stats['solves'] += 1
            anchors = sorted(self._anchors(), key=lambda a: canon(a[0]))
            context = list(self._context) if self.config.method in CONTEXT_METHODS else []
            anchors = [(d, CONTEXT, False) for d in context] + anchors
            rows = [a[0] for a in anchors] + window
            dets = as_detections(rows)
            if not final:
                self._calibrate(k, window)
            labels, degraded, failed = solve_window(self._associator, self.layout, dets)
            self._stats['degraded'] += degraded
            self._stats['failed_solves'] += failed
            n_a = len(anchors)
            anchor_track = np.array([a[1] for a in anchors] + [-1] * len(window), np.int64)
            last = np.array([a[2] for a in anchors] + [False] * len(window), bool)
            occupied = {
                tid: {self._dets[k].sensor for k in self._tracks[tid] if k not in self._pending}
                for tid in set(anchor_track[:n_a].tolist()) - {CONTEXT}
            }
            slack = 6 * math.sqrt(2) * self._params.stamp_noise
            own, groups = owners(
                labels, dets.sensor_index, dets.stamp, anchor_track, last, occupied, slack
            )
            self._apply(window, own[n_a:], [g - n_a for g in groups])
            self._commit([d for d in window if d.stamp < cutoff], bound)
        if not final:  # a flush commits up to the newest stamp (``flush``)
            self._committed_until = max(self._committed_until, cutoff)
        self._finalize(bound, final)

    def _apply(self, window: list[Det], own: np.ndarray, groups: list[np.ndarray]) -> None:
        """Move the window's detections to the tracks of the solve."""
        target = {d.key: int(t) for d, t in zip(window, own, strict=True) if t >= 0}
        claimed = set(target.values())
        groups = sorted(groups, key=lambda g: min((window[i].stamp, window[i].sensor) for i in g))
        for g in groups:
            votes = Counter(
                window[i].track
                for i in g
                if window[i].track >= 0
                and not self._n_committed.get(window[i].track, 1)
                and window[i].track not in claimed
            )
            if votes:
                tid = min(votes, key=lambda t: (-votes[t], t))
            else:
                tid = self._new_track()
            claimed.add(tid)
            for i in g:
                target[window[i].key] = tid
        touched = set()
        for d in window:
            touched.add(d.track)
            self._move(d, target[d.key])
            touched.add(d.track)
        for tid in touched:
            self._retail(tid)

    def _commit(self, due: list[Det], bound: float) -> None:
        """Commit ``due`` (canonical order): a detection whose track has another detection
        below the boundary keeps it for good, one alone is a false alarm (-1)."""
        touched = set()
        for d in due:
            tid = d.track
            members = [
                m
                for m in (self._dets[k] for k in self._tracks[tid])
                if m.key not in self._pending or m.stamp < bound
            ]
            self._pending.discard(d.key)
            self._stats['committed'] += 1
            before = [m for m in members if (m.sensor, m.stamp) < (d.sensor, d.stamp)]
            link = max(before, key=lambda m: (m.sensor, m.stamp)).key if before else -1
            if len(members) >= 2:
                label = tid
                self._n_committed[tid] += 1
                self._stats['assigned'] += 1
            else:
                label = -1
                self._move(d, -1)
                del self._dets[d.key]
                touched.add(tid)
                self._unassigned.append(d.key)
                self._stats['false_alarms'] += 1
            if (link if label >= 0 else -1) != d.first:  # the link first published changed
                self._stats['revised'] += 1
            self._committed.append((d.key, label))
            self._history.append((d.sensor, d.stamp, d.velocity))
        for tid in touched:
            self._retail(tid)

    def _due(self, tail: Det) -> float:
        """Stamp after which a track ending at ``tail`` is over: its passage at the next
        station (before an off-ramp) or 1 + max_skip stations on is beyond the gate."""
        span = 1 if self._before_exit[tail.sensor] else 1 + self._params.max_skip
        to = min(tail.sensor + span, self.layout.n_sensors - 1)
        return overdue_at(self._params, self.layout, tail.sensor, tail.stamp, tail.velocity, to)

    def _finalize(self, bound: float, everything: bool) -> None:
        """FINAL: a track whose detections below the boundary are all committed and that
        passed the last station, left at an exit or is overdue (``_due``)."""
        last_s = self.layout.n_sensors - 1
        for tid in list(self._tracks):
            members = [self._dets[k] for k in self._tracks[tid]]
            if not everything:
                if not self._n_committed[tid] or any(
                    d.key in self._pending and d.stamp < bound for d in members
                ):
                    continue
                done = [d for d in members if d.key not in self._pending]
                tail = max(done, key=lambda d: (d.sensor, d.stamp))
                if tail.sensor != last_s and bound <= self._due(tail):
                    continue
            later = [d for d in members if d.key in self._pending]
            done = sorted(
                (d for d in members if d.key not in self._pending), key=lambda d: (d.stamp, d.key)
            )
            if later:  # linked at once to a track that is over: they start their own
                new = self._new_track()
                for d in later:
                    self._move(d, new)
                self._retail(new)
            self._drop_track(tid, np.array([d.key for d in done], np.int64))
            for d in done:
                del self._dets[d.key]
            if len(done) >= 3:
                self._context.extend(sorted(done, key=canon))
            self._stats['final_tracks'] += 1

    def _calibrate(self, k: int, window: list[Det]) -> None:
        """Re-estimate the motion model on the history and the window, every
        ``calibration_every`` solves (a function of the data and the boundaries only)."""
        c = self.config
        if self._calibrated_at is not None and k - self._calibrated_at < c.calibration_every:
            return
        rows = list(self._history) + [(d.sensor, d.stamp, d.velocity) for d in window]
        params = calibrate_on(self.layout, rows)
        if params is not None:
            self._params, self._calibrated_at = params, k
