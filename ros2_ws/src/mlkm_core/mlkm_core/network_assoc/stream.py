"""The fixed-lag stream on a road network: detections pushed in stamp order, tracks out as
they form, every link committed for good once the newest stamp is ``lag`` past it.

The same contract as one road's ``streaming.StreamTracker`` (``push`` / ``poll`` / ``flush``
give a ``StreamUpdate``: the tracks whose membership or status changed, with all their keys,
and the (key, track) pairs committed), by a simpler mechanism that the network methods allow:

* **Immediate links.** Each detection joins at once the open track it follows at the least
  cost under the carried model (``_link_now``), or starts a track; a consumer sees it in a
  track within the push.
* **Windows.** At every multiple of ``solve_interval`` of stamp time (once the newest stamp
  is ``reorder_tolerance`` past it) the detections up to that boundary and not yet committed,
  with the committed ones of the last ``context`` seconds, are linked by the network
  ``assignment`` (``linking.solve``) under the carried model.
* **The model** (``fit.calibrate_and_link``: motion, hops' own motion, turns, time lost, lane
  and length cues) is fitted on the window with the most recent committed detections
  (``calibration_size``), again every ``calibration_every`` solves, and carried in between;
  while it was fitted on fewer rows than ``warmup_rows``, at every solve.
* **Stitching.** Committed links never change. A window track holding committed detections
  continues the committed track of its latest one, if that track has not been continued by
  a later committed detection; its uncommitted detections join it. A window track without
  committed detections keeps the id its detections had (no other group claimed it) or gets
  a new one. A detection a window leaves alone is unassigned until a later window takes it.
* **Commit and end.** Detections older than the boundary minus ``lag`` are committed with
  their track, once the model has been fitted on ``warmup_rows`` rows (before, the first
  windows of a road filling up would commit links made with a model of few links). The lag
  grows (never shrinks) to ``lag_factor`` times the 95th percentile of the travel times of
  the window's links, so that a vehicle held at a red light still reaches its next station
  before its last detection is committed alone. A track whose detections are
  all committed and whose last one is more than a lag older than the commit horizon is FINAL.

Stamps pushed out of order within ``reorder_tolerance`` change nothing; a detection older than
the commit horizon is committed at once, as a track of its own (unassigned).
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

from mlkm_core.model.motion import END_MISSES
from mlkm_core.network import RoadNetwork
from mlkm_core.network_assoc import MAX_SKIP, network_hops
from mlkm_core.network_assoc.fit import NetworkModel, calibrate_and_link
from mlkm_core.network_assoc.linking import candidates, solve
from mlkm_core.streaming.config import CONFIRMED, FINAL, TENTATIVE, StreamUpdate, TrackUpdate
from mlkm_core.types import Detections

#: the counters of ``stats``
COUNTERS = ('pushed', 'linked', 'started', 'late', 'solves', 'committed', 'revised',
            'false_alarms', 'final_tracks')  # fmt: skip
#: link travel times the lag is grown from (the latest), and the fewest it is grown from
TRAVEL_SAMPLES = 2000
MIN_TRAVEL_SAMPLES = 30


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


class NetworkStreamTracker:
    """Associates an endless stream of detections on ``net`` with a fixed commit lag."""

    def __init__(self, net: RoadNetwork, config: NetworkStreamConfig | None = None) -> None:
        self.net = net
        self.config = config or NetworkStreamConfig()
        self._hops = network_hops(net, MAX_SKIP)
        # station -> the stations a vehicle can be seen at next (the hops' ends)
        self._reach: list[set[int]] = [set() for _ in range(net.n_stations)]
        self._into: list[list[int]] = [[] for _ in range(net.n_stations)]  # hops ending there
        for h, (a, b) in enumerate(zip(self._hops.src.tolist(), self._hops.dst.tolist())):
            self._reach[a].add(b)
            self._into[b].append(h)
        # key -> (station, stamp, speed, lane, length) of the detections still held
        self._det: dict[int, tuple[int, float, float, int, float]] = {}
        self._track: dict[int, int] = {}  # key -> its track, -1 unassigned (held ones)
        self._members: dict[int, list[int]] = {}  # open track -> its keys, stamp order
        self._last_committed: dict[int, int] = {}  # open track -> its latest committed key
        self._committed: set[int] = set()  # held keys whose link is committed
        self._history: deque = deque(maxlen=self.config.calibration_size)
        self._travel: deque = deque(maxlen=TRAVEL_SAMPLES)  # the windows' link times [s]
        self._counts: Counter[str] = Counter()
        self._revised: set[int] = set()  # held keys moved after their first track
        self._model: NetworkModel | None = None
        self._fitted_on = 0  # rows the model was fitted on: below warmup_rows, every solve
        # fits it again (the first windows of a road filling up hold few links)
        self._solves = 0
        self._next_id = 0
        self._boundary: float | None = None
        self._newest = -math.inf
        self.committed_until = -math.inf
        self.lag = self.config.lag
        self.deferring = False  # the live node's flag; solves here are inline
        self.solving = False

    # --- the stream -----------------------------------------------------------------------
    def push(
        self,
        key: int,
        station: int,
        stamp: float,
        velocity: float,
        lane: int = -1,
        length: float = math.nan,
    ) -> StreamUpdate:
        """One detection (``station``: its index in the network); the updates it made due."""
        if not 0 <= station < self.net.n_stations:
            raise ValueError(f'station index {station} outside [0, {self.net.n_stations})')
        if stamp < self.committed_until:  # too late to be linked: committed alone
            self._counts.update(('pushed', 'late', 'committed', 'false_alarms'))
            out = _Changes()
            out.commit(key, -1)
            return out.update(self.committed_until)
        self._det[key] = (int(station), float(stamp), float(velocity), int(lane), float(length))
        self._track[key] = -1
        self._newest = max(self._newest, float(stamp))
        self._counts['pushed'] += 1
        if self._boundary is None:
            self._boundary = float(stamp) + self.config.solve_interval
        out = _Changes()
        while self._newest >= self._boundary + self.config.reorder_tolerance:
            self._solve(self._boundary, self._boundary - self.lag, out)
            self._boundary += self.config.solve_interval
        if self._track.get(key) == -1:  # not in a window solved just now
            self._link_now(key, out)
        return out.update(self.committed_until)

    def _link_now(self, key: int, out: _Changes) -> None:
        """The immediate link: ``key`` joins the open track whose latest detection it follows
        (or a detection the last window left alone) at the least cost under the carried
        model, where that cost beats starting a track there and ending the other; else it
        starts a track of its own. The next window solve revises it."""
        station, stamp = self._det[key][0], self._det[key][1]
        m = self._model
        tails = []  # (its track or -1 for a detection alone, the detection)
        if m is not None:
            for tid, keys_of in self._members.items():
                last = self._det[keys_of[-1]]
                if last[1] < stamp and station in self._reach[last[0]]:
                    tails.append((tid, keys_of[-1]))
            for k, tid in self._track.items():  # alone since the last window: a start
                row = self._det[k]
                if tid < 0 and k != key and k not in self._committed and row[1] < stamp:
                    if station in self._reach[row[0]]:
                        tails.append((-1, k))
        tid = -1
        if tails:
            d = _detections([self._det[k] for _, k in tails] + [self._det[key]])
            cue = m.cue(d)
            i, j, cost, _ = candidates(
                self._hops, d, m.motion, m.junctions, cue, m.lanes, m.per_hop, self._into[station]
            )
            to_new = j == len(tails)  # the links into the new detection
            i, cost = i[to_new], cost[to_new]
            hops, p = self._hops, m.motion
            start = p.new_cost + min(hops.before[station], p.max_skip + 1) * p.miss_cost
            end = np.minimum(hops.after[d.sensor_index[i]], END_MISSES) * p.miss_cost
            weight = cost - start - end
            if weight.size and weight.min() < 0:
                tid, first = tails[int(i[np.argmin(weight)])]
                if tid < 0:  # the two start a track
                    tid, self._next_id = self._next_id, self._next_id + 1
                    self._track[first] = tid
                    self._members[tid] = [first]
        if tid < 0:
            tid, self._next_id = self._next_id, self._next_id + 1
            self._counts['started'] += 1
        else:
            self._counts['linked'] += 1
        self._track[key] = tid
        self._members.setdefault(tid, []).append(key)
        out.tracks[tid] = self._view(tid)

    def poll(self) -> StreamUpdate:
        """Nothing runs beside the stream: no update is ever waiting."""
        return StreamUpdate(committed_until=self.committed_until)

    def flush(self) -> StreamUpdate:
        """The end of the stream: every detection linked, committed, every track FINAL."""
        out = _Changes()
        if self._det:
            self._solve(math.inf, math.inf, out)
        for tid in list(self._members):
            self._end(tid, out)
        return out.update(self.committed_until)

    @property
    def working_set(self) -> int:
        """Detections held (uncommitted, or committed and still in the context)."""
        return len(self._det)

    def stats(self) -> dict:
        """Counters: pushed, linked and started (its immediate link), late, solves, committed,
        revised (committed detections that changed
        track before their commit), false_alarms (committed unassigned), final_tracks; the
        gauges working_set, open_tracks, lag [s] and revision_rate (revised / committed)."""
        c = self._counts
        return {
            **{k: int(c[k]) for k in COUNTERS},
            'working_set': self.working_set,
            'open_tracks': len(self._members),
            'lag': self.lag,
            'revision_rate': c['revised'] / c['committed'] if c['committed'] else 0.0,
        }

    # --- one window -----------------------------------------------------------------------
    def _solve(self, boundary: float, horizon: float, out: _Changes) -> None:
        keys = sorted((k for k, v in self._det.items() if v[1] <= boundary),
                      key=lambda k: (self._det[k][1], self._det[k][0], k))  # fmt: skip
        if not keys:
            return
        d = self._detections(keys)
        rows = list(self._history) + [self._det[k] for k in keys]
        young = self._fitted_on < self.config.warmup_rows
        if young or self._solves % self.config.calibration_every == 0:
            _, self._model = calibrate_and_link(self.net, self._hops, _detections(rows))
            self._fitted_on = len(rows)
        self._solves += 1
        self._counts['solves'] += 1
        m = self._model
        labels, links = solve(self._hops, d, m.motion, m.junctions, m.cue(d), m.lanes, m.per_hop)
        self._travel.extend((d.stamp[links.b] - d.stamp[links.a]).tolist())
        if len(self._travel) >= MIN_TRAVEL_SAMPLES:
            p95 = float(np.percentile(np.fromiter(self._travel, float), 95))
            self.lag = max(self.lag, self.config.lag_factor * p95)
            horizon = min(horizon, boundary - self.lag)
        self._stitch(keys, labels, out)
        if self._fitted_on >= self.config.warmup_rows or horizon == math.inf:
            self._commit(horizon, out)

    def _detections(self, keys: list[int]) -> Detections:
        return _detections([self._det[k] for k in keys])

    def _stitch(self, keys: list[int], labels: np.ndarray, out: _Changes) -> None:
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
                self._track[k] = tid
        for tid in touched:
            keys_of = self._members.get(tid, [])
            if not keys_of:  # every detection moved elsewhere: the track is gone
                self._members.pop(tid, None)
                self._last_committed.pop(tid, None)
                out.tracks[tid] = TrackUpdate(tid, FINAL, np.zeros(0, np.int64))
                continue
            keys_of.sort(key=lambda k: (self._det[k][1], k))
            out.tracks[tid] = self._view(tid)

    def _view(self, tid: int, status: int | None = None) -> TrackUpdate:
        keys_of = self._members[tid]
        if status is None:
            status = CONFIRMED if len(keys_of) >= self.config.confirm_count else TENTATIVE
        return TrackUpdate(tid, status, np.array(keys_of, np.int64))

    def _commit(self, horizon: float, out: _Changes) -> None:
        self.committed_until = max(self.committed_until, horizon)
        for k, row in list(self._det.items()):
            if row[1] < horizon and k not in self._committed:
                self._committed.add(k)
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

    def _end(self, tid: int, out: _Changes) -> None:
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


def _detections(rows: list[tuple[int, float, float, int, float]]) -> Detections:
    """(station, stamp, speed, lane, length) rows as Detections, lane and length where known."""
    s, t, v, lane, length = (np.array(c) for c in zip(*rows, strict=True))
    lane = lane.astype(np.int64)
    return Detections(
        s.astype(np.int64),
        t.astype(float),
        v.astype(float),
        lane=lane if np.any(lane >= 0) else None,
        length=length.astype(float) if np.any(np.isfinite(length)) else None,
    )


class _Changes:
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
