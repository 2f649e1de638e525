"""Bags recorded with an older definition of a message type still replay.

The old ``Detection`` below is the definition before lanes and vehicle lengths were added;
its CDR bytes do not deserialize as the installed type, so without conversion a subscriber
would drop every recorded detection.
"""

from __future__ import annotations

import math

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from road_sensor_msgs.msg import Detection
from rosbag_mcap.definitions import SEPARATOR, DefinitionCache
from rosbag_mcap.migrate import Migration, needs_migration
from rosbag_mcap.storage import BagWriter

TYPE = 'road_sensor_msgs/msg/Detection'
OLD_DETECTION = """# One passage of one target at one road-side sensor (older layout).
std_msgs/Header header
uint32 sensor_id
float64 position
float64 velocity
"""
KEEP_ALL = QoSProfile(
    history=HistoryPolicy.KEEP_ALL, depth=0, reliability=ReliabilityPolicy.RELIABLE
)


def old_full_text() -> str:
    """The old Detection with the installed Header and Time sections, as a bag stores it."""
    installed = DefinitionCache().full_text(TYPE)
    return OLD_DETECTION + installed[installed.index(f'\n{SEPARATOR}\n') :]


def old_store():
    store = get_typestore(Stores.EMPTY)
    types = {}
    for section in old_full_text().split(f'\n{SEPARATOR}\n')[1:]:
        header, _, text = section.partition('\n')
        types.update(get_types_from_msg(text, header[5:]))
    types.update(get_types_from_msg(OLD_DETECTION, TYPE))
    store.register(types)
    return store


def old_detection_bytes(store, i: int) -> bytes:
    t = store.types
    stamp = t['builtin_interfaces/msg/Time'](sec=100 + i, nanosec=5)
    header = t['std_msgs/msg/Header'](stamp=stamp, frame_id='road')
    msg = t[TYPE](header=header, sensor_id=3, position=125.0, velocity=20.0 + i)
    return bytes(store.serialize_cdr(msg, TYPE))


def test_field_layout_decides_comments_do_not():
    installed = DefinitionCache().full_text(TYPE)
    assert needs_migration(old_full_text(), installed, TYPE)
    commented = installed.replace('# Identifier of the sensor', '# The id of the sensor')
    assert commented != installed
    assert not needs_migration(commented, installed, TYPE)
    assert not needs_migration('', installed, TYPE)  # nothing recorded: play as is


def test_old_detection_converts_with_installed_defaults():
    data = old_detection_bytes(old_store(), 2)
    with pytest.raises(Exception):  # noqa: B017 (the raw bytes are not an installed Detection)
        deserialize_message(data, Detection)
    msg = deserialize_message(Migration(old_full_text(), TYPE, Detection)(data), Detection)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (
        102,
        5,
        'road',
    )
    assert (msg.sensor_id, msg.position, msg.velocity) == (3, 125.0, 22.0)
    assert msg.lane == Detection.LANE_UNKNOWN
    assert msg.length == 0.0 or math.isnan(msg.length)  # unknown


@pytest.mark.ros
def test_player_converts_a_bag_recorded_with_the_old_definition(
    ros_process, rclpy_context, spin_until, tmp_path
):
    store = old_store()
    bag = tmp_path / 'old_bag'
    with BagWriter(bag) as writer:
        writer.add_topic('/old/detections', TYPE, old_full_text(), [])
        for i in range(5):
            writer.write('/old/detections', old_detection_bytes(store, i), log_time=10**9 + i)
    node = Node('old_bag_listener', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    got: list[Detection] = []
    node.create_subscription(Detection, '/old/detections', got.append, KEEP_ALL)
    player = ros_process(
        'rosbag_mcap', 'bag_player', '--ros-args', '-p', f'bag:={bag}', '-p', 'rate:=0.0',
        '-p', 'wait_for_subscribers:=1',
    )  # fmt: skip
    assert spin_until(executor, lambda: len(got) >= 5, 30.0), player.output()
    assert [m.velocity for m in got] == [20.0, 21.0, 22.0, 23.0, 24.0]
    assert all(m.lane == -1 and m.sensor_id == 3 for m in got)
    assert 'recorded with another definition' in player.output()
    assert player.proc.wait(30) == 0, player.output()


@pytest.mark.ros
def test_player_plays_the_sample_bag_layout_as_a_single_road(
    ros_process, rclpy_context, spin_until, repo_root
):
    """bags/sample holds a SensorLayout from before road networks: the player converts it,
    the nodes' reading of it is unchanged, and it reads as the one-link network of its road."""
    from mlkm_ros import conversions as conv
    from mlkm_ros import qos
    from mlkm_ros.network_conversions import is_network_msg, msg_to_network
    from road_sensor_msgs.msg import SensorLayout

    node = Node('sample_layout_listener', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    got: list[SensorLayout] = []
    node.create_subscription(SensorLayout, qos.LAYOUT_TOPIC, got.append, qos.LAYOUT_QOS)
    player = ros_process(
        'rosbag_mcap', 'bag_player', '--ros-args', '-p', f'bag:={repo_root / "bags" / "sample"}',
        '-p', 'include_regex:=^/road/sensor_layout$', '-p', 'rate:=0.0', '-p', 'linger:=-1.0',
    )  # fmt: skip
    assert spin_until(executor, lambda: len(got) >= 1, 60.0), player.output()
    assert 'sensor_layout was recorded with another definition' in player.output()
    layout = conv.layout_from_msg(got[0])
    assert layout.n_sensors == 20 and not is_network_msg(got[0])
    net = msg_to_network(got[0])
    assert net.is_single_road() and len(net.links) == 1
    assert net.station_offsets.tolist() == layout.positions.tolist()
