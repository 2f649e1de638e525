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
* **Stitching** (``stream_book``). Committed links never change: a window track holding
  committed detections continues the committed track of its latest one.
* **Commit and end.** Detections older than the boundary minus ``lag`` are committed with
  their track, once the model has been fitted on ``warmup_rows`` rows (before, the first
  windows of a road filling up would commit links made with a model of few links). The lag
  grows (never shrinks) to ``lag_factor`` times the 95th percentile of the travel times of
  the window's links, so that a vehicle held at a red light still reaches its next station
  before its last detection is committed alone. A track whose detections are
  all committed and whose last one is more than a lag older than the commit horizon is FINAL.

Solving beside the stream. Given an ``executor`` (``submit(fn, *args)`` returning a future:
a ``concurrent.futures`` executor, or the live node's solver process), a due window is
snapshotted as a ``stream_window.WindowJob`` and submitted, and the push returns with its
immediate link; ``push`` and ``poll`` (call it every few milliseconds while ``solving``) apply
a finished solve at its boundary and submit the next due one. Solves run one at a time, in
boundary order. A detection pushed meanwhile whose track the solve changed is linked again at
once. Without an executor each solve runs inside the push that made its boundary due; the
commits are the same either way, only later in wall time.

Stamps pushed out of order within ``reorder_tolerance`` change nothing; a detection older than
the horizon of the last window snapshotted (its boundary minus the lag) is committed at once,
as a track of its own (unassigned).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from mlkm_core.network import RoadNetwork
from mlkm_core.network_assoc import MAX_SKIP, network_hops
from mlkm_core.network_assoc.fit import NetworkModel
from mlkm_core.network_assoc.linking import candidates, link_weights
from mlkm_core.network_assoc.stream_book import Changes, NetworkStreamConfig, TrackBook
from mlkm_core.network_assoc.stream_window import (
    WindowJob,
    WindowResult,
    detections_of,
    solve_window,
)
from mlkm_core.streaming.config import StreamUpdate

#: the counters of ``stats``
COUNTERS = ('pushed', 'linked', 'started', 'late', 'solves', 'committed', 'revised',
            'false_alarms', 'final_tracks', 'executor_errors')  # fmt: skip
#: link travel times the lag is grown from (the latest), and the fewest it is grown from
TRAVEL_SAMPLES = 2000
MIN_TRAVEL_SAMPLES = 30
#: most due boundaries left unsolved while ``deferring`` (then solves go on regardless)
MAX_DEFERRED = 30


class NetworkStreamTracker(TrackBook):
    """Associates an endless stream of detections on ``net`` with a fixed commit lag."""

    #: the network method its windows link with (``linking.solve``)
    METHOD = 'assignment'

    def __init__(
        self, net: RoadNetwork, config: NetworkStreamConfig | None = None, executor: Any = None
    ) -> None:
        """``executor``: runs the window solves beside the stream (module docstring); None:
        each runs inside the push that made it due. The commits are the same either way."""
        super().__init__(config or NetworkStreamConfig())
        self.net = net
        self._executor = executor
        self._hops = network_hops(net, MAX_SKIP)
        # station -> the stations a vehicle can be seen at next (the hops' ends)
        self._reach: list[set[int]] = [set() for _ in range(net.n_stations)]
        self._into: list[list[int]] = [[] for _ in range(net.n_stations)]  # hops ending there
        for h, (a, b) in enumerate(zip(self._hops.src.tolist(), self._hops.dst.tolist())):
            self._reach[a].add(b)
            self._into[b].append(h)
        self._travel: deque = deque(maxlen=TRAVEL_SAMPLES)  # the windows' link times [s]
        self._model: NetworkModel | None = None
        self._fitted_on = 0  # rows the model was fitted on: below warmup_rows, every solve
        # fits it again (the first windows of a road filling up hold few links)
        self._solves = 0  # windows snapshotted
        self._inflight: tuple[_Window, Any] | None = None  # the window on the executor
        self._since: list[int] = []  # keys pushed since the in-flight window's snapshot
        self._late_before = -math.inf  # pushes stamped before it are late
        self._boundary: float | None = None
        self._newest = -math.inf
        #: while True, due windows wait (up to MAX_DEFERRED) instead of being solved: the
        #: caller is busy taking a backlog. Only when commits come changes, never what they are.
        self.deferring = False

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
        if stamp < max(self.committed_until, self._late_before):  # too late: committed alone
            self._counts.update(('pushed', 'late', 'committed', 'false_alarms'))
            out = Changes()
            out.commit(key, -1)
            return out.update(self.committed_until)
        self._det[key] = (int(station), float(stamp), float(velocity), int(lane), float(length))
        self._set_track(key, -1)
        self._newest = max(self._newest, float(stamp))
        self._counts['pushed'] += 1
        if self._boundary is None:
            self._boundary = float(stamp) + self.config.solve_interval
        out = Changes()
        self._advance(out)
        if self._track.get(key) == -1:  # not in a window solved just now
            self._link_now(key, out)
        if self._inflight is not None:
            self._since.append(key)
        return out.update(self.committed_until)

    def poll(self) -> StreamUpdate:
        """Apply the window solve the executor finished and submit the next due one; what
        changed. Call it every few milliseconds while ``solving``."""
        out = Changes()
        self._advance(out)
        return out.update(self.committed_until)

    @property
    def solving(self) -> bool:
        """A window solve is in flight on the executor."""
        return self._inflight is not None

    def flush(self) -> StreamUpdate:
        """The end of the stream: every detection linked, committed, every track FINAL
        (waits for the solve in flight)."""
        out = Changes()
        self._advance(out, wait=True)
        if self._det:
            self._run(self._snapshot(math.inf, math.inf), out, wait=True)
        for tid in list(self._members):
            self._end(tid, out)
        return out.update(self.committed_until)

    @property
    def working_set(self) -> int:
        """Detections held (uncommitted, or committed and still in the context)."""
        return len(self._det)

    def stats(self) -> dict:
        """Counters: pushed, linked and started (its immediate link), late, solves, committed,
        revised (committed detections that changed track before their commit), false_alarms
        (committed unassigned), final_tracks, executor_errors (solves the executor failed,
        run here instead); the gauges working_set, open_tracks, lag [s] and revision_rate
        (revised / committed)."""
        c = self._counts
        return {
            **{k: int(c[k]) for k in COUNTERS},
            'working_set': self.working_set,
            'open_tracks': len(self._members),
            'lag': self.lag,
            'revision_rate': c['revised'] / c['committed'] if c['committed'] else 0.0,
        }

    # --- the immediate link ---------------------------------------------------------------
    def _link_now(self, key: int, out: Changes) -> None:
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
            for k in self._alone:  # alone since the last window: a start
                row = self._det[k]
                if k != key and row[1] < stamp and station in self._reach[row[0]]:
                    tails.append((-1, k))
        tid = -1
        if tails:
            d = detections_of([self._det[k] for _, k in tails] + [self._det[key]])
            cue = m.cue(d)
            i, j, cost, _ = candidates(
                self._hops, d, m.motion, m.junctions, cue, m.lanes, m.per_hop, self._into[station]
            )
            to_new = j == len(tails)  # the links into the new detection
            i = i[to_new]
            weight = link_weights(self._hops, m.motion, d, i, j[to_new], cost[to_new])
            if weight.size and weight.min() < 0:
                tid, first = tails[int(i[np.argmin(weight)])]
                if tid < 0:  # the two start a track
                    tid, self._next_id = self._next_id, self._next_id + 1
                    self._set_track(first, tid)
                    self._members[tid] = [first]
        if tid < 0:
            tid, self._next_id = self._next_id, self._next_id + 1
            self._counts['started'] += 1
        else:
            self._counts['linked'] += 1
        self._set_track(key, tid)
        self._members.setdefault(tid, []).append(key)  # the tail it follows is older
        out.tracks[tid] = self._view(tid)

    def _advance(self, out: Changes, wait: bool = False) -> None:
        """Apply the solve in flight once it is done (``wait``: wait for it), then snapshot
        and solve (or submit) every window the newest stamp has made due, in order."""
        c = self.config
        while True:
            if self._inflight is not None:
                window, future = self._inflight
                if not (wait or future.done()):
                    return
                self._inflight = None
                self._apply(window, self._result(window, future), out)
            if self._boundary is None or self._newest < self._boundary + c.reorder_tolerance:
                return
            due = (self._newest - c.reorder_tolerance - self._boundary) / c.solve_interval
            if self.deferring and not wait and due < MAX_DEFERRED:
                return
            window = self._snapshot(self._boundary, self._boundary - self.lag)
            self._boundary += c.solve_interval
            self._run(window, out, wait)

    def _snapshot(self, boundary: float, horizon: float) -> _Window:
        """The window due at ``boundary``: the held detections stamped up to it, and the rows
        to fit the model on first when this solve fits it."""
        keys = sorted((k for k, v in self._det.items() if v[1] <= boundary),
                      key=lambda k: (self._det[k][1], self._det[k][0], k))  # fmt: skip
        self._late_before = max(self._late_before, horizon)
        if not keys:
            return _Window(boundary, horizon, keys, None, 0)
        rows = [self._det[k] for k in keys]
        fit = None
        if self._fitted_on < self.config.warmup_rows or (
            self._solves % self.config.calibration_every == 0
        ):
            fit = list(self._history) + rows
        self._solves += 1
        job = WindowJob(
            self.net,
            self._hops,
            detections_of(rows),
            self._model,
            None if fit is None else detections_of(fit),
        )
        return _Window(boundary, horizon, keys, job, 0 if fit is None else len(fit))

    def _run(self, window: _Window, out: Changes, wait: bool) -> None:
        """Solve a window here (no executor, or an empty window) or submit it."""
        if window.job is None or self._executor is None:
            result = None if window.job is None else solve_window(window.job)
            self._apply(window, result, out)
            return
        try:
            future = self._executor.submit(solve_window, window.job)
        except Exception:  # noqa: BLE001 - a broken executor: solve here, lose nothing
            self._counts['executor_errors'] += 1
            self._apply(window, solve_window(window.job), out)
            return
        self._inflight = (window, future)
        self._since = []
        if wait:
            self._advance(out, wait=True)

    def _result(self, window: _Window, future) -> WindowResult:
        try:
            return future.result()
        except Exception:  # noqa: BLE001 - the executor failed it: solve here (same result)
            self._counts['executor_errors'] += 1
            return solve_window(window.job)

    def _apply(self, window: _Window, result: WindowResult | None, out: Changes) -> None:
        """A window's solution: its detections to their tracks, the commits it makes due, and
        the detections pushed since its snapshot linked again where it changed their track."""
        since, self._since = self._since, []
        if result is None:
            return
        if result.model is not None:
            self._model, self._fitted_on = result.model, window.fit_rows
        self._counts['solves'] += 1
        horizon = window.horizon
        self._travel.extend(result.travel.tolist())
        if len(self._travel) >= MIN_TRAVEL_SAMPLES:
            p95 = float(np.percentile(np.fromiter(self._travel, float), 95))
            self.lag = max(self.lag, self.config.lag_factor * p95)
            horizon = min(horizon, window.boundary - self.lag)
        touched = self._stitch(window.keys, result.labels, horizon, out)
        if self._fitted_on >= self.config.warmup_rows or horizon == math.inf:
            self._commit(horizon, out)
        moved = [k for k in since if self._track.get(k, -1) in touched]
        for k in moved:
            self._leave(k, out)
        for k in sorted(moved, key=lambda k: (self._det[k][1], k)):
            self._link_now(k, out)


@dataclass(frozen=True)
class _Window:
    """A snapshotted window: its boundary and commit horizon [s], its keys (in the job's
    order), the job (None: no detection) and the rows its model fit is made on."""

    boundary: float
    horizon: float
    keys: list[int]
    job: WindowJob | None
    fit_rows: int
