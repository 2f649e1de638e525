"""``mlkm_assoc scorer_node``: scores each episode's final tracks against ground truth.

Joins the FINAL TrackArray of an episode with its GroundTruth messages on (sensor id, lane,
stamp in integer ns; lane -1 where unknown) and calls the core's one scoring function,
``mlkm_core.metrics.score``. Stream tracks of an open road (TrackArray MODE_STREAM) are
scored per window of stamp time instead (parameters ``mode``, ``window``; the logic is
:mod:`mlkm_assoc.stream_scoring`).

* Complete truth: EpisodeInfo ENDED says how many detections each sensor published, and one
  GroundTruth was published for each. The node waits for all of them (truth arriving after
  the tracks is fine); ``truth_timeout`` seconds after the final tracks it scores with the
  truth at hand. Such an episode is published with ``truth_complete`` false, counted in
  ``episodes_incomplete`` and left out of the running mean, as is an episode without any
  true detection (its accuracy is NaN, never a perfect 1).
* Runs: a restarted source numbers its episodes from 0 again. A new run begins with a layout
  of other content or published later than the current run began, or, for one episode id,
  with an EpisodeInfo of another window or number of targets (or a STARTED published at
  another time). The scored ids are forgotten; an old episode still waiting for its final or
  truth is scored as usual, or with what it has when the new run's EpisodeInfo for its id
  comes; the new run's episodes are scored as they come.
* Memory: scored ids are remembered (to drop their late truth and repeated finals) up to
  ``max_scored_episodes``; an unscored episode without input for ``forget_after`` seconds,
  or beyond ``max_open_episodes``, is dropped (counted); at most ``max_buffered_truth``
  truth messages are held; the running mean is a sum and a count.

Publishes AssociationScore on /mlkm/score (latched), a status on /diagnostics (rejected
inputs with reasons, buffers, episodes) and logs one line per episode.
"""

from __future__ import annotations

import math
import sys
import time
from collections import Counter, OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from mlkm_assoc.stream_scoring import STREAM_SPECS, StreamScoring
from mlkm_core.metrics import score
from mlkm_core.types import Detections
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from mlkm_ros.params import ParameterError, ParamSpec, declare_parameters, positive
from road_sensor_msgs.msg import (
    AssociationScore,
    EpisodeInfo,
    GroundTruth,
    SensorLayout,
    TrackArray,
)

NS_PER_S = conv.NS_PER_S
Key = tuple[int, int, int]  # (sensor id, stamp ns, lane): the join key
Window = tuple[int, int, int]  # (num_targets, start ns, end ns) of an EpisodeInfo

SPECS = [
    ParamSpec(
        'truth_timeout',
        10.0,
        'score an episode with the truth at hand when its final tracks arrived this '
        'long ago and truth is still missing [s]',
        1e-3,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'forget_after',
        300.0,
        'drop an unscored episode (no final tracks) after this long without any input for it [s]',
        1e-3,
        1e9,
        check=positive,
    ),
    ParamSpec(
        'max_open_episodes',
        100,
        'unscored episodes held at once; beyond it the oldest is dropped [episodes]',
        1,
        1_000_000,
    ),
    ParamSpec(
        'max_scored_episodes',
        1000,
        'scored episode ids remembered to drop their late truth and repeated finals [episodes]',
        1,
        10_000_000,
    ),
    ParamSpec(
        'max_buffered_truth',
        1_000_000,
        'ground-truth messages held for unscored episodes; beyond it new ones are '
        'rejected [messages]',
        1,
        1_000_000_000,
    ),
    ParamSpec(
        'diagnostics_period',
        1.0,
        'period of the /diagnostics status [s]',
        1e-2,
        3600.0,
        check=positive,
        read_only=True,
    ),
]

SPECS += STREAM_SPECS

#: Reasons an input is rejected (counted in /diagnostics).
REJECT_REASONS = (
    'invalid_layout',
    'invalid_episode',
    'invalid_truth',
    'invalid_tracks',
    'truth_buffer_full',
)


@dataclass(frozen=True)
class ScorerConfig:
    truth_timeout: float = 10.0  # [s]
    forget_after: float = 300.0  # [s]
    max_open_episodes: int = 100  # [episodes]
    max_scored_episodes: int = 1000  # [episodes]
    max_buffered_truth: int = 1_000_000  # [messages]


