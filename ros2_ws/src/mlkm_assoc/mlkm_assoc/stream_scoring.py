"""The scorer's stream mode: committed tracks of an open road against ground truth, per window.

A stream has no episodes: the association node publishes TrackArray MODE_STREAM (the tracks
that changed, with ``committed_until``), the source publishes one GroundTruth per detection.
They are joined on (sensor id, lane, stamp in integer ns) and scored in consecutive windows
of ``window`` seconds of stamp time:

* A window is scored once every link in it is committed (``committed_until`` past its end)
  and every detection the tracks hold in it is in a FINAL track (or committed unassigned)
  and has its ground truth; or ``truth_timeout`` seconds (wall time) after it was committed,
  with what is at hand (truth_complete false). Committed labels never change, so the
  timeout only matters for the truth. The last window of a road that fell quiet (no tracks
  for ``truth_timeout`` seconds, everything held committed: the association node flushed
  it) is scored as it is, although ``committed_until`` never reaches its end.
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
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mlkm_core.metrics import Score, accuracy, score
from mlkm_core.types import Detections
from mlkm_ros import conversions as conv
from mlkm_ros.params import ParamSpec, positive
from road_sensor_msgs.msg import AssociationScore, TrackArray

NS_PER_S = 1_000_000_000
FINAL = 2  # road_sensor_msgs/Track.STATUS_FINAL
Key = tuple[int, int, int]  # (sensor id, lane, stamp ns)

#: Parameters of the scorer's stream mode (declared by scorer_node with its own).
STREAM_SPECS = [
    ParamSpec(
        'mode',
        'auto',
        'episodes: score each episode; stream: score windows of an open road; auto: stream '
        'once the association node publishes stream tracks, episodes otherwise [-]',
        check=lambda v: (
            None
            if v in ('auto', 'episodes', 'stream')
            else f'unknown mode {v!r}; choose one of auto, episodes, stream'
        ),
        constraints='one of: auto, episodes, stream',
        read_only=True,
    ),
    ParamSpec(
        'window',
        60.0,
        'stream mode: scores cover consecutive windows of this much stamp time [s]',
        1e-3,
        1e9,
        check=positive,
        read_only=True,
    ),
]


@dataclass(frozen=True)
class WindowScore:
    """One scored window."""

    number: int  # 0, 1, ... in scoring order
    start_ns: int
    end_ns: int
    method: str
    score: Score | None  # None: no true detection in the window
    cumulative_accuracy: float  # NaN while no true detection was scored
    windows_scored: int  # windows with at least one true detection
    truth_complete: bool
    truth_expected: int  # detections of the window's tracks
    truth_received: int  # of them with ground truth
    incomplete: int  # windows scored with incomplete truth so far
    links_published: int
    links_revised: int
    cumulative_revision_rate: float


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
        self.current: dict[Key, tuple[int, int]] = {}  # -> (label, status)
        self.committed_until = -(2**63)
        self.method = ''
        self.next_start: int | None = None  # start of the next window to score [ns]
        self._committed_at: float | None = None  # wall time the next window was committed
        self.number = 0
        self.windows_scored = 0
        self.incomplete = 0
        self._pairs: Counter[tuple[int, int]] = Counter()  # (track, vehicle) -> detections
        self._true_total = 0  # true detections scored
        self._published_total = 0
        self._revised_total = 0
        self.last_cumulative = math.nan  # cumulative accuracy at the last scored window
        self._last_tracks = -math.inf  # wall time of the last stream tracks [s]
        self.events: Counter[str] = Counter()

    # --- inputs ---------------------------------------------------------------------------
    def add_tracks(
        self, method: str, keys: list[Key], labels, status, committed_ns: int, now: float
    ) -> None:
        """The detections of one stream TrackArray, each track's in road order."""
        self.method = method
        self._last_tracks = now
        done = self.next_start
        prev_key, prev_label = None, -1
        for key, label, state in zip(keys, labels, status):
            # a track's detections come in road order: each follows the one before it
            link = prev_key if label >= 0 and label == prev_label else None
            prev_key, prev_label = key, label
            if done is not None and key[2] < done:
                self.events['tracks_after_score'] += 1
                continue
            self.first.setdefault(key, link)
            self.link[key] = link
            self.current[key] = (label, state)
            self._start(key[2])
        self.committed_until = max(self.committed_until, committed_ns)

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
    def ready(self, now: float) -> list[WindowScore]:
        """Every window that can be scored now, in order."""
        out = []
        while self.next_start is not None:
            end = self.next_start + self.window_ns
            if self.committed_until < end and not self._quiet(now):
                self._committed_at = None
                break
            if self._committed_at is None:
                self._committed_at = now
            if self._empty(end):
                continue
            complete = self._complete(self.next_start, end)
            if not complete and now - self._committed_at < self.truth_timeout:
                break
            out.append(self._score(self.next_start, end, complete))
            self.next_start = end
            self._committed_at = None
        return out

    def _quiet(self, now: float) -> bool:
        """No tracks for ``truth_timeout`` and every detection held is committed."""
        if now - self._last_tracks < self.truth_timeout:
            return False
        stamps = [k[2] for k in self.current]
        return bool(stamps) and max(stamps) < self.committed_until

    def _empty(self, end: int) -> bool:
        """Skip windows without any detection (a quiet road): move to the next one that has
        some, or to the committed horizon. True when the window was skipped."""
        if any(k[2] < end for k in self.current) or any(k[2] < end for k in self.truth):
            return False
        stamps = [k[2] for k in self.current] + [k[2] for k in self.truth]
        nxt = min(stamps) if stamps else self.committed_until
        self.next_start = max(end, nxt - nxt % self.window_ns)
        self._committed_at = None
        return True

    def _window_keys(self, start: int, end: int, source) -> list[Key]:
        return [k for k in source if start <= k[2] < end]

    def _complete(self, start: int, end: int) -> bool:
        for k in self._window_keys(start, end, self.current):
            label, state = self.current[k]
            if k not in self.truth or (label >= 0 and state != FINAL):
                return False
        return True

    def _score(self, start: int, end: int, complete: bool) -> WindowScore:
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
        if result is not None:
            self.windows_scored += 1
        if not complete:
            self.incomplete += 1
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
            truth_expected=len(tracked),
            truth_received=sum(1 for k in tracked if k in truth_set),
            incomplete=self.incomplete,
            links_published=len(tracked),
            links_revised=revised,
            cumulative_revision_rate=(
                self._revised_total / self._published_total if self._published_total else math.nan
            ),
        )

    def cumulative_accuracy(self) -> float:
        """The core's accuracy over every true detection scored so far (NaN before any)."""
        if not self._true_total:
            return math.nan
        pairs = list(self._pairs.items())
        counts = np.array([c for _, c in pairs], np.int64)
        tracks = np.repeat(np.array([p[0] for p, _ in pairs], np.int64), counts)
        vehicles = np.repeat(np.array([p[1] for p, _ in pairs], np.int64), counts)
        unassigned = self._true_total - int(counts.sum())  # true but never correct
        labels = np.concatenate([tracks, np.full(unassigned, -1, np.int64)])
        targets = np.concatenate([vehicles, np.zeros(unassigned, np.int64)])
        return accuracy(labels, targets).accuracy

    # --- bookkeeping ----------------------------------------------------------------------
    def held(self) -> dict[str, int]:
        return {
            'stream_buffered_truth': len(self.truth),
            'stream_tracked_detections': len(self.current),
            'stream_contingency_pairs': len(self._pairs),
        }

    def reset_truth(self) -> None:
        """Forget held truth (the source turned out to have episodes)."""
        self.truth.clear()


