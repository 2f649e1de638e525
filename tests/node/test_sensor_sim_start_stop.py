"""sensor_sim as a ROS 2 user meets it: stamps rclpy accepts, a quiet Ctrl-C.

In-process tests: the node and a listener share a private context (fixture rclpy_context).
"""

from __future__ import annotations

import time

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.time import Time

from mlkm_core.simulator import SimConfig, simulate_episodes, time_window
from mlkm_ros import qos
from road_sensor_msgs.msg import Detection, EpisodeInfo, GroundTruth
from road_sensors.sensor_sim import SensorSimNode

pytestmark = pytest.mark.ros


def test_the_default_scenario_starts_before_zero_in_the_core() -> None:
    # What makes the test below meaningful: the core's first passage is at a negative time.
    first = simulate_episodes(SimConfig(), 0, 2, 10.0)[0]
    assert time_window(first)[0] < -1.0


def test_every_published_stamp_is_a_valid_ros_time(rclpy_context, spin_until) -> None:
    episodes = 2
    expected = sum(len(d.detections) for d in simulate_episodes(SimConfig(), 0, episodes, 10.0))
    listener = Node('stamp_listener', context=rclpy_context)
    stamps: dict[str, list] = {'detection': [], 'truth': [], 'episode': []}
    for name in simulate_episodes(SimConfig(), 0, 1, 10.0)[0].layout.names:
        listener.create_subscription(
            Detection,
            qos.detections_topic(name),
            lambda m: stamps['detection'].append(m.header.stamp),
            qos.DETECTIONS_QOS,
        )
    listener.create_subscription(
        GroundTruth,
        qos.GROUND_TRUTH_TOPIC,
        lambda m: stamps['truth'].append(m.header.stamp),
        qos.GROUND_TRUTH_QOS,
    )
    windows: list[tuple] = []
    listener.create_subscription(
        EpisodeInfo,
        qos.EPISODE_TOPIC,
        lambda m: windows.append((m.start, m.end, m.header.stamp)),
        qos.EPISODE_QOS,
    )
    sim = SensorSimNode(
        context=rclpy_context,
        parameter_overrides=[
            Parameter('episodes', value=episodes),
            Parameter('wait_for_truth_subscribers', value=1),
            Parameter('keep_running', value=True),  # it shares the listener's context
        ],
    )
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(listener)
    try:
        done = spin_until(
            executor,
            lambda: len(stamps['truth']) >= expected and len(stamps['detection']) >= expected,
            120.0,
        )
        assert done, {k: len(v) for k, v in stamps.items()}
        assert spin_until(executor, lambda: len(windows) >= 2 * episodes, 30.0)
        assert sim.error is None
    finally:
        sim.stop()
        sim.destroy_node()
    every = stamps['detection'] + stamps['truth'] + [s for w in windows for s in w]
    assert min(s.sec for s in every) >= 0
    for stamp in every:
        Time.from_msg(stamp)  # refuses negative times
    # The stream starts within a second of t = 0 (a whole-second shift of the core's times).
    assert min(s.sec for s in stamps['detection']) == 0


def test_ctrl_c_while_waiting_for_subscribers_is_no_error(rclpy_context) -> None:
    import rclpy

    sim = SensorSimNode(
        context=rclpy_context,
        parameter_overrides=[
            Parameter('n_targets', value=2),
            Parameter('episodes', value=1),
            Parameter('wait_for_subscribers', value=5),
            Parameter('wait_timeout', value=0.0),
        ],
    )
    time.sleep(0.5)  # the thread is in its subscriber wait
    rclpy.try_shutdown(context=rclpy_context)  # what the SIGINT handler does
    time.sleep(0.5)  # the thread polls the (now invalid) publishers at least once
    sim.stop()
    assert sim.error is None