@dataclass
class _Episode:
    """One unscored episode of the current run."""

    last_rx: float  # monotonic time of its last input [s]
    window: Window | None = None
    started_ns: int | None = None  # publication stamp of its STARTED
    counts: dict[int, int] | None = None  # ENDED: {sensor id: detections published}
    truth: dict[Key, tuple[int, float]] = field(default_factory=dict)  # -> (target, true v)
    final: TrackArray | None = None
    final_rx: float = 0.0

    def inside(self, stamp_ns: int) -> bool:
        return self.window is None or self.window[1] <= stamp_ns <= self.window[2]


@dataclass(frozen=True)
class _Scored:
    window: Window | None
    started_ns: int | None


def _stamp_ns(stamp) -> int:
    if stamp.sec < 0 or stamp.nanosec >= NS_PER_S:
        raise ValueError(f'invalid time {stamp.sec} s {stamp.nanosec} ns')
    return conv.time_to_ns(stamp)


def _check_tracks(msg: TrackArray) -> list[int]:
    """Stamps [ns] of every detection in the tracks; ValueError when arrays disagree."""
    stamps = []
    for track in msg.tracks:
        n = len(track.sensor_ids)
        if not (len(track.stamps) == len(track.velocities) == len(track.positions) == n):
            raise ValueError(f'track {track.track_id}: parallel arrays differ in length')
        stamps.extend(_stamp_ns(t) for t in track.stamps)
    n = len(msg.unassigned_sensor_ids)
    if not (len(msg.unassigned_stamps) == len(msg.unassigned_velocities) == n):
        raise ValueError('unassigned_* arrays differ in length')
    stamps.extend(_stamp_ns(t) for t in msg.unassigned_stamps)
    conv.track_lanes_from_msg(msg)  # lanes/lengths empty or parallel to sensor_ids
    return stamps


