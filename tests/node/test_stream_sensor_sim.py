"""sensor_sim in continuous mode, in process (private context): an open road, no episodes.

The published detections and ground truth are exactly the core's ``simulate_stream`` for the
same settings (stamps as whole nanoseconds), never negative, in stamp order on every topic,
and no EpisodeInfo exists: not a message, not even a /road/episode publisher.
"""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from mlkm_core.simulator import SimConfig
from mlkm_core.simulator_stream import simulate_stream, stream_layout
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from mlkm_ros.params import ParameterError
from road_sensor_msgs.msg import Detection, EpisodeInfo, GroundTruth
from road_sensors.sensor_sim import SensorSimNode

pytestmark = pytest.mark.ros

SENSORS, DURATION, SEED = 5, 300.0, 3
CONFIG = SimConfig(n_sensors=SENSORS, miss_probability=0.05, false_alarm_rate=0.05)


def test_continuous_publishes_the_core_stream_without_episodes(rclpy_context, spin_until):
    expected = list(simulate_stream(CONFIG, SEED, duration=DURATION))
    layout = stream_layout(CONFIG, SEED)
    assert len(expected) > 50 and any(d.target < 0 for d in expected)  # clutter is in it
    listener = Node('continuous_listener', context=rclpy_context)
    detections: dict[int, list[tuple[int, float]]] = {int(s): [] for s in layout.sensor_ids}
    truth: list[GroundTruth] = []
    episodes: list[EpisodeInfo] = []
    for name in layout.names:
        listener.create_subscription(
            Detection,
            qos.detections_topic(name),
            lambda m: detections[m.sensor_id].append(
                (conv.time_to_ns(m.header.stamp), m.velocity)
            ),
            qos.DETECTIONS_QOS,
        )
    listener.create_subscription(
        GroundTruth, qos.GROUND_TRUTH_TOPIC, truth.append, qos.GROUND_TRUTH_QOS
    )
    listener.create_subscription(EpisodeInfo, qos.EPISODE_TOPIC, episodes.append, qos.EPISODE_QOS)
    sim = SensorSimNode(
        context=rclpy_context,
        parameter_overrides=[
            Parameter('mode', value='continuous'),
            Parameter('duration', value=DURATION),
            Parameter('seed', value=SEED),
            Parameter('n_sensors', value=SENSORS),
            Parameter('miss_probability', value=0.05),
            Parameter('false_alarm_rate', value=0.05),
            Parameter('wait_for_truth_subscribers', value=1),
            Parameter('keep_running', value=True),  # it shares the listener's context
        ],
    )
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(listener)
    try:
        n = len(expected)
        got = lambda: sum(len(v) for v in detections.values())  # noqa: E731
        assert spin_until(executor, lambda: len(truth) >= n and got() >= n, 120.0), (
            len(truth),
            got(),
            n,
        )
        assert spin_until(executor, sim._done.is_set, 30.0)
        assert sim.error is None
        assert listener.count_publishers(qos.EPISODE_TOPIC) == 0
        spin_until(executor, lambda: False, 0.5)  # anything late would show up now
    finally:
        sim.stop()
        sim.destroy_node()
        executor.shutdown()
        listener.destroy_node()
    assert episodes == []
    assert len(truth) == n and got() == n
    ids = layout.sensor_ids
    want = sorted(
        (int(ids[d.sensor_index]), conv.seconds_to_ns(d.stamp), d.target) for d in expected
    )
    have = sorted(
        (t.sensor_id, conv.time_to_ns(t.header.stamp), conv.ground_truth_target(t)) for t in truth
    )
    assert have == want
    assert {t.episode_id for t in truth} == {0}
    truth_ns = [conv.time_to_ns(t.header.stamp) for t in truth]  # one topic: arrival order
    assert truth_ns[0] >= 0 and truth_ns == sorted(truth_ns)
    for sensor, rows in detections.items():
        stamps = [ns for ns, _ in rows]
        assert stamps == sorted(stamps), sensor
        want_s = sorted(
            (conv.seconds_to_ns(d.stamp), d.velocity)
            for d in expected
            if ids[d.sensor_index] == sensor
        )
        assert rows == want_s
    assert max(truth_ns) <= DURATION * conv.NS_PER_S
    assert np.all(np.diff(truth_ns) >= 0)


def test_continuous_refuses_per_episode_clutter(rclpy_context) -> None:
    with pytest.raises(ParameterError, match='false_alarms_per_sensor'):
        SensorSimNode(
            context=rclpy_context,
            parameter_overrides=[
                Parameter('mode', value='continuous'),
                Parameter('false_alarms_per_sensor', value=1.0),
            ],
        )
