"""scorer_node joins tracks and ground truth on (sensor, lane, stamp): two vehicles passing
one station in different lanes within the same nanosecond are two true detections, each
scored against its own track. The node runs in process; a probe receives its scores."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from mlkm_assoc.scorer_node import ScorerNode
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import AssociationScore

S = conv.NS_PER_S
LAYOUT = Layout(400.0, np.array([100.0, 200.0]), np.array([10, 11]), ('a', 'b'))
#: (sensor id, stamp ns, lane, target): targets 0 and 1 side by side at sensor 10.
ROWS = [(10, 5 * S, 0, 0), (10, 5 * S, 1, 1), (11, 9 * S, 0, 0), (11, 8 * S, 1, 1)]


@pytest.fixture
def rig(rclpy_context, spin_until):
    node = ScorerNode(context=rclpy_context)
    probe = Node('lanes_probe', context=rclpy_context)
    scores: list[AssociationScore] = []
    probe.create_subscription(AssociationScore, qos.SCORE_TOPIC, scores.append, qos.SCORE_QOS)
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(node)
    ex.add_node(probe)
    node._on_layout(conv.layout_to_msg(LAYOUT, S, [2, 2]))
    yield node, scores, lambda: spin_until(ex, lambda: scores, 30.0)
    ex.shutdown()
    probe.destroy_node()
    node.destroy_node()


def feed(node: ScorerNode, labels: list[int]) -> None:
    node._on_episode(conv.episode_started_msg(0, 2, 0, 20 * S, 2 * S))
    for sensor, stamp, lane, target in ROWS:
        node._on_truth(
            conv.ground_truth_to_msg(0, sensor, stamp, target, 30.0, lane, f'v{target}')
        )
    node._on_episode(conv.episode_ended_msg(0, 2, 0, 20 * S, 3 * S, {10: 2, 11: 2}))
    node._on_tracks(
        conv.tracks_to_msg(
            episode_id=0,
            method='mlkm',
            final=True,
            segments_done=1,
            segments_total=1,
            sensor_ids=[r[0] for r in ROWS],
            stamps_ns=[r[1] for r in ROWS],
            velocities=[30.0] * 4,
            positions=[100.0, 100.0, 200.0, 200.0],
            labels=labels,
            solve_time=0.0,
            stamp_ns=0,
            lanes=[r[2] for r in ROWS],
        )
    )


def test_same_nanosecond_in_two_lanes_scored_separately(rig) -> None:
    node, scores, wait = rig
    feed(node, [0, 1, 0, 1])
    assert wait()
    (score,) = scores
    assert (score.correct, score.total, score.accuracy) == (4, 4, 1.0)
    assert score.truth_complete and score.truth_received == 4


def test_lanes_swapped_at_the_shared_stamp_cost_two_detections(rig) -> None:
    node, scores, wait = rig
    feed(node, [1, 0, 0, 1])  # the side-by-side detections in each other's track
    assert wait()
    (score,) = scores
    assert (score.correct, score.total) == (2, 4)
