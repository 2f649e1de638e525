"""The scorer node's stream mode: which messages are the stream's (``mode``), the windows
they are scored in (:mod:`mlkm_assoc.stream_windows`, whose docstring holds the rules), one
AssociationScore MODE_STREAM per window; and the parameters of this mode.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from mlkm_assoc.stream_windows import NS_PER_S, Key, StreamScorer, WindowScore
from mlkm_ros import conversions as conv
from mlkm_ros.params import ParamSpec, positive
from road_sensor_msgs.msg import AssociationScore, TrackArray

#: Parameters of the scorer's stream mode (declared by scorer_node with its own).
STREAM_SPECS = [
    ParamSpec(
        'mode',
        'auto',
        'episodes: score each episode; stream: score windows of an open road; auto: stream '
        'while stream tracks arrive and the source shows no episodes, episodes otherwise [-]',
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


class StreamScoring:
    """The scorer node's stream mode: decides which messages are the stream's, feeds a
    :class:`StreamScorer`, publishes one AssociationScore (MODE_STREAM) per window.

    ``mode`` ``stream``: every TrackArray and GroundTruth is the stream's. ``episodes``:
    nothing here. ``auto`` follows the input both ways, as the association node does: stream
    mode begins with a TrackArray of MODE_STREAM that arrives while the source shows no
    episodes (``episode_source()`` false: no /road/episode publisher, no announced episode
    open); an EpisodeInfo, a TrackArray of MODE_EPISODES or a /road/episode publisher switch
    back to episodes mode at once. Stream tracks arriving in episodes mode (the association
    node flushes its stream when it switches to episodes) are still scored here, with the
    truth the stream had. Ground truth goes to the mode the scorer is in; while in episodes
    mode without an episode source, a copy is kept here too (the association node needs a
    moment before its first stream tracks), given to the stream at the switch, when
    ``forget_unannounced`` lets episodes mode drop its own. A stream after an earlier one is
    a new run: the earlier one's windows are scored with what is at hand, then windows are
    numbered from 0 again.
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
        episode_source: Callable[[], bool],
    ) -> None:
        self._node = node
        self._publisher = publisher
        self.mode = mode
        self.active = mode == 'stream'
        self._source = False  # the source showed episodes at the last look
        self._copies: dict[Key, tuple[int, float]] = {}  # truth kept for a stream to come
        self._reject = reject
        self._forget_unannounced = forget_unannounced
        self._episode_source = episode_source
        self._make = lambda: StreamScorer(window, truth_timeout, max_buffered_truth, sensor_index)
        self.scorer = self._make()
        self.switches = 0

    # --- mode -----------------------------------------------------------------------------
    def _to_stream(self, now: float) -> None:
        if self.scorer.used():
            for w in self.scorer.ready(now, force=True):
                self._publish(w)
            self.scorer = self._make()
            self._node.get_logger().info('a new stream: its windows are numbered from 0')
        self.active = True
        self.switches += 1
        for key, value in self._copies.items():
            self.scorer.add_truth(key, *value)
        self._copies.clear()
        self._forget_unannounced()
        self._node.get_logger().info('stream tracks: scoring windows of the open road')

    def _to_episodes(self, why: str) -> None:
        self.active = False
        self._source = True
        self.switches += 1
        self._node.get_logger().info(f'scoring episodes ({why})')

    # --- inputs ---------------------------------------------------------------------------
    def take_tracks(self, msg) -> bool:
        """True when the TrackArray was the stream's (handled here)."""
        if self.mode == 'episodes':
            return False
        if msg.mode != TrackArray.MODE_STREAM:
            if self.mode == 'auto' and self.active:
                self._to_episodes('tracks of an episode arrived')
            return False
        now = time.monotonic()
        if not self.active and not self._episode_source():
            self._to_stream(now)
        try:
            d = conv.stream_tracks_from_msg(msg)
        except (ValueError, OverflowError) as exc:  # overflow: a track id beyond int64
            self._reject('invalid_tracks', f'stream tracks: {exc}')
            return True
        keys = list(zip(d.sensor_ids.tolist(), d.lanes.tolist(), d.stamps_ns.tolist()))
        note = self.scorer.add_tracks(
            msg.method,
            keys,
            d.labels.tolist(),
            d.status.tolist(),
            d.committed_until_ns,
            now,
            d.run,
        )
        if note and d.run < self.scorer.run:
            self._node.get_logger().warning(note, throttle_duration_sec=2.0)
        elif note:
            self._node.get_logger().info(note)
        return True

    def take_truth(self, msg) -> bool:
        """True when the GroundTruth was the stream's alone."""
        if self.mode == 'auto' and self.active and self._episode_source():
            # An episodes source started: its truth can come before its first EpisodeInfo
            # (another topic) and before the next tick; it is the episodes mode's.
            self._to_episodes('a /road/episode publisher appeared')
        copy = not self.active and not self._source
        if self.mode == 'episodes' or not (self.active or copy):
            return False
        stamp = msg.header.stamp
        if stamp.sec < 0 or stamp.nanosec >= NS_PER_S:
            if self.active:
                self._reject('invalid_truth', f'stream truth: invalid time {stamp.sec} s')
            return self.active
        key = (int(msg.sensor_id), int(msg.lane), conv.time_to_ns(stamp))
        value = (conv.ground_truth_target(msg), float(msg.true_velocity))
        if copy:
            if key in self._copies or len(self._copies) < self.scorer.max_buffered_truth:
                self._copies[key] = value
            return False
        why = self.scorer.add_truth(key, *value)
        if why:
            self._reject(why, f'{len(self.scorer.truth)} stream ground-truth messages held')
        return True

    def episode_info(self) -> None:
        """An EpisodeInfo arrived: the source has episodes."""
        if self.mode != 'auto':
            return
        self._copies.clear()
        if self.active:
            self._to_episodes('an EpisodeInfo arrived')
        self._source = True

    # --- output ---------------------------------------------------------------------------
    def tick(self, now: float) -> None:
        if self.mode == 'episodes':
            return
        if self.mode == 'auto':
            self._source = self._episode_source()
            if self.active and self._source:
                self._to_episodes('a /road/episode publisher appeared')
            if self._source:
                self._copies.clear()
        if self.active or self.scorer.holds():
            for w in self.scorer.ready(now):
                self._publish(w)

    def _publish(self, w: WindowScore) -> None:
        """One AssociationScore for a window with true detections; a log line for one
        without (it has no accuracy)."""
        span = f'window {w.number} [{w.start_ns / NS_PER_S:g}, {w.end_ns / NS_PER_S:g}) s'
        if w.score is None:
            self._node.get_logger().warning(
                f'{span} [{w.method}]: not scored, no true detection at hand '
                f'({w.truth_received} of {w.truth_expected} tracked detections with ground '
                'truth); nothing published'
            )
            return
        s = w.score
        rate = w.links_revised / w.links_published if w.links_published else 0.0
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
        msg.revision_rate = rate
        msg.cumulative_revision_rate = w.cumulative_revision_rate
        self._publisher.publish(msg)
        note = (
            ''
            if w.truth_complete
            else (f' [truth incomplete: {w.truth_received} of {w.truth_expected}]')
        )
        if not w.tracks_final:
            note += ' [tracks not all final]'
        self._node.get_logger().info(
            f'{span} [{w.method}]: accuracy {s.accuracy:.4f} ({s.correct}/{s.total}), revision '
            f'rate {rate:.4f} ({w.links_revised}/{w.links_published}); cumulative '
            f'accuracy {w.cumulative_accuracy:.4f}, revision rate '
            f'{w.cumulative_revision_rate:.4f}{note}'
        )

    def diagnostics(self) -> dict[str, object]:
        if self.mode == 'episodes':
            return {}
        sc = self.scorer
        values: dict[str, object] = {
            'stream_active': self.active,
            'stream_mode_switches': self.switches,
            'stream_run': '' if sc.run is None else sc.run,
            'stream_windows_published': sc.windows_scored,
            'stream_windows_scored': sc.windows_scored,
            'stream_windows_incomplete': sc.incomplete,
            'stream_windows_unscored': sc.unscored,
            'stream_windows_not_final': sc.not_final,
            'stream_cumulative_accuracy': f'{sc.last_cumulative:.6f}' if sc.windows_scored else '',
            'stream_truth_copies': len(self._copies),
            **sc.held(),
        }
        values.update({f'stream_{k}': v for k, v in sorted(self.scorer.events.items())})
        return values