class StreamScoring:
    """The scorer node's stream mode: decides which messages are the stream's, feeds a
    :class:`StreamScorer`, publishes one AssociationScore (MODE_STREAM) per window.

    ``mode`` ``stream``: every TrackArray and GroundTruth is the stream's. ``auto``: stream
    mode begins with the first TrackArray of MODE_STREAM; until then ground truth goes to
    episodes mode as always and, while no EpisodeInfo was seen, a copy is kept here (the
    association node needs a moment before its first stream tracks); at the switch
    ``forget_unannounced`` lets episodes mode drop its copies. ``episodes``: nothing here.
    """

    def __init__(
        self,
        node,
        publisher,
        mode: str,
        window: float,
        truth_timeout: float,
        max_buffered_truth: int,
        sensor_index: Callable[[int], int],
        reject: Callable[[str, str], None],
        forget_unannounced: Callable[[], None],
    ) -> None:
        self._node = node
        self._publisher = publisher
        self.mode = mode
        self.active = mode == 'stream'
        self._episodes_seen = False
        self._reject = reject
        self._forget_unannounced = forget_unannounced
        self.scorer = StreamScorer(window, truth_timeout, max_buffered_truth, sensor_index)

    # --- inputs ---------------------------------------------------------------------------
    def take_tracks(self, msg) -> bool:
        """True when the TrackArray was the stream's (handled here)."""
        if self.mode == 'episodes' or msg.mode != TrackArray.MODE_STREAM:
            return False
        if not self.active:
            self.active = True
            self._forget_unannounced()
            self._node.get_logger().info('stream tracks: scoring windows of the open road')
        try:
            d = conv.stream_tracks_from_msg(msg)
        except ValueError as exc:
            self._reject('invalid_tracks', f'stream tracks: {exc}')
            return True
        keys = list(zip(d.sensor_ids.tolist(), d.lanes.tolist(), d.stamps_ns.tolist()))
        self.scorer.add_tracks(
            msg.method,
            keys,
            d.labels.tolist(),
            d.status.tolist(),
            d.committed_until_ns,
            time.monotonic(),
        )
        return True

    def take_truth(self, msg) -> bool:
        """True when the GroundTruth was the stream's alone."""
        if self.mode == 'episodes' or (not self.active and self._episodes_seen):
            return False
        stamp = msg.header.stamp
        if stamp.sec < 0 or stamp.nanosec >= NS_PER_S:
            if self.active:
                self._reject('invalid_truth', f'stream truth: invalid time {stamp.sec} s')
            return self.active
        key = (int(msg.sensor_id), int(msg.lane), conv.time_to_ns(stamp))
        why = self.scorer.add_truth(key, conv.ground_truth_target(msg), float(msg.true_velocity))
        if why and self.active:
            self._reject(why, f'{len(self.scorer.truth)} stream ground-truth messages held')
        return self.active

    def episode_info(self) -> None:
        if not self.active and not self._episodes_seen:
            self._episodes_seen = True
            self.scorer.reset_truth()

    # --- output ---------------------------------------------------------------------------
    def tick(self, now: float) -> None:
        if not self.active:
            return
        for w in self.scorer.ready(now):
            self._publish(w)

    def _publish(self, w: WindowScore) -> None:
        empty = Score(math.nan, 0, 0, math.nan, math.nan, 0, math.nan)
        s = w.score or empty
        msg = conv.score_to_msg(
            episode_id=w.number,
            method=w.method,
            score=s,
            mean_accuracy=w.cumulative_accuracy,
            episodes_scored=w.windows_scored,
            stamp_ns=self._node.get_clock().now().nanoseconds,
        )
        msg.mode = AssociationScore.MODE_STREAM
        msg.window_start = conv.ns_to_time(max(w.start_ns, 0))
        msg.window_end = conv.ns_to_time(max(w.end_ns, 0))
        msg.truth_complete = w.truth_complete
        msg.truth_expected = w.truth_expected
        msg.truth_received = w.truth_received
        msg.episodes_incomplete = w.incomplete
        msg.links_published = w.links_published
        msg.links_revised = w.links_revised
        msg.revision_rate = w.links_revised / w.links_published if w.links_published else math.nan
        msg.cumulative_revision_rate = w.cumulative_revision_rate
        self._publisher.publish(msg)
        note = '' if w.truth_complete else ' [truth incomplete]'
        self._node.get_logger().info(
            f'window {w.number} [{w.start_ns / NS_PER_S:g}, {w.end_ns / NS_PER_S:g}) s '
            f'[{w.method}]: accuracy {s.accuracy:.4f} ({s.correct}/{s.total}), revision rate '
            f'{msg.revision_rate:.4f} ({w.links_revised}/{w.links_published}); cumulative '
            f'accuracy {w.cumulative_accuracy:.4f}, revision rate '
            f'{w.cumulative_revision_rate:.4f}{note}'
        )

    def diagnostics(self) -> dict[str, object]:
        if self.mode == 'episodes':
            return {}
        values: dict[str, object] = {
            'stream_active': self.active,
            'stream_windows_published': self.scorer.number,
            'stream_windows_scored': self.scorer.windows_scored,
            'stream_windows_incomplete': self.scorer.incomplete,
            'stream_cumulative_accuracy': self.scorer.last_cumulative,
            **self.scorer.held(),
        }
        values.update({f'stream_{k}': v for k, v in sorted(self.scorer.events.items())})
        return values
