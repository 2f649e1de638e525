"""``mlkm_assoc scorer_node``: scores each episode's final tracks against ground truth.

Joins the FINAL TrackArray of an episode with its GroundTruth messages on (sensor id, lane,
stamp in integer ns; lane -1 where unknown) and calls the core's one scoring function,
``mlkm_core.metrics.score`` (the logic is :mod:`mlkm_assoc.episode_scoring`). Stream tracks
of an open road (TrackArray MODE_STREAM) are scored per window of stamp time instead
(parameters ``mode``, ``window``; the logic is :mod:`mlkm_assoc.stream_scoring`); a message
of a later tracker run (TrackArray.run: the association node restarted) ends the earlier
run's tracks as last carried. In mode ``auto`` the node follows its input both ways, as the
association node does.

* Complete truth: EpisodeInfo ENDED says how many detections each sensor published, and one
  GroundTruth was published for each. The node waits for all of them (truth arriving after
  the tracks is fine) while ground truth keeps arriving, and says on /diagnostics which
  episode waits for how many; once no ground truth and no input for the episode arrived for
  ``truth_timeout`` seconds it scores with the truth at hand. Such an episode is published
  with ``truth_complete`` false, counted in ``episodes_incomplete`` and left out of the
  running mean. An episode without any true detection at hand has no accuracy: it is not
  published, only logged and counted (``episodes_unscored``); no score carries NaN.
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

import sys
import time
from collections import Counter

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node

from mlkm_assoc.episode_inputs import ScorerConfig, valid_stamp_ns
from mlkm_assoc.episode_scoring import EpisodeScoring
from mlkm_assoc.stream_scoring import STREAM_SPECS, StreamScoring
from mlkm_core.network_assoc.stations import network_stations
from mlkm_ros import conversions as conv
from mlkm_ros import lifecycle, qos
from mlkm_ros.network_conversions import is_network_msg, msg_to_network
from mlkm_ros.params import ParamSpec, declare_parameters, positive
from road_sensor_msgs.msg import (
    AssociationScore,
    EpisodeInfo,
    GroundTruth,
    SensorLayout,
    TrackArray,
)

#: The defaults of the episodes-mode settings.
_DEFAULTS = ScorerConfig()

SPECS = [
    ParamSpec(
        'truth_timeout',
        _DEFAULTS.truth_timeout,
        'score an episode with the truth at hand when truth is still missing and no '
        'ground truth (nor any input for the episode) arrived for this long [s]',
        1e-3,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'forget_after',
        _DEFAULTS.forget_after,
        'drop an unscored episode (no final tracks) after this long without any input for it [s]',
        1e-3,
        1e9,
        check=positive,
    ),
    ParamSpec(
        'max_open_episodes',
        _DEFAULTS.max_open_episodes,
        'unscored episodes held at once; beyond it the oldest is dropped [episodes]',
        1,
        1_000_000,
    ),
    ParamSpec(
        'max_scored_episodes',
        _DEFAULTS.max_scored_episodes,
        'scored episode ids remembered to drop their late truth and repeated finals [episodes]',
        1,
        10_000_000,
    ),
    ParamSpec(
        'max_buffered_truth',
        _DEFAULTS.max_buffered_truth,
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


class ScorerNode(Node):
    """Final tracks + ground truth -> AssociationScore per episode, with the running mean."""

    def __init__(self, node_name: str = 'scorer_node', **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        values = declare_parameters(self, SPECS, self._on_change)
        diag_period: float = values.pop('diagnostics_period')
        stream_mode, window = values.pop('mode'), values.pop('window')
        config = ScorerConfig(**values)
        self._sensor_index: dict[int, int] = {}
        self._episode_topic = self.resolve_topic_name(qos.EPISODE_TOPIC)
        self._layout_key: tuple | None = None
        self._layout_ns = -1  # publication stamp of the current layout
        self._run_ns = -1  # publication stamp of the message that began this run
        self._runs = 1
        self._rejected: Counter[str] = Counter({r: 0 for r in REJECT_REASONS})
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
        self._episodes = EpisodeScoring(
            self, self._score_pub, config, self._index_of, self._reject
        )
        self._stream = StreamScoring(
            self,
            self._score_pub,
            stream_mode,
            window,
            config.truth_timeout,
            config.max_buffered_truth,
            self._index_of,
            self._reject,
            self._episodes.forget_unannounced,
            self._episode_source,
        )
        self._timer = self.create_timer(0.5, self._on_timer)
        self._diag_timer = self.create_timer(diag_period, self._publish_diagnostics)

    def _on_change(self, changed: dict) -> None:
        self._episodes.config = ScorerConfig(**(self._episodes.config.__dict__ | changed))

    # The episodes mode's bookkeeping, read by the memory-limit test.
    @property
    def _open(self) -> dict:
        return self._episodes._open

    @property
    def _scored(self) -> dict:
        return self._episodes._scored

    @property
    def _buffered(self) -> int:
        return self._episodes._buffered

    def _episode_source(self) -> bool:
        """Whether the source shows episodes: a /road/episode publisher, or an announced
        episode still open."""
        try:
            publishers = self.count_publishers(self._episode_topic)
        except Exception:  # noqa: BLE001 - the context is shutting down
            publishers = 0
        return publishers > 0 or self._episodes.announced_open()

    def _index_of(self, sensor_id: int) -> int:
        """A sensor's index in road order (its id while no layout knows it)."""
        return self._sensor_index.get(sensor_id, sensor_id)

    def _reject(self, reason: str, detail: str) -> None:
        self._rejected[reason] += 1
        self.get_logger().warning(f'{reason}: {detail}', throttle_duration_sec=2.0)

    # --- inputs ---------------------------------------------------------------------------
    def _on_layout(self, msg: SensorLayout) -> None:
        try:
            # a road network's stations in the message's order, as `mlkm associate --layout`
            # indexes them; one road's in road order
            network = is_network_msg(msg)
            if network:
                layout = network_stations(msg_to_network(msg))
            else:
                layout = conv.layout_from_msg(msg)
            stamp = valid_stamp_ns(msg.header.stamp)
        except ValueError as exc:
            self._reject('invalid_layout', f'layout refused, keeping the previous one: {exc}')
            return
        key = (
            layout.road_length,
            tuple(msg.sensor_ids),
            layout.names,
            tuple(msg.positions),
            tuple(msg.sensor_links),
        )
        if key == self._layout_key and (stamp == self._layout_ns or stamp <= self._run_ns):
            return
        if self._layout_key is not None:
            self.get_logger().info('a new layout: a new run of the source begins')
            self._new_run(stamp)
        self._layout_key, self._layout_ns = key, stamp
        self._run_ns = max(self._run_ns, stamp)
        order = (
            range(layout.n_sensors)
            if network
            else np.argsort(np.asarray(msg.positions, dtype=float), kind='stable')
        )
        self._sensor_index = {int(msg.sensor_ids[i]): rank for rank, i in enumerate(order)}

    def _on_episode(self, msg: EpisodeInfo) -> None:
        self._stream.episode_info()
        self._episodes.on_episode(msg)

    def _on_truth(self, msg: GroundTruth) -> None:
        if not self._stream.take_truth(msg):
            self._episodes.on_truth(msg)

    def _on_tracks(self, msg: TrackArray) -> None:
        if not self._stream.take_tracks(msg):
            self._episodes.on_tracks(msg)

    def _on_timer(self) -> None:
        now = time.monotonic()
        self._stream.tick(now)
        self._episodes.tick(now)

    def _new_run(self, stamp_ns: int) -> None:
        """The source restarted (see :meth:`EpisodeScoring.new_run`)."""
        self._episodes.new_run()
        self._run_ns = max(self._run_ns, stamp_ns)
        self._runs += 1

    # --- diagnostics ----------------------------------------------------------------------
    def _publish_diagnostics(self) -> None:
        rejected = sum(self._rejected.values())
        episodes = self._episodes
        troubles = (
            episodes.incomplete
            + episodes.events['episodes_dropped']
            + episodes.events['episodes_unscored']
            + self._stream.scorer.unscored
        )
        values = {
            **episodes.diagnostics(time.monotonic()),
            'runs': self._runs,
            **{f'rejected_{r}': n for r, n in sorted(self._rejected.items())},
            **dict(sorted(episodes.events.items())),
            **self._stream.diagnostics(),
        }
        level, message = DiagnosticStatus.OK, 'scoring'
        if values['episodes_waiting_for_truth']:
            message = f'waiting for ground truth: {values["truth_waiting"]}'
        if (rejected, troubles) != self._reported:
            level, message = (
                DiagnosticStatus.WARN,
                'inputs rejected or episodes/windows scored incomplete, dropped or not '
                'scored since the last status',
            )
        self._reported = (rejected, troubles)
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
    return lifecycle.run_node('scorer_node', ScorerNode, args)


if __name__ == '__main__':
    sys.exit(main())
