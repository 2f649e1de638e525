"""scorer_node across processes: ``sensor_sim`` restarted against running nodes, as one does
with the nodes in separate terminals.

Every process is started through the ``ros_process`` fixture, which stops it at teardown
even when the test fails.
"""

from __future__ import annotations

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import AssociationScore, GroundTruth, TrackArray

pytestmark = [pytest.mark.ros, pytest.mark.slow]

EPISODES = 2
SIM = ('n_targets:=20', 'n_sensors:=8', 'seed:=3', f'episodes:={EPISODES}')


class Listener:
    """Every score, the stream TrackArrays and the association node's diagnostics; a truth
    subscription (the gate of the second source run) once ``open_gate`` is called."""

    def __init__(self, context) -> None:
        self.node = Node('scorer_graph_listener', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.scores: list[AssociationScore] = []
        self.stream_tracks = 0
        self.diag: dict[str, str] = {}
        self.node.create_subscription(
            AssociationScore, qos.SCORE_TOPIC, self.scores.append, qos.SCORE_QOS
        )
        self.node.create_subscription(
            TrackArray, qos.TRACKS_TOPIC, self._on_tracks, qos.TRACKS_QOS
        )
        self.node.create_subscription(
            DiagnosticArray, qos.DIAGNOSTICS_TOPIC, self._on_diag, qos.DIAGNOSTICS_QOS
        )

    def _on_tracks(self, msg: TrackArray) -> None:
        self.stream_tracks += msg.mode == TrackArray.MODE_STREAM

    def _on_diag(self, msg: DiagnosticArray) -> None:
        values = conv.diagnostics_values(msg, '/association_node')
        if values is not None:
            self.diag = values

    def open_gate(self) -> None:
        self.node.create_subscription(
            GroundTruth, qos.GROUND_TRUTH_TOPIC, lambda _: None, qos.GROUND_TRUTH_QOS
        )

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.fixture
def listener(rclpy_context):
    lst = Listener(rclpy_context)
    yield lst
    lst.close()


def test_restarted_source_is_scored_per_episode(ros_process, listener, spin_until) -> None:
    """Association and scorer in mode auto keep running while sensor_sim runs twice with one
    seed. Between the runs the association node has no episode source and switches to stream
    mode; the second run's /road/episode publisher switches it back, and it flushes its
    stream: a MODE_STREAM TrackArray reaches the scorer before the second run's first
    ground truth (the run waits for a second truth subscriber, the listener, which
    subscribes only once it saw that TrackArray). The second run is scored per episode,
    exactly as the first."""
    assoc = ros_process(
        'mlkm_assoc',
        'association_node',
        '--ros-args',
        '-p',
        'method:=mlkm',
        '-p',
        'diagnostics_period:=0.2',
    )
    scorer = ros_process('mlkm_assoc', 'scorer_node')
    ex = listener.executor

    def matched() -> bool:
        node = listener.node
        return node.count_publishers('/mlkm/tracks') >= 1 and (
            node.count_subscribers('/mlkm/tracks') >= 2
        )

    assert spin_until(ex, matched, 60.0), assoc.output() + scorer.output()
    args = [a for p in SIM for a in ('-p', p)]
    first = ros_process(
        'road_sensors',
        'sensor_sim',
        '--ros-args',
        *args,
        '-p',
        'wait_for_subscribers:=1',
        '-p',
        'wait_for_truth_subscribers:=1',
    )
    assert spin_until(ex, lambda: len(listener.scores) >= EPISODES, 120.0), (
        first.output() + scorer.output()
    )
    assert first.proc.wait(60) == 0, first.output()
    # no episode source any more: the association node goes to stream mode
    assert spin_until(ex, lambda: listener.diag.get('mode') == 'stream', 60.0), listener.diag
    seen = listener.stream_tracks
    second = ros_process(
        'road_sensors',
        'sensor_sim',
        '--ros-args',
        *args,
        '-p',
        'wait_for_subscribers:=1',
        '-p',
        'wait_for_truth_subscribers:=2',
    )
    # the association node sees the new source, goes back to episodes and flushes its stream
    assert spin_until(ex, lambda: listener.stream_tracks > seen, 120.0), (
        assoc.output() + second.output()
    )
    listener.open_gate()
    assert spin_until(ex, lambda: len(listener.scores) >= 2 * EPISODES, 120.0), (
        second.output() + scorer.output()
    )
    assert second.proc.wait(60) == 0, second.output()
    # each run's episodes in id order: the scorer publishes an episode when its truth is
    # complete, which on a busy machine need not be in the order of the episodes
    by_id = lambda scores: sorted(scores, key=lambda s: s.episode_id)  # noqa: E731
    run1, run2 = by_id(listener.scores[:EPISODES]), by_id(listener.scores[EPISODES:])
    for s1, s2 in zip(run1, run2, strict=True):
        assert s2.mode == AssociationScore.MODE_EPISODES
        assert s2.truth_complete and s2.total == 20 * 8
        assert (s2.episode_id, s2.accuracy, s2.correct) == (s1.episode_id, s1.accuracy, s1.correct)
