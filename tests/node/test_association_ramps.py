"""The association node in episodes mode on an open road: the layout's entry and exit
positions reach the associator it solves with. Vehicle A passes the first two stations and
leaves at the ramp between the second and third; vehicle B joins there and passes the last
two, 2 s too late to be A at A's speed. Told of the ramp, multiframe keeps them apart; on a
closed road it would continue A with B's last detection and leave B's first unassigned."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from mlkm_assoc.association_node import AssociationNode
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import Detection, EpisodeInfo, SensorLayout, TrackArray

pytestmark = pytest.mark.ros

S = conv.NS_PER_S
IDS = [30, 31, 32, 33]
NAMES = ['r_a', 'r_b', 'r_c', 'r_d']
POS = [100.0, 400.0, 700.0, 1000.0]
LAYOUT = Layout(1100.0, np.array(POS), np.array(IDS), tuple(NAMES))
RAMP = 550.0  # an off-ramp and an on-ramp between the second and third station [m]
#: (station, stamp [s], speed [m/s]) of A (25 m/s) and of B (25 m/s, at 700 m at 32 s)
PASSAGES = [(0, 10.0, 25.0), (1, 22.0, 25.0), (2, 32.0, 25.0), (3, 44.0, 25.0)]


def test_episode_solved_with_the_layouts_ramps(rclpy_context, spin_until) -> None:
    overrides = [
        Parameter('completion_timeout', value=1.0),
        Parameter('segment_size', value=2),
        Parameter('method', value='multiframe'),
    ]
    node = AssociationNode(context=rclpy_context, parameter_overrides=overrides)
    test = Node('ramps_test', context=rclpy_context)
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(node)
    ex.add_node(test)
    tracks: list[TrackArray] = []
    test.create_subscription(TrackArray, qos.TRACKS_TOPIC, tracks.append, qos.TRACKS_QOS)
    layout_pub = test.create_publisher(SensorLayout, qos.LAYOUT_TOPIC, qos.LAYOUT_QOS)
    episode_pub = test.create_publisher(EpisodeInfo, qos.EPISODE_TOPIC, qos.EPISODE_QOS)
    det_pubs = [
        test.create_publisher(Detection, qos.detections_topic(n), qos.DETECTIONS_QOS)
        for n in NAMES
    ]
    try:
        layout_pub.publish(conv.layout_to_msg(LAYOUT, S, None, [RAMP], [RAMP]))
        assert spin_until(ex, lambda: all(p.get_subscription_count() >= 1 for p in det_pubs), 20.0)
        ramps = ((RAMP,), (RAMP,))
        assert spin_until(ex, lambda: (node.config.entries, node.config.exits) == ramps, 20.0)
        window = (0, 60 * S)
        episode_pub.publish(conv.episode_started_msg(0, 2, *window, 2 * S))
        for s, t, v in PASSAGES:
            det_pubs[s].publish(conv.detection_to_msg(IDS[s], conv.seconds_to_ns(t), POS[s], v))
        episode_pub.publish(conv.episode_ended_msg(0, 2, *window, 3 * S, dict.fromkeys(IDS, 1)))
        assert spin_until(ex, lambda: any(t.final for t in tracks), 30.0), 'no final tracks'
        final = next(t for t in tracks if t.final)
        assert len(final.unassigned_sensor_ids) == 0
        assert sorted(list(t.sensor_ids) for t in final.tracks) == [IDS[:2], IDS[2:]]
    finally:
        ex.shutdown()
        test.destroy_node()
        node.destroy_node()
