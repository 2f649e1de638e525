"""Road networks through the ``SensorLayout`` message (``mlkm_ros.network_conversions``):
the network form round trip, the single road as its one-link network, a recorded single-road
layout of the sample bag, and every refusal; each through a CDR round trip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from mlkm_core.layout_file import RoadLayout
from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from mlkm_ros.network_conversions import is_network_msg, msg_to_network, network_to_msg
from road_sensor_msgs.msg import SensorLayout
from rosbag_mcap.definitions import DefinitionCache
from rosbag_mcap.migrate import Migration, needs_migration
from rosbag_mcap.reader import BagReader

SAMPLE = Path(__file__).resolve().parents[3] / 'bags' / 'sample'
LAYOUT_TYPE = 'road_sensor_msgs/msg/SensorLayout'


def cdr(msg):
    return deserialize_message(serialize_message(msg), type(msg))


def interchange() -> RoadNetwork:
    return RoadNetwork(
        links=(
            RoadLink(0, 'main_in', 800.0, 3),
            RoadLink(1, 'main_out', 900.0, 3),
            RoadLink(2, 'exit_ramp', 300.0, 1),
            RoadLink(7, 'on_ramp', 250.0),
        ),  # fmt: skip
        connections=((0, 1), (0, 2), (7, 1)),
        station_ids=np.array([0, 1, 2]),
        station_names=('loop_00', 'loop_01', 'loop_02'),
        station_links=np.array([0, 1, 2]),
        station_offsets=np.array([200.0, 500.0, 150.0]),
        station_lanes=np.array([3, 0, 1]),
        entries=((1, 400.0),),
    )


def test_network_round_trip():
    net = interchange()
    msg = cdr(network_to_msg(net, 5))
    assert is_network_msg(msg)
    assert msg.road_length == 0.0
    assert list(msg.link_ids) == [0, 1, 2, 7]
    assert list(msg.link_names) == ['main_in', 'main_out', 'exit_ramp', 'on_ramp']
    assert list(msg.link_lengths) == [800.0, 900.0, 300.0, 250.0]
    assert list(msg.link_lanes) == [3, 3, 1, 0]
    assert list(zip(msg.connection_from, msg.connection_to)) == [(0, 1), (0, 2), (7, 1)]
    assert list(msg.sensor_links) == [0, 1, 2] and list(msg.lane_counts) == [3, 0, 1]
    # the explicit entry, then the implicit ones at the starts of links 0 and 7
    assert list(zip(msg.entry_links, msg.entry_positions)) == [(0, 0.0), (1, 400.0), (7, 0.0)]
    assert list(zip(msg.exit_links, msg.exit_positions)) == [(1, 900.0), (2, 300.0)]
    back = msg_to_network(msg)
    assert back == net
    assert [(s.index, s.distance_m) for s in back.successors(0)] == [(2, 750.0), (1, 1100.0)]


def test_a_network_without_known_lanes_sends_no_lane_counts():
    net = RoadNetwork((RoadLink(0, 'a', 10.0),), (), [4], ('s',), [0], [5.0])
    msg = cdr(network_to_msg(net, 0))
    assert list(msg.lane_counts) == []
    assert msg_to_network(msg).station_lanes.tolist() == [0]


def test_the_nodes_of_a_single_road_refuse_a_network_layout():
    with pytest.raises(ValueError, match='road_length must be finite and > 0, got 0.0'):
        conv.layout_from_msg(cdr(network_to_msg(interchange(), 5)))


def test_a_single_road_message_is_its_one_link_network():
    layout = Layout(
        5000.0, np.array([500.0, 1500.0, 2500.0]), np.array([7, 8, 9]), ('a', 'b', 'c')
    )
    msg = cdr(conv.layout_to_msg(layout, 5, [3, 2, 3], [1200.0], [2300.0, 4300.0]))
    assert not is_network_msg(msg)
    assert list(msg.link_ids) == list(msg.sensor_links) == list(msg.entry_links) == []
    net = msg_to_network(msg)
    road = RoadLayout(layout, np.array([3, 2, 3]), (1200.0,), (2300.0, 4300.0))
    assert net == RoadNetwork.single_road(road)
    assert net.entries == ((0, 0.0), (0, 1200.0))
    assert net.exits == ((0, 2300.0), (0, 4300.0), (0, 5000.0))
    # its road is the message's road again
    again = net.road_layout()
    assert again.layout.positions.tolist() == [500.0, 1500.0, 2500.0]
    assert (again.entries, again.exits) == ((1200.0,), (2300.0, 4300.0))


def test_the_sample_bag_layout_reads_as_a_single_road():
    """bags/sample was recorded before road networks: its layout converts to the installed
    type with empty network arrays, and reads as the one-link network of its road."""
    reader = BagReader(SAMPLE)
    recorded = reader.definition('/road/sensor_layout')
    assert needs_migration(recorded, DefinitionCache().full_text(LAYOUT_TYPE), LAYOUT_TYPE)
    (data,) = [m.data for m in reader.messages(topics=['/road/sensor_layout'])]
    msg = deserialize_message(Migration(recorded, LAYOUT_TYPE, SensorLayout)(data), SensorLayout)
    layout = conv.layout_from_msg(msg)  # what the nodes read, unchanged
    assert layout.n_sensors == 20 and not is_network_msg(msg)
    net = msg_to_network(msg)
    assert len(net.links) == 1 and net.links[0].length == layout.road_length
    assert net.station_offsets.tolist() == layout.positions.tolist()
    assert net.road_layout().layout.positions.tolist() == layout.positions.tolist()


def bad(**fields) -> SensorLayout:
    msg = network_to_msg(interchange(), 5)
    for name, value in fields.items():
        setattr(msg, name, value)
    return msg


@pytest.mark.parametrize(
    ('msg', 'words'),
    [
        (bad(road_length=4000.0), 'road_length must be 0 on a road network, got 4000.0'),
        (bad(link_names=['a']), 'parallel arrays differ in length: link_ids 4, link_names 1'),
        (bad(connection_to=[1]), 'connection_from 3, connection_to 1'),
        (bad(sensor_links=[0, 1]), 'sensor_ids 3, sensor_names 3, positions 3, sensor_links 2'),
        (bad(exit_links=[]), 'exit_links 0, exit_positions 2'),
        (bad(lane_counts=[1]), 'lane_counts has 1 entries for 3 sensors'),
        (bad(sensor_links=[0, 1, 5]), r'station 2 \(loop_02\): link 5 is not in the network'),
        (bad(positions=[200.0, 500.0, 301.0]), 'position 301 m is off link 2'),
        (bad(connection_to=[1, 2, 7]), 'connection 7 -> 7 joins a link to itself'),
        (bad(link_names=['a', 'b', 'c', 'a']), "link name 'a' is used twice"),
        (bad(entry_positions=[0.0, 950.0, 0.0]), 'entry on link 1 at 950 m: off the link'),
        (
            bad(sensor_ids=[], sensor_names=[], positions=[], sensor_links=[], lane_counts=[]),
            'a network needs at least one station',
        ),
    ],
)
def test_bad_network_messages_are_refused_with_the_reason(msg, words):
    with pytest.raises(ValueError, match=words):
        msg_to_network(cdr(msg))


def test_a_bad_single_road_message_is_refused_as_before():
    msg = conv.layout_to_msg(Layout(100.0, np.array([10.0, 20.0])), 0, [1, 0])
    with pytest.raises(ValueError, match='lane_counts must be >= 1'):
        msg_to_network(msg)


def shaped() -> RoadNetwork:
    """The interchange with its links drawn: main_in bends at (400, 0)."""
    shapes = {
        0: ((0.0, 0.0), (400.0, 0.0), (400.0, 400.0)),
        1: ((400.0, 400.0), (400.0, 1300.0)),
        2: ((400.0, 400.0), (700.0, 400.0)),
        7: ((0.0, 650.0), (400.0, 400.0)),
    }
    net = interchange()
    links = tuple(RoadLink(k.link_id, k.name, k.length, k.lanes, shapes[k.link_id])
                  for k in net.links)  # fmt: skip
    return RoadNetwork(links, net.connections, net.station_ids, net.station_names,
                       net.station_links, net.station_offsets, net.station_lanes,
                       net.entries, net.exits)  # fmt: skip


def test_link_shapes_round_trip():
    msg = cdr(network_to_msg(shaped(), 5))
    assert list(msg.link_shape_sizes) == [3, 2, 2, 2]
    assert list(msg.link_shape_x)[:3] == [0.0, 400.0, 400.0]
    assert list(msg.link_shape_y)[-2:] == [650.0, 400.0]
    back = msg_to_network(msg)
    assert back == shaped() and back != interchange()
    assert back.links[0].point_at(600.0)[:2] == (400.0, 200.0)  # 600 m of 800 along the bend
    # a network without shapes sends none
    assert list(cdr(network_to_msg(interchange(), 5)).link_shape_sizes) == []


@pytest.mark.parametrize(
    ('fields', 'words'),
    [
        ({'link_shape_sizes': [3, 2]}, 'link_shape_sizes has 2 entries for 4 links'),
        ({'link_shape_sizes': [3, 2, 2, 3]}, 'add up to 10 points, link_shape_x holds 9'),
        ({'link_shape_y': [0.0]}, 'link_shape_x 9, link_shape_y 1'),
        ({'link_shape_sizes': [3, 2, 3, 1]}, 'link 7: a shape needs at least 2 finite'),
    ],
)
def test_bad_link_shapes_are_refused_with_the_reason(fields, words):
    msg = network_to_msg(shaped(), 5)
    for name, value in fields.items():
        setattr(msg, name, value)
    with pytest.raises(ValueError, match=words):
        msg_to_network(cdr(msg))