class ScorerNode(Node):
    """Final tracks + ground truth -> AssociationScore per episode, with the running mean."""

    def __init__(self, node_name: str = 'scorer_node', **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        values = declare_parameters(self, SPECS, self._on_change)
        diag_period: float = values.pop('diagnostics_period')
        stream_mode, window = values.pop('mode'), values.pop('window')
        self._config: ScorerConfig = ScorerConfig(**values)
        self._open: dict[int, _Episode] = {}  # unscored episodes, by id
        self._scored: OrderedDict[int, _Scored] = OrderedDict()  # oldest first
        self._buffered = 0  # truth messages held in self._open
        self._sensor_index: dict[int, int] = {}
        self._layout_key: tuple | None = None
        self._layout_ns = -1  # publication stamp of the current layout
        self._run_ns = -1  # publication stamp of the message that began this run
        self._runs = 1
        self._sum = 0.0  # accuracies in the mean
        self._in_mean = 0
        self._incomplete = 0
        self._rejected: Counter[str] = Counter({r: 0 for r in REJECT_REASONS})
        self._events: Counter[str] = Counter()
        self._reported = (0, 0)  # (rejected, incomplete + dropped) at the last status
        self._score_pub = self.create_publisher(AssociationScore, qos.SCORE_TOPIC, qos.SCORE_QOS)
        self._diag_pub = self.create_publisher(
            DiagnosticArray, qos.DIAGNOSTICS_TOPIC, qos.DIAGNOSTICS_QOS
        )
        self._subs = [
            self.create_subscription(
                TrackArray, qos.TRACKS_TOPIC, self._on_tracks, qos.TRACKS_QOS
            ),
            self.create_subscription(
                GroundTruth, qos.GROUND_TRUTH_TOPIC, self._on_truth, qos.GROUND_TRUTH_QOS
            ),
            self.create_subscription(
                EpisodeInfo, qos.EPISODE_TOPIC, self._on_episode, qos.EPISODE_QOS
            ),
            self.create_subscription(
                SensorLayout, qos.LAYOUT_TOPIC, self._on_layout, qos.LAYOUT_QOS
            ),
        ]
        self._stream = StreamScoring(
            self,
            self._score_pub,
            stream_mode,
            window,
            self._config.truth_timeout,
            self._config.max_buffered_truth,
            lambda sensor_id: self._sensor_index.get(sensor_id, sensor_id),
            self._reject,
            self._forget_unannounced,
        )
        self._timer = self.create_timer(0.5, self._on_timer)
        self._diag_timer = self.create_timer(diag_period, self._publish_diagnostics)

    def _on_change(self, changed: dict) -> None:
        self._config = ScorerConfig(**(self._config.__dict__ | changed))

    def _reject(self, reason: str, detail: str) -> None:
        self._rejected[reason] += 1
        self.get_logger().warning(f'{reason}: {detail}', throttle_duration_sec=2.0)

    # --- inputs ---------------------------------------------------------------------------
    def _on_layout(self, msg: SensorLayout) -> None:
        try:
            layout = conv.layout_from_msg(msg)
            stamp = _stamp_ns(msg.header.stamp)
        except ValueError as exc:
            self._reject('invalid_layout', f'layout refused, keeping the previous one: {exc}')
            return
        key = (layout.road_length, tuple(msg.sensor_ids), layout.names, tuple(msg.positions))
        if key == self._layout_key and (stamp == self._layout_ns or stamp <= self._run_ns):
            return
        if self._layout_key is not None:
            self.get_logger().info('a new layout: a new run of the source begins')
            self._new_run(stamp)
        self._layout_key, self._layout_ns = key, stamp
        self._run_ns = max(self._run_ns, stamp)
        order = np.argsort(np.asarray(msg.positions, dtype=float), kind='stable')
        self._sensor_index = {int(msg.sensor_ids[i]): rank for rank, i in enumerate(order)}

    def _on_episode(self, msg: EpisodeInfo) -> None:
        self._stream.episode_info()
        try:
            info = conv.episode_from_msg(msg)
        except ValueError as exc:
            self._reject('invalid_episode', f'episode {msg.episode_id}: {exc}')
            return
        episode, now = info.episode_id, time.monotonic()
        window = (info.num_targets, info.start_ns, info.end_ns)
        started = info.counts is None
        pending = self._open.get(episode)
        known = pending if pending is not None else self._scored.get(episode)
        if known is not None and known.window is not None:
            first = known.started_ns
            restarted = started and first is not None and info.published_ns != first
            if known.window != window or restarted:
                self.get_logger().info(
                    f'episode {episode}: EpisodeInfo of a new run of the source; '
                    'forgetting the previous one'
                )
                self._restart_episode(episode, window, now)
            elif pending is None:
                return  # a repeated EpisodeInfo of a scored episode
        ep = self._episode(episode, now)
        ep.window = window
        if started:
            ep.started_ns = ep.started_ns if ep.started_ns is not None else info.published_ns
        else:
            ep.counts = info.counts
        self._try(episode)

    def _on_truth(self, msg: GroundTruth) -> None:
        if self._stream.take_truth(msg):
            return
        try:
            stamp = _stamp_ns(msg.header.stamp)
        except ValueError as exc:
            self._reject('invalid_truth', f'episode {msg.episode_id}: {exc}')
            return
        episode, now = msg.episode_id, time.monotonic()
        done = self._scored.get(episode)
        if done is not None and episode not in self._open:
            if done.window is None or done.window[1] <= stamp <= done.window[2]:
                self._events['truth_after_score'] += 1
                return
        key = (int(msg.sensor_id), stamp, int(msg.lane))
        ep = self._open.get(episode)
        if (
            ep is None or key not in ep.truth
        ) and self._buffered >= self._config.max_buffered_truth:
            self._reject(
                'truth_buffer_full',
                f'episode {episode}: {self._buffered} ground-truth messages held already',
            )
            return
        ep = self._episode(episode, now)
        if key not in ep.truth:
            self._buffered += 1
        ep.truth[key] = (conv.ground_truth_target(msg), float(msg.true_velocity))
        self._try(episode)

    def _on_tracks(self, msg: TrackArray) -> None:
        if self._stream.take_tracks(msg):
            return
        try:
            stamps = _check_tracks(msg)
        except ValueError as exc:
            self._reject('invalid_tracks', f'episode {msg.episode_id}: {exc}')
            return
        if not msg.final:
            return
        episode, now = msg.episode_id, time.monotonic()
        done = self._scored.get(episode)
        if done is not None and episode not in self._open:
            w = done.window
            if w is None or all(w[1] <= s <= w[2] for s in stamps):
                self._events['final_after_score'] += 1
                return
        ep = self._episode(episode, now)
        ep.final, ep.final_rx = msg, now
        self._try(episode)

    def _on_timer(self) -> None:
        now, cfg = time.monotonic(), self._config
        self._stream.tick(now)
        for episode, ep in list(self._open.items()):
            if ep.final is not None and now - ep.final_rx > cfg.truth_timeout:
                self.get_logger().warning(
                    f'episode {episode}: scoring with {len(ep.truth)} ground-truth messages '
                    f'({"unknown" if ep.counts is None else sum(ep.counts.values())} expected) '
                    f'after waiting {cfg.truth_timeout:g} s'
                )
                self._score(episode)
            elif ep.final is None and now - ep.last_rx > cfg.forget_after:
                self._drop(episode, f'no final tracks for {cfg.forget_after:g} s')

    # --- bookkeeping ----------------------------------------------------------------------
    def _episode(self, episode: int, now: float) -> _Episode:
        """The open record of ``episode`` (created, and the oldest dropped past the limit)."""
        ep = self._open.get(episode)
        if ep is None:
            while len(self._open) >= self._config.max_open_episodes:
                oldest = min(self._open, key=lambda k: self._open[k].last_rx)
                if self._open[oldest].final is not None:
                    self._score(oldest)
                else:
                    self._drop(oldest, f'more than {self._config.max_open_episodes} open')
            ep = self._open[episode] = _Episode(last_rx=now)
        ep.last_rx = now
        return ep

    def _forget_unannounced(self) -> None:
        """The source is a stream: drop the truth held for episodes no EpisodeInfo announced
        (stream mode kept its own copy)."""
        for episode, ep in list(self._open.items()):
            if ep.window is None and ep.final is None:
                self._buffered -= len(self._open.pop(episode).truth)

    def _drop(self, episode: int, why: str) -> None:
        ep = self._open.pop(episode)
        self._buffered -= len(ep.truth)
        self._events['episodes_dropped'] += 1
        self.get_logger().warning(
            f'episode {episode}: dropped unscored ({why}; {len(ep.truth)} ground-truth messages)'
        )

    def _restart_episode(self, episode: int, window: Window, now: float) -> None:
        """A new run of ``episode``: the old one is scored with what it has (if its final
        came) or forgotten; truth that only the new window holds is kept for the new run."""
        self._scored.pop(episode, None)
        old = self._open.get(episode)
        if old is None:
            return
        moved = {
            k: v
            for k, v in old.truth.items()
            if not old.inside(k[1]) and window[1] <= k[1] <= window[2]
        }
        for k in moved:
            del old.truth[k]
        if old.final is not None:
            self._score(episode)
        else:
            self._drop(episode, 'a new run of the source began')
        self._scored.pop(episode, None)
        if moved:
            self._episode(episode, now).truth.update(moved)
            self._buffered += len(moved)

    def _new_run(self, stamp_ns: int) -> None:
        """The source restarted: its episode ids start again, so the scored ids are
        forgotten. Unscored episodes stay: the old run's last finals may still be on their
        way; each is scored as usual, or replaced when the new run's EpisodeInfo for its id
        comes, or dropped after ``forget_after``."""
        self._scored.clear()
        self._run_ns = max(self._run_ns, stamp_ns)
        self._runs += 1

    def _remember(self, episode: int, ep: _Episode) -> None:
        self._scored[episode] = _Scored(ep.window, ep.started_ns)
        self._scored.move_to_end(episode)
        while len(self._scored) > self._config.max_scored_episodes:
            self._scored.popitem(last=False)

    # --- scoring --------------------------------------------------------------------------
    @staticmethod
    def _complete(ep: _Episode, truth: Iterable[Key]) -> bool:
        """Whether ``truth`` (keys inside the window) holds every ENDED count."""
        if ep.counts is None:
            return False
        have = Counter(key[0] for key in truth)
        return all(have[sensor] >= n for sensor, n in ep.counts.items())

    def _try(self, episode: int) -> None:
        ep = self._open[episode]
        if (
            ep.final is not None
            and ep.counts is not None
            and len(ep.truth) >= sum(ep.counts.values())  # cheap, before the full count
            and self._complete(ep, [k for k in ep.truth if ep.inside(k[1])])
        ):
            self._score(episode)

    def _score(self, episode: int) -> None:
        ep = self._open.pop(episode)
        self._buffered -= len(ep.truth)
        truth = {k: v for k, v in ep.truth.items() if ep.inside(k[1])}
        tracks = ep.final
        complete = self._complete(ep, truth)
        self._remember(episode, ep)
        ids, stamps, _, labels = conv.tracks_from_msg(tracks)
        lanes, _ = conv.track_lanes_from_msg(tracks)
        track_of = dict(zip(zip(ids.tolist(), stamps.tolist(), lanes.tolist()), labels.tolist()))
        keys = list(truth)
        index = self._sensor_index
        values = list(truth.values())
        detections = Detections(
            np.array([index.get(k[0], k[0]) for k in keys], dtype=np.int64),
            conv.ns_to_seconds([k[1] for k in keys]),
            np.array([v[1] for v in values], dtype=float),
            np.array([v[0] for v in values], dtype=np.int64),
        )
        result = score(detections, np.array([track_of.get(k, -1) for k in keys], np.int64))
        accuracy = result.accuracy if result.total > 0 else math.nan
        if complete and result.total > 0:
            self._sum += accuracy
            self._in_mean += 1
        elif not complete:
            self._incomplete += 1
        mean = self._sum / self._in_mean if self._in_mean else math.nan
        msg = conv.score_to_msg(
            episode_id=episode,
            method=tracks.method,
            score=result,
            mean_accuracy=mean,
            episodes_scored=self._in_mean,
            stamp_ns=self.get_clock().now().nanoseconds,
        )
        msg.accuracy = accuracy
        msg.truth_complete = complete
        msg.truth_expected = 0 if ep.counts is None else sum(ep.counts.values())
        msg.truth_received = len(truth)
        msg.episodes_incomplete = self._incomplete
        self._score_pub.publish(msg)
        note = (
            ''
            if complete
            else (
                f' [truth incomplete: {len(truth)} of '
                f'{"unknown" if ep.counts is None else msg.truth_expected}; not in the mean]'
            )
        )
        self.get_logger().info(
            f'episode {episode} [{tracks.method}]: accuracy {accuracy:.4f} '
            f'({result.correct}/{result.total}), link P/R {result.link_precision:.4f}/'
            f'{result.link_recall:.4f}, id switches {result.identity_switches}, '
            f'ARI {result.adjusted_rand_index:.4f}; mean accuracy {mean:.4f} over '
            f'{self._in_mean} episode(s){note}'
        )

    # --- diagnostics ----------------------------------------------------------------------
    def _publish_diagnostics(self) -> None:
        rejected = sum(self._rejected.values())
        troubles = self._incomplete + self._events['episodes_dropped']
        level, message = DiagnosticStatus.OK, 'scoring'
        if (rejected, troubles) != self._reported:
            level, message = (
                DiagnosticStatus.WARN,
                ('inputs rejected or episodes scored incomplete/dropped since the last status'),
            )
        self._reported = (rejected, troubles)
        values = {
            'episodes_scored': self._in_mean,
            'episodes_incomplete': self._incomplete,
            'mean_accuracy': self._sum / self._in_mean if self._in_mean else math.nan,
            'open_episodes': len(self._open),
            'buffered_truth': self._buffered,
            'remembered_scored': len(self._scored),
            'runs': self._runs,
            **{f'rejected_{r}': n for r, n in sorted(self._rejected.items())},
            **dict(sorted(self._events.items())),
            **self._stream.diagnostics(),
        }
        self._diag_pub.publish(
            conv.diagnostics_to_msg(
                name=self.get_fully_qualified_name(),
                hardware_id='mlkm_assoc',
                level=level[0] if isinstance(level, bytes) else level,
                message=message,
                values=values,
                stamp_ns=self.get_clock().now().nanoseconds,
            )
        )


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    try:
        node = ScorerNode()
    except ParameterError as exc:
        print(f'scorer_node: {exc}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
