"""The scorer's stream mode: committed tracks of an open road against ground truth, per window.

A stream has no episodes: the association node publishes TrackArray MODE_STREAM (the tracks
that changed, with ``committed_until``), the source publishes one GroundTruth per detection.
They are joined on (sensor id, lane, stamp in integer ns) and scored in consecutive windows
of ``window`` seconds of stamp time:

* A window is scored once every link in it is committed (``committed_until`` past its end)
  and every detection the tracks hold in it is in a FINAL track (or committed unassigned)
  and has its ground truth; or ``truth_timeout`` seconds (wall time) after it was committed,
  with what is at hand: ``truth_complete`` false when ground truth is missing (and only
  then), a log note when tracks were not all FINAL. Committed labels never change, so the
  timeout only matters for the truth. The last window of a road that fell quiet (no tracks
  for ``truth_timeout`` seconds, everything held committed: the association node flushed
  it) is scored as it is, although ``committed_until`` never reaches its end.
* Runs (TrackArray.run, one per start of the association node's tracker): a message of a
  later run than any seen ends the earlier ones. Their tracks that were not FINAL count as
  FINAL with the detections they last carried, their links as committed, and they covered
  every stamp up to their newest (or their committed_until): a window within that waits
  only for the current run's detections it holds to be committed, not for the current
  run's committed_until, which counts on its own. A late message of an ended run is
  applied with every track FINAL and moves no commit of the current run (counted,
  ``stream_tracks_of_ended_run``).
* A window without any true detection (only false alarms, or no truth at hand) has no
  accuracy: it is not published, only logged and counted (``stream_windows_unscored``).
* Scores: the core's ``mlkm_core.metrics.score`` on the window's true detections (a true
  detection no track holds counts as unassigned, never correct); cumulatively the core's
  ``accuracy`` over every window scored so far, kept as the track x vehicle contingency
  counts (one entry per pair that shares a detection), so one mapping for the whole run.
* Revision rate: a detection's *link* is the detection it follows in its track (in road
  order; none for the first of a track and for an unassigned detection), as the core's
  tracker counts revisions, so a track that only changed its id revises nothing. Of the
  window's detections published by the node, the share whose committed link differs from
  the one first published.
* Memory: everything of a window is dropped once it is scored; late truth or tracks for it
  are counted and ignored; at most ``max_buffered_truth`` truth messages are held.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mlkm_core.metrics import Score, accuracy, score
from mlkm_core.types import Detections

NS_PER_S = 1_000_000_000
FINAL = 2  # road_sensor_msgs/Track.STATUS_FINAL (this module imports no ROS)
Key = tuple[int, int, int]  # (sensor id, lane, stamp ns)


@dataclass(frozen=True)
class WindowScore:
    """One scored window."""

    number: int  # 0, 1, ... in scoring order
    start_ns: int
    end_ns: int
    method: str
    score: Score | None  # None: no true detection in the window (not published)
    cumulative_accuracy: float  # 0 while no true detection was scored
    windows_scored: int  # windows with at least one true detection
    truth_complete: bool  # every detection of the window's tracks had its ground truth
    tracks_final: bool  # every tracked detection of the window was in a FINAL track
    truth_expected: int  # detections of the window's tracks
    truth_received: int  # of them with ground truth
    incomplete: int  # windows scored with incomplete truth so far
    links_published: int
    links_revised: int
    cumulative_revision_rate: float  # 0 while no link was published


class StreamScorer:
    """ROS-free: feed decoded stream tracks and truth, call ``ready`` to get scored windows."""

    def __init__(
        self,
        window: float,
        truth_timeout: float,
        max_buffered_truth: int,
        sensor_index: Callable[[int], int],
    ) -> None:
        self.window_ns = int(round(window * NS_PER_S))
        self.truth_timeout = truth_timeout
        self.max_buffered_truth = max_buffered_truth
        self._sensor_index = sensor_index
        self.truth: dict[Key, tuple[int, float]] = {}  # -> (target, true velocity)
        self.first: dict[Key, Key | None] = {}  # link first published
        self.link: dict[Key, Key | None] = {}  # link last published
        self.current: dict[Key, tuple[int, int, int]] = {}  # -> (label, status, run)
        self.run: int | None = None  # the current run (TrackArray.run): the latest seen
        self.committed_until = -(2**63)  # the current run's committed_until [ns]
        self._ended_until = -(2**63)  # ended runs covered every stamp before it [ns]
        self._run_newest = -(2**63)  # the current run's newest stamp [ns]
        self.method = ''
        self.next_start: int | None = None  # start of the next window to score [ns]
        self._committed_at: float | None = None  # wall time the next window was committed
        self.number = 0
        self.windows_scored = 0
        self.incomplete = 0  # published windows with truth_complete false
        self.unscored = 0  # windows without any true detection (not published)
        self.not_final = 0  # windows scored with tracks that were not all FINAL
        self._pairs: Counter[tuple[int, int]] = Counter()  # (track, vehicle) -> detections
        self._true_total = 0  # true detections scored
        self._published_total = 0
        self._revised_total = 0
        self.last_cumulative = 0.0  # cumulative accuracy at the last scored window
        self._last_tracks = -math.inf  # wall time of the last stream tracks [s]
        self.events: Counter[str] = Counter()

    # --- inputs ---------------------------------------------------------------------------
    def add_tracks(
        self,
        method: str,
        keys: list[Key],
        labels,
        status,
        committed_ns: int,
        now: float,
        run: int = 0,
    ) -> str | None:
        """The detections of one stream TrackArray of tracker run ``run``, each track's in
        road order. Returns a note for the log when a run ended or an ended run spoke."""
        self.method = method
        self._last_tracks = now
        note = None
        if self.run is None or run > self.run:
            note = self._end_run(run)
        ended = run < self.run
        if ended:
            self.events['tracks_of_ended_run'] += 1
            note = (
                f'a late message of run {run}, which ended (the current run is {self.run}): '
                'its tracks are taken as FINAL'
            )
        done = self.next_start
        prev_key, prev_label = None, -1
        newest = -(2**63)
        for key, label, state in zip(keys, labels, status):
            # a track's detections come in road order: each follows the one before it
            link = prev_key if label >= 0 and label == prev_label else None
            prev_key, prev_label = key, label
            newest = max(newest, key[2])
            if done is not None and key[2] < done:
                self.events['tracks_after_score'] += 1
                continue
            if ended and self.current.get(key, (0, 0, run))[2] > run:
                continue  # a later run carries it now
            self.first.setdefault(key, link)
            self.link[key] = link
            self.current[key] = (label, FINAL if ended and label >= 0 else state, run)
            self._start(key[2])
        if ended:
            self._ended_until = max(self._ended_until, committed_ns, newest + 1)
        else:
            self.committed_until = max(self.committed_until, committed_ns)
            self._run_newest = max(self._run_newest, newest)
        return note

    def _end_run(self, run: int) -> str | None:
        """A message of a later run: the current run's node is gone. Its tracks that were not
        FINAL have ended as last carried, its links are all committed, and it covered every
        stamp up to its newest (the later run began after it). The new run's committed_until
        counts on its own, from nothing."""
        old, self.run = self.run, run
        if old is None:
            return None
        self._ended_until = max(self._ended_until, self.committed_until, self._run_newest + 1)
        self.committed_until = self._run_newest = -(2**63)
        ended = set()
        for k, (label, state, r) in self.current.items():
            if label >= 0 and state != FINAL:
                ended.add(label)
                self.current[k] = (label, FINAL, r)
        self.events['runs_ended'] += 1
        self.events['tracks_ended_with_run'] += len(ended)
        return (
            f'run {run} began: run {old} ended, its {len(ended)} tracks not FINAL are taken '
            'as FINAL with the detections they last carried'
        )

    def add_truth(self, key: Key, target: int, true_velocity: float) -> str | None:
        """None, or why the message was not kept."""
        if self.next_start is not None and key[2] < self.next_start:
            self.events['truth_after_score'] += 1
            return None
        if key not in self.truth and len(self.truth) >= self.max_buffered_truth:
            return 'truth_buffer_full'
        self.truth[key] = (target, true_velocity)
        self._start(key[2])
        return None

    def _start(self, stamp_ns: int) -> None:
        if self.next_start is None:
            self.next_start = stamp_ns - stamp_ns % self.window_ns

    # --- scoring --------------------------------------------------------------------------
    def ready(self, now: float, force: bool = False) -> list[WindowScore]:
        """Every window that can be scored now, in order; ``force``: every window held,
        with what is at hand (the stream ended)."""
        out = []
        while self.next_start is not None:
            if force and not self.current and not self.truth:
                break
            end = self.next_start + self.window_ns
            if not force and not self._committed(end) and not self._quiet(now):
                self._committed_at = None
                break
            if self._committed_at is None:
                self._committed_at = now
            if self._empty(end):
                continue
            truth, final = self._complete(self.next_start, end)
            waited = force or now - self._committed_at >= self.truth_timeout
            if not (truth and final) and not waited:
                break
            out.append(self._score(self.next_start, end, truth, final))
            self.next_start = end
            self._committed_at = None
        return out

    def _is_committed(self, key: Key, run: int) -> bool:
        """An ended run's links are all committed; the current run's below its own
        committed_until."""
        return run != self.run or key[2] < self.committed_until

    def _committed(self, end: int) -> bool:
        """Every link stamped before ``end`` is committed and no uncommitted one can still
        come: the current run's committed_until is past ``end``; or ended runs covered every
        stamp before ``end`` and the current run's detections held there are committed."""
        if self.committed_until >= end:
            return True
        if self._ended_until < end:
            return False
        return all(self._is_committed(k, v[2]) for k, v in self.current.items() if k[2] < end)

    def _quiet(self, now: float) -> bool:
        """No tracks for ``truth_timeout`` and every detection held is committed."""
        if now - self._last_tracks < self.truth_timeout:
            return False
        return bool(self.current) and all(
            self._is_committed(k, v[2]) for k, v in self.current.items()
        )

    def _empty(self, end: int) -> bool:
        """Skip windows without any detection (a quiet road): move to the next one that has
        some, or to the committed horizon. True when the window was skipped."""
        if any(k[2] < end for k in self.current) or any(k[2] < end for k in self.truth):
            return False
        stamps = [k[2] for k in self.current] + [k[2] for k in self.truth]
        nxt = min(stamps) if stamps else max(self.committed_until, self._ended_until)
        self.next_start = max(end, nxt - nxt % self.window_ns)
        self._committed_at = None
        return True

    def _window_keys(self, start: int, end: int, source) -> list[Key]:
        return [k for k in source if start <= k[2] < end]

    def _complete(self, start: int, end: int) -> tuple[bool, bool]:
        """(every tracked detection of the window has its truth, every one is in a FINAL
        track or unassigned)."""
        truth = final = True
        for k in self._window_keys(start, end, self.current):
            label, state, _ = self.current[k]
            truth = truth and k in self.truth
            final = final and (label < 0 or state == FINAL)
        return truth, final

    def _score(self, start: int, end: int, complete: bool, final: bool) -> WindowScore:
        tracked = self._window_keys(start, end, self.current)
        truth_keys = self._window_keys(start, end, self.truth)
        labels = {k: self.current[k][0] for k in tracked}
        truth_set = set(truth_keys)
        revised = sum(1 for k in tracked if self.first[k] != self.link[k])
        result = None
        if truth_keys:
            values = [self.truth[k] for k in truth_keys]
            d = Detections(
                np.array([self._sensor_index(k[0]) for k in truth_keys], np.int64),
                np.array([k[2] for k in truth_keys], np.int64) / NS_PER_S,
                np.array([v[1] for v in values], float),
                np.array([v[0] for v in values], np.int64),
            )
            lab = np.array([labels.get(k, -1) for k in truth_keys], np.int64)
            if (d.target >= 0).any():
                result = score(d, lab)
                self._true_total += int((d.target >= 0).sum())
                keep = (d.target >= 0) & (lab >= 0)
                self._pairs.update(zip(lab[keep].tolist(), d.target[keep].tolist()))
        if result is None:
            self.unscored += 1
        else:
            self.windows_scored += 1
            self.incomplete += not complete
            self.not_final += not final
        self._published_total += len(tracked)
        self._revised_total += revised
        for source in (self.truth, self.first, self.link, self.current):
            for k in [k for k in source if k[2] < end]:
                del source[k]
        number, self.number = self.number, self.number + 1
        self.last_cumulative = self.cumulative_accuracy()
        return WindowScore(
            number=number,
            start_ns=start,
            end_ns=end,
            method=self.method,
            score=result,
            cumulative_accuracy=self.last_cumulative,
            windows_scored=self.windows_scored,
            truth_complete=complete,
            tracks_final=final,
            truth_expected=len(tracked),
            truth_received=sum(1 for k in tracked if k in truth_set),
            incomplete=self.incomplete,
            links_published=len(tracked),
            links_revised=revised,
            cumulative_revision_rate=(
                self._revised_total / self._published_total if self._published_total else 0.0
            ),
        )

    def cumulative_accuracy(self) -> float:
        """The core's accuracy over every true detection scored so far (0 before any)."""
        if not self._true_total:
            return 0.0
        pairs = list(self._pairs.items())
        counts = np.array([c for _, c in pairs], np.int64)
        tracks = np.repeat(np.array([p[0] for p, _ in pairs], np.int64), counts)
        vehicles = np.repeat(np.array([p[1] for p, _ in pairs], np.int64), counts)
        unassigned = self._true_total - int(counts.sum())  # true but never correct
        labels = np.concatenate([tracks, np.full(unassigned, -1, np.int64)])
        targets = np.concatenate([vehicles, np.zeros(unassigned, np.int64)])
        return accuracy(labels, targets).accuracy

    # --- bookkeeping ----------------------------------------------------------------------
    def used(self) -> bool:
        """Whether any stream tracks came."""
        return bool(self.method) or self.number > 0

    def holds(self) -> bool:
        """Whether any detection or truth waits to be scored."""
        return bool(self.current or self.truth)

    def held(self) -> dict[str, int]:
        return {
            'stream_buffered_truth': len(self.truth),
            'stream_tracked_detections': len(self.current),
            'stream_contingency_pairs': len(self._pairs),
        }
