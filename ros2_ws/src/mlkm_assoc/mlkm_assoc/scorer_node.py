"""``mlkm_assoc scorer_node``: scores each episode's final tracks against ground truth.

Joins the FINAL TrackArray of an episode with its GroundTruth messages on (sensor id, stamp
in integer ns) and calls the core's one scoring function, ``mlkm_core.metrics.score``. It
waits until it has all of the episode's truth (the EpisodeInfo ENDED counts say how much) so
truth arriving after the tracks is fine; after ``truth_timeout`` it scores with the truth
it has and says so. Publishes AssociationScore on /mlkm/score (latched) and logs one line
per episode.
"""

from __future__ import annotations

import statistics
import sys
import time
from dataclasses import dataclass

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from mlkm_core.metrics import Score, score
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
]


@dataclass(frozen=True)
class ScorerConfig:
    truth_timeout: float = 10.0  # [s]


class ScorerNode(Node):
    """Final tracks + ground truth -> AssociationScore per episode, with the running mean."""

    def __init__(self, node_name: str = 'scorer_node', **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        values = declare_parameters(self, SPECS, self._on_change)
        self._config: ScorerConfig = ScorerConfig(**values)
        # episode id -> {(sensor id, stamp ns): (target, true velocity)}
        self._truth: dict[int, dict[tuple[int, int], tuple[int, float]]] = {}
        self._expected: dict[int, int] = {}  # episode id -> number of detections (ENDED)
        self._finals: dict[int, tuple[TrackArray, float]] = {}  # id -> (msg, t_received)
        self._scored: set[int] = set()
        self._accuracies: list[float] = []
        self._sensor_index: dict[int, int] = {}
        self._score_pub = self.create_publisher(AssociationScore, qos.SCORE_TOPIC, qos.SCORE_QOS)
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
        self._timer = self.create_timer(0.5, self._on_timer)

    def _on_change(self, changed: dict) -> None:
        self._config = ScorerConfig(**(self._config.__dict__ | changed))

    # --- inputs ---------------------------------------------------------------------------
    def _on_layout(self, msg: SensorLayout) -> None:
        order = np.argsort(np.asarray(msg.positions, dtype=float), kind='stable')
        self._sensor_index = {int(msg.sensor_ids[i]): rank for rank, i in enumerate(order)}

    def _on_truth(self, msg: GroundTruth) -> None:
        episode = msg.episode_id
        if episode in self._scored:
            return
        stamp = msg.header.stamp
        self._truth.setdefault(episode, {})[
            (msg.sensor_id, stamp.sec * NS_PER_S + stamp.nanosec)
        ] = (conv.ground_truth_target(msg), msg.true_velocity)
        if episode in self._finals and len(self._truth[episode]) >= self._expected.get(
            episode, 1 << 62
        ):
            self._score(episode)

    def _on_episode(self, msg: EpisodeInfo) -> None:
        if msg.status == EpisodeInfo.STATUS_ENDED:
            self._expected[msg.episode_id] = int(sum(msg.detection_counts))
            self._try(msg.episode_id)

    def _on_tracks(self, msg: TrackArray) -> None:
        if msg.final and msg.episode_id not in self._scored:
            self._finals[msg.episode_id] = (msg, time.monotonic())
            self._try(msg.episode_id)

    def _on_timer(self) -> None:
        now = time.monotonic()
        for episode, (_, t_rx) in list(self._finals.items()):
            if now - t_rx > self._config.truth_timeout:
                have = len(self._truth.get(episode, {}))
                want = self._expected.get(episode)
                self.get_logger().warning(
                    f'episode {episode}: scoring with {have} truth messages '
                    f'({"unknown" if want is None else want} expected) after waiting '
                    f'{self._config.truth_timeout:g} s'
                )
                self._score(episode)

    # --- scoring --------------------------------------------------------------------------
    def _try(self, episode: int) -> None:
        if (
            episode in self._finals
            and episode in self._expected
            and len(self._truth.get(episode, {})) >= self._expected[episode]
        ):
            self._score(episode)

    def _score(self, episode: int) -> None:
        tracks, _ = self._finals.pop(episode)
        truth = self._truth.pop(episode, {})
        self._scored.add(episode)
        ids, stamps, _, labels = conv.tracks_from_msg(tracks)
        track_of = dict(zip(zip(ids.tolist(), stamps.tolist()), labels.tolist()))
        keys = list(truth)
        sensor_ids = np.array([k[0] for k in keys], dtype=np.int64)
        stamps_ns = np.array([k[1] for k in keys], dtype=np.int64)
        index = self._sensor_index
        sensor_index = np.array([index.get(s, s) for s in sensor_ids.tolist()], np.int64)
        values = list(truth.values())
        detections = Detections(
            sensor_index,
            conv.ns_to_seconds(stamps_ns),
            np.array([v[1] for v in values], dtype=float),
            np.array([v[0] for v in values], dtype=np.int64),
        )
        labels_all = np.array([track_of.get(k, -1) for k in keys], dtype=np.int64)
        result: Score = score(detections, labels_all)
        self._accuracies.append(result.accuracy)
        mean = statistics.fmean(self._accuracies)
        self._score_pub.publish(
            conv.score_to_msg(
                episode_id=episode,
                method=tracks.method,
                score=result,
                mean_accuracy=mean,
                episodes_scored=len(self._accuracies),
                stamp_ns=self.get_clock().now().nanoseconds,
            )
        )
        self.get_logger().info(
            f'episode {episode} [{tracks.method}]: accuracy {result.accuracy:.4f} '
            f'({result.correct}/{result.total}), link P/R {result.link_precision:.4f}/'
            f'{result.link_recall:.4f}, id switches {result.identity_switches}, '
            f'ARI {result.adjusted_rand_index:.4f}; mean accuracy {mean:.4f} over '
            f'{len(self._accuracies)} episode(s)'
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
