"""The association node in process (private rclpy Context) on a road whose stations report
lanes: two vehicles side by side pass the first station in the same nanosecond; both are kept
and end in separate final tracks with their lanes and lengths, while a detection in a lane the
station does not have and one with an absurd length are rejected with their reasons counted
in /diagnostics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from mlkm_assoc.association_node import AssociationNode
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import Detection, EpisodeInfo, SensorLayout, Track, TrackArray

pytestmark = pytest.mark.ros

S = conv.NS_PER_S
IDS = [20, 21, 22]
NAMES = ['l_a', 'l_b', 'l_c']
POS = [100.0, 400.0, 700.0]
LANES = [2, 2, 3]
LAYOUT = Layout(800.0, np.array(POS), np.array(IDS), tuple(NAMES))
#: lane -> (length [m], speed [m/s]): a truck and a car side by side at the first station
#: (the same nanosecond), then each at its own speed in its own lane.
VEHICLES = {0: (16.5, 22.0), 1: (4.25, 33.0)}


def stamp(s: int, lane: int) -> int:
    return 10 * S + conv.seconds_to_ns((POS[s] - POS[0]) / VEHICLES[lane][1])


def test_side_by_side_vehicles_kept_and_bad_lane_or_length_rejected(
    rclpy_context, spin_until
) -> None:
    overrides = [
        Parameter('diagnostics_period', value=0.2),
        Parameter('completion_timeout', value=1.0),
        Parameter('segment_size', value=2),
        Parameter('method', value='assignment'),
    ]
    node = AssociationNode(context=rclpy_context, parameter_overrides=overrides)
    test = Node('lanes_test', context=rclpy_context)
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(node)
    ex.add_node(test)
    tracks: list[TrackArray] = []
    diag: dict[str, str] = {}

    def on_diag(msg: DiagnosticArray) -> None:
        values = conv.diagnostics_values(msg, node.get_fully_qualified_name())
        if values is not None:
            diag.update(values)

    test.create_subscription(TrackArray, qos.TRACKS_TOPIC, tracks.append, qos.TRACKS_QOS)
    test.create_subscription(DiagnosticArray, qos.DIAGNOSTICS_TOPIC, on_diag, qos.DIAGNOSTICS_QOS)
    layout_pub = test.create_publisher(SensorLayout, qos.LAYOUT_TOPIC, qos.LAYOUT_QOS)
    episode_pub = test.create_publisher(EpisodeInfo, qos.EPISODE_TOPIC, qos.EPISODE_QOS)
    det_pubs = [
        test.create_publisher(Detection, qos.detections_topic(n), qos.DETECTIONS_QOS)
        for n in NAMES
    ]
    try:
        layout_pub.publish(conv.layout_to_msg(LAYOUT, S, LANES))
        assert spin_until(ex, lambda: all(p.get_subscription_count() >= 1 for p in det_pubs), 20.0)
        window = (0, 60 * S)
        episode_pub.publish(conv.episode_started_msg(0, 2, *window, 2 * S))
        for s in range(3):
            for lane, (length, speed) in VEHICLES.items():
                det_pubs[s].publish(
                    conv.detection_to_msg(IDS[s], stamp(s, lane), POS[s], speed, lane, length)
                )
        det_pubs[0].publish(conv.detection_to_msg(IDS[0], 30 * S, POS[0], 25.0, 2, 4.0))
        det_pubs[2].publish(conv.detection_to_msg(IDS[2], 31 * S, POS[2], 25.0, 2, 400.0))
        counts = {IDS[0]: 3, IDS[1]: 2, IDS[2]: 3}
        episode_pub.publish(conv.episode_ended_msg(0, 2, *window, 3 * S, counts))
        assert spin_until(ex, lambda: any(t.final for t in tracks), 30.0), 'no final tracks'
        final = next(t for t in tracks if t.final)
        assert final.mode == TrackArray.MODE_EPISODES
        assert len(final.tracks) == 2 and len(final.unassigned_sensor_ids) == 0
        for track in final.tracks:
            assert track.status == Track.STATUS_FINAL
            assert len(track.sensor_ids) == 3
            lanes, lengths = set(track.lanes), set(track.lengths)
            assert len(lanes) == 1 and len(lengths) == 1, 'a track mixes the two vehicles'
            (lane,) = lanes
            assert lengths == {VEHICLES[lane][0]}
            assert [conv.time_to_ns(t) for t in track.stamps] == [stamp(s, lane) for s in range(3)]
        assert {t.lanes[0] for t in final.tracks} == {0, 1}
        assert spin_until(ex, lambda: diag.get('rejected.length_out_of_range') == '1', 10.0), diag
        assert diag['rejected.lane_out_of_range'] == '1'
        assert diag['rejected.duplicate'] == '0' and diag['accepted'] == '6'
        assert not math.isnan(float(diag['received']))
    finally:
        ex.shutdown()
        test.destroy_node()
        node.destroy_node()
