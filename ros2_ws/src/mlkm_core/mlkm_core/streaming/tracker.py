"""``StreamTracker``: the fixed-lag streaming associator (mechanism in ``mlkm_core.streaming``)."""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Sequence
from typing import Any

import numpy as np

from mlkm_core.model.motion import MotionParams
from mlkm_core.streaming.book import COUNTERS, Det, canon
from mlkm_core.streaming.config import (
    StreamConfig,
    StreamUpdate,
)
from mlkm_core.streaming.entries import EndedTracks
from mlkm_core.streaming.snapshot import PreparedWindow, WindowSnapshots
from mlkm_core.streaming.solve import CarriedModel, WindowSolution, add_evidence, solve
from mlkm_core.streaming.window import owners
from mlkm_core.types import UNKNOWN_LANE, Layout

#: Most due boundaries left unsolved while ``deferring`` (then solves go on regardless) [-].
MAX_DEFERRED = 30
#: Predicted travel times kept for the lag (the latest ones) [-], and the fewest it is grown
#: from [-].
TRAVEL_SAMPLES = 2000
MIN_TRAVEL_SAMPLES = 30


class StreamTracker(WindowSnapshots):
    """Associates an endless stream of detections into tracks with a fixed commit lag."""

    def __init__(
        self,
        layout: Layout,
        config: StreamConfig = StreamConfig(),  # noqa: B008  (frozen, immutable)
        entries: Sequence[float] = (),
        exits: Sequence[float] = (),
        executor: Any = None,
    ) -> None:
        """``executor``: an object with ``submit(fn, *args)`` returning a future
        (``concurrent.futures`` shape) on which window solves run beside the stream: ``push``
        then only snapshots a due window and submits it, and ``push`` and ``poll`` apply
        finished solves in boundary order. None: each solve runs inside the ``push`` whose
        stamp made its boundary due. The committed association is the same either way."""
        super().__init__(layout, config, entries, exits)
        self._executor = executor
        self._inflight: tuple[PreparedWindow, Any] | None = None
        # solves dropped while overloaded that the executor may still be running: no new one
        # is submitted behind them, so the executor's queue never grows
        self._dropped: list[Any] = []
        self._overloaded = False
        self._since: list[int] = []  # keys pushed since the in-flight window was snapshotted
        self._late_before = -math.inf  # pushes stamped before it are late
        self._context: list[tuple[float, tuple, Det]] = []  # (end stamp, canon, det), sorted
        self._history: deque = deque(maxlen=config.calibration_size)
        self._ended = EndedTracks(layout)  # where vehicles enter and leave mid-road
        self._calibrated_at: int | None = None
        # rows the carried model was calibrated on: one calibrated on fewer than a full
        # context (a road filling up) is not carried, the next window calibrates again
        self._calibrated_rows = 0
        self._model: CarriedModel | None = None  # the method's, from its last calibrating solve
        # the method's evidence about the traffic over the windows solved (``add_evidence``)
        self._evidence: tuple[float, float] | None = None
        self._next_k: int | None = None
        self._solved = False
        self._lag = config.lag
        self._gaps = np.diff(layout.positions)  # [m] from each station to the next
        # [s] travel times between consecutive stations of the latest solved tracks
        self._travel: deque = deque(maxlen=TRAVEL_SAMPLES)
        self._newest = -math.inf
        self._stats: Counter = Counter()
        #: while True, due windows wait (up to MAX_DEFERRED boundaries) instead of being
        #: solved: the caller is busy taking a backlog of detections, and the solves would
        #: take the CPU it needs. Only when commits come changes, never what they are.
        self.deferring = False

    # ----------------------------------------------------------------- public surface
    @property
    def working_set(self) -> int:
        """Detections held: uncommitted ones and those of tracks not yet final."""
        return len(self._dets)

    @property
    def lag(self) -> float:
        """The commit lag in force [s]: ``config.lag``, grown with the travel times seen
        (``StreamConfig.lag_factor``). Until ``MIN_TRAVEL_SAMPLES`` of them are seen the 95th
        percentile is not yet estimated, and the lag is at least ``lag_factor`` times the
        longest seen: at the start of a stream of slow traffic a detection is not committed
        before its vehicle can reach the next station (this early hold is not kept once the
        percentile is known, so one stopped vehicle among the first does not fix the lag)."""
        c = self.config
        if 0 < len(self._travel) < MIN_TRAVEL_SAMPLES and c.lag_factor > 0:
            return max(self._lag, c.lag_factor * max(self._travel))
        return self._lag

    @property
    def committed_until(self) -> float:
        return self._committed_until

    @property
    def params(self) -> MotionParams:
        """The motion model calibrated on the stream so far."""
        return self._params

    def stats(self) -> dict:
        """Counters: pushed, linked, started, late, reordered, committed, assigned,
        false_alarms, revised, solves, degraded, failed_solves, executor_errors (solves the
        executor failed, run in the caller instead), final_tracks, rejected; and the gauges
        working_set, open_tracks, lag (the lag in force [s]) and revision_rate: revised /
        committed, the share of committed detections whose link first published (the
        detection it followed in its track, or none) changed before the commit."""
        out = {name: self._stats[name] for name in COUNTERS}
        out['working_set'] = self.working_set
        out['open_tracks'] = len(self._tracks)
        out['revision_rate'] = out['revised'] / out['committed'] if out['committed'] else 0.0
        out['uncommitted'] = len(self._pending)
        out['overloaded'] = int(self._overloaded)
        out['lag'] = self.lag
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
        if stamp < max(self._committed_until, self._late_before):
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
        self._ended.begin(stamp)
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
        if self._inflight is not None:
            self._since.append(key)
        return self._end()

    def poll(self) -> StreamUpdate:
        """Apply the window solves the executor finished (in boundary order) and submit the
        next due one; what changed. Call it often while a solve is in flight
        (``solving``): commits arrive with it when no detection is pushed."""
        self._begin()
        self._advance()
        return self._end()

    @property
    def solving(self) -> bool:
        """A window solve is in flight on the executor."""
        return self._inflight is not None

    @property
    def overloaded(self) -> bool:
        """The last boundaries were committed on the immediate links, without a window solve:
        more than ``max_uncommitted`` detections waited for their commit. Cleared by the next
        solve applied."""
        return self._overloaded

    def flush(self) -> StreamUpdate:
        """Commit everything and finalise every track (the road fell quiet, or input ended);
        waits for the solves in flight."""
        self._begin()
        self._advance(wait=True)
        if self._over_budget():
            self._commit_now(None)
        elif self._dets:
            self._run(self._prepare(None), wait=True)
        self._overloaded = False
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

    # ----------------------------------------------------------------- revision and commit
    def _advance(self, wait: bool = False) -> None:
        """Solve every boundary the newest stamp has passed by the reorder tolerance, in
        order: apply the solve in flight once it is done (``wait``: wait for it), then
        snapshot the next due window and solve it (or submit it to the executor).

        Boundaries whose window is empty only end tracks; a run of them is skipped to the
        first one with a window (or the last passed), ending first the tracks that the
        skipped boundaries would have ended, so the outcome is that of solving each.

        Over ``max_uncommitted`` detections waiting for their commit, the solve in flight is
        dropped and every due boundary is committed at once on the immediate links
        (``_commit_now``); no solve is submitted while a dropped one may still be running.
        """
        c = self.config
        while True:
            if self._inflight is not None:
                prepared, future = self._inflight
                if self._over_budget():
                    self._inflight = None
                    self._dropped.append(future)
                    self._since = []
                    self._next_k = prepared.k  # due again: committed below without it
                elif not (wait or future.done()):
                    return
                else:
                    self._inflight = None
                    self._finish(prepared, self._result(prepared, future))
            if self._next_k is None:
                return
            last_k = math.floor((self._newest - c.reorder_tolerance) / c.solve_interval)
            if self._next_k > last_k:
                return
            if self._over_budget():
                self._commit_now(last_k)
                continue
            if self.deferring and not wait and last_k - self._next_k < MAX_DEFERRED:
                return
            self._dropped = [f for f in self._dropped if not f.done()]
            if self._dropped and not wait:
                return
            oldest = min((self._dets[k].stamp for k in self._pending), default=math.inf)
            first_k = math.floor(oldest / c.solve_interval) + 1 if oldest < math.inf else last_k
            target = min(max(first_k, self._next_k), last_k)
            if target > self._next_k:
                skipped = (target - 1) * c.solve_interval
                self._committed_until = max(self._committed_until, skipped - self.lag)
                self._finalize(skipped, False)
                self._next_k = target
            prepared = self._prepare(self._next_k)
            self._next_k += 1
            self._run(prepared, wait)

    def _over_budget(self) -> bool:
        return 0 < self.config.max_uncommitted < len(self._pending)

    def _commit_now(self, k: int | None) -> None:
        """Commit the boundaries up to k (None: everything, at a flush) on the tracks the
        detections are in now (their immediate links), without a window solve: what the
        solve at k would commit, a detection alone as a false alarm, then end the tracks that
        are over."""
        c = self.config
        bound = math.inf if k is None else k * c.solve_interval
        cutoff = math.inf if k is None else bound - self.lag
        window = {key for key in self._pending if self._dets[key].stamp < bound}
        due = sorted(
            (self._dets[key] for key in window if self._dets[key].stamp < cutoff), key=canon
        )
        self._commit(due, window)
        self._stats['forced_commits'] += len(due)
        self._stats['skipped_solves'] += 1 if k is None else k - self._next_k + 1
        self._solved = True
        if k is not None:
            self._late_before = max(self._late_before, cutoff)
            self._committed_until = max(self._committed_until, cutoff)
            self._next_k = k + 1
        self._finalize(bound, k is None)
        self._overloaded = True

    def _run(self, prepared: PreparedWindow, wait: bool) -> None:
        """Solve a snapshotted window: at once without an executor (or for an empty window),
        else submitted (and, with ``wait``, applied once done)."""
        if prepared.problem is None or self._executor is None:
            solution = solve(prepared.problem) if prepared.problem is not None else None
            self._finish(prepared, solution)
            return
        try:
            future = self._executor.submit(solve, prepared.problem)
        except Exception:  # noqa: BLE001 - a broken executor: solve here, lose nothing
            self._stats['executor_errors'] += 1
            self._finish(prepared, solve(prepared.problem))
            return
        self._inflight = (prepared, future)
        self._since = []
        if wait:
            self._inflight = None
            self._finish(prepared, self._result(prepared, future))

    def _result(self, prepared: PreparedWindow, future) -> WindowSolution:
        try:
            return future.result()
        except Exception:  # noqa: BLE001 - the executor failed it: solve here (same result)
            self._stats['executor_errors'] += 1
            return solve(prepared.problem)

    def _finish(self, prepared: PreparedWindow, solution: WindowSolution | None) -> None:
        """Apply a window's solution: move its detections to the tracks of the solve, commit
        what fell out of the lag, finalise the tracks that ended and link again at once the
        detections pushed since the snapshot whose tracks the solve changed."""
        p = prepared
        final = p.k is None
        changed = set(self._changed)
        if solution is not None:
            self._stats['solves'] += 1
            self._overloaded = False
            self._stats['degraded'] += solution.degraded
            self._stats['failed_solves'] += solution.failed
            if solution.params is not None:
                self._params, self._calibrated_at = solution.params, p.k
            if solution.model is not None:
                # the method's model also drives the immediate link and the ends of tracks
                self._model, self._params = solution.model, solution.model.params
                self._calibrated_at = p.k
                self._calibrated_rows = len(p.problem.detections)
            slack = 6 * math.sqrt(2) * self._params.stamp_noise
            d = p.problem.detections
            own, groups = owners(
                solution.labels, d.sensor_index, d.stamp, p.anchor_track, p.last, p.occupied, slack
            )
            n_a = p.n_anchors
            self._apply(p.window, own[n_a:], [g - n_a for g in groups])
            in_window = {d.key for d in p.window}
            due = [det for det in p.window if det.stamp < p.cutoff]
            if solution.evidence is not None and due:
                self._evidence = add_evidence(self._evidence, solution.evidence, len(due) / len(d))
            self._commit(due, in_window)
        if not final:  # a flush commits up to the newest stamp (``flush``)
            self._committed_until = max(self._committed_until, p.cutoff)
        self._grow_lag(p)
        self._finalize(p.bound, final)
        since, self._since = self._since, []
        self._relink(since, (self._changed - changed) | set(self._gone))

    def _grow_lag(self, p: PreparedWindow) -> None:
        """Add the travel times to the next station that the speeds of the window's newest
        detections predict (gap / speed; those stamped in its last ``solve_interval``, so each
        detection counts once) and grow the lag to ``lag_factor`` times their 95th percentile
        (``StreamConfig.lag_factor``). Taken from the snapshot, they are the same whether the
        solve ran inline or beside the stream."""
        c = self.config
        if c.lag_factor <= 0 or p.k is None:
            return
        start = p.bound - c.solve_interval
        self._travel.extend(
            float(self._gaps[d.sensor] / d.velocity)
            for d in p.window
            if d.stamp >= start and d.sensor < self._gaps.size
        )
        if len(self._travel) >= MIN_TRAVEL_SAMPLES:
            need = c.lag_factor * float(np.quantile(np.fromiter(self._travel, float), 0.95))
            self._lag = max(self._lag, need)

    def _relink(self, keys: list[int], changed: set[int]) -> None:
        """Link ``keys`` (in push order) again at once if their tracks changed."""
        for key in keys:
            d = self._dets.get(key)
            if d is None or key not in self._pending or d.track not in changed:
                continue
            old = d.track
            self._move(d, -1)
            self._retail(old)
            tid, _ = self._link_now(d)
            if tid < 0:
                tid = self._new_track()
            self._move(d, tid)
            self._retail(tid)
