"""bag_player with ``wait_timeout:=0`` waits for its subscribers however long they take to
come (a node warming up on a busy machine) and never plays to nobody: ``make replay`` runs it
so."""

from __future__ import annotations

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from mlkm_ros import qos
from road_sensor_msgs.msg import GroundTruth
from rosbag_mcap.reader import BagReader

pytestmark = pytest.mark.ros


def test_player_without_a_wait_limit_plays_to_a_late_subscriber(
    ros_process, rclpy_context, spin_until, repo_root
) -> None:
    bag = repo_root / 'bags' / 'sample'
    want = BagReader(bag).topics['/road/ground_truth'].message_count
    player = ros_process(
        'rosbag_mcap', 'bag_player', '--ros-args', '-p', f'bag:={bag}',
        '-p', 'include_regex:=^/road/ground_truth$', '-p', 'rate:=0.0',
        '-p', 'wait_for_subscribers:=1', '-p', 'wait_timeout:=0.0',
    )  # fmt: skip
    # the subscriber comes only once the player waits for it, however long that took
    assert player.wait_for_output('waiting for 1 subscriber(s)', 120.0), player.output()
    assert player.poll() is None and 'playing' not in player.output(), player.output()
    node = Node('late_subscriber', context=rclpy_context)
    truth: list[GroundTruth] = []
    node.create_subscription(
        GroundTruth, qos.GROUND_TRUTH_TOPIC, truth.append, qos.GROUND_TRUTH_QOS
    )
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    assert spin_until(executor, lambda: len(truth) >= want, 120.0), (len(truth), player.output())
    assert spin_until(executor, lambda: player.poll() is not None, 60.0), player.output()
    assert player.poll() == 0, player.output()
    assert len(truth) == want
