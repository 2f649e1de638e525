"""Every road_sensor_msgs message survives a CDR round trip through rclpy.serialization.

Each message is filled with non-default values in every field (the test checks that, so a
field added later without a value here fails), serialised, deserialised and compared field by
field, recursively.
"""

from __future__ import annotations

import array
import importlib
import math
import re
from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Header

MESSAGES = (
    'Detection',
    'SensorLayout',
    'EpisodeInfo',
    'GroundTruth',
    'Track',
    'TrackArray',
    'AssociationScore',
    'TrackHandoff',
)
U32_MAX = 2**32 - 1
MSG_DIR = Path(__file__).resolve().parents[2] / 'ros2_ws' / 'src' / 'road_sensor_msgs' / 'msg'
UNIT = re.compile(r'\[[^\]]+\]')


def msg_class(name: str):
    return getattr(importlib.import_module('road_sensor_msgs.msg'), name)


def header(sec: int = 1_700_000_123, nanosec: int = 456_789_012, frame: str = 'road') -> Header:
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame)


def track(track_id: int) -> object:
    Track = msg_class('Track')
    return Track(
        track_id=track_id,
        status=Track.STATUS_FINAL,
        sensor_ids=[3, 7, U32_MAX],
        stamps=[Time(sec=10, nanosec=1), Time(sec=12, nanosec=999_999_999), Time(sec=15)],
        velocities=[48.25, -0.5, 61.125],
        positions=[120.0, 480.5, 999.875],
        lanes=[0, 2, -1],
        lengths=[4.5, 16.25, 0.5],
    )


def filled(name: str):
    """An instance of ``name`` with a non-default value in every field."""
    cls = msg_class(name)
    if name == 'Detection':
        return cls(
            header=header(),
            sensor_id=42,
            position=1234.5,
            velocity=-13.75,
            lane=2,
            length=12.5,
        )
    if name == 'SensorLayout':
        return cls(
            header=header(frame='road_é'),
            road_length=5000.0,
            sensor_ids=[1, 5, U32_MAX],
            sensor_names=['s01', 'bridge_north', ''],
            positions=[10.0, 2500.25, 4999.5],
            lane_counts=[3, 2, 65535],
            entry_positions=[1200.0],
            exit_positions=[2300.5, 4300.0],
            link_ids=[0, U32_MAX],
            link_names=['main_in', 'ramp_é'],
            link_lengths=[800.0, 4999.5],
            link_lanes=[3, 65535],
            connection_from=[0],
            connection_to=[U32_MAX],
            sensor_links=[0, 0, U32_MAX],
            entry_links=[U32_MAX],
            exit_links=[0, U32_MAX],
            link_shape_sizes=[2, 3],
            link_shape_x=[0.0, 800.0, -1.5e6, 0.25, 3.0],
            link_shape_y=[0.0, 0.0, 4.0e6, -7.75, 3.0],
        )
    if name == 'EpisodeInfo':
        return cls(
            header=header(),
            episode_id=7,
            status=cls.STATUS_ENDED,
            num_targets=50,
            start=Time(sec=100, nanosec=5),
            end=Time(sec=2_000, nanosec=6),
            sensor_ids=[1, 2, 3],
            detection_counts=[50, 49, 52],
        )
    if name == 'GroundTruth':
        return cls(
            header=header(),
            episode_id=3,
            sensor_id=9,
            target_id=cls.FALSE_ALARM,
            false_alarm=True,
            true_velocity=55.5,
            lane=1,
            vehicle_id='v17',
        )
    if name == 'Track':
        return track(17)
    if name == 'TrackArray':
        return cls(
            header=header(),
            mode=cls.MODE_STREAM,
            episode_id=11,
            method='mlkm',
            final=True,
            segments_done=4,
            segments_total=4,
            # a stream id of a run started now (us since the Unix epoch), and the largest id
            tracks=[track(1_764_000_000_000_000 + 7), track(2**64 - 1)],
            unassigned_sensor_ids=[8, 9],
            unassigned_stamps=[Time(sec=1), Time(sec=2)],
            unassigned_velocities=[33.0, 70.5],
            unassigned_lanes=[1, -1],
            unassigned_lengths=[9.25, 7.5],
            committed_until=Time(sec=3, nanosec=7),
            solve_time=0.0125,
            run=1_764_000_000_000_000,
        )
    if name == 'AssociationScore':
        return cls(
            header=header(),
            episode_id=5,
            method='kmeans++',
            accuracy=0.9165,
            correct=917,
            total=1000,
            link_recall=0.875,
            link_precision=0.5,
            identity_switches=12,
            adjusted_rand_index=-0.25,
            mean_accuracy=0.8125,
            episodes_scored=6,
            truth_complete=True,
            truth_expected=1010,
            truth_received=1009,
            episodes_incomplete=2,
            mode=cls.MODE_STREAM,
            window_start=Time(sec=120),
            window_end=Time(sec=180, nanosec=5),
            revision_rate=0.125,
            links_published=800,
            links_revised=100,
            cumulative_revision_rate=0.0625,
        )
    if name == 'TrackHandoff':
        return cls(
            header=header(),
            shard=1,
            shard_count=4,
            run=1_764_000_000_001_024,
            offers=[track(1_764_000_000_001_025)],
            continued_ids=[1_764_000_000_000_000],
            continuing_ids=[1_764_000_000_001_025],
            committed_until=Time(sec=100, nanosec=5),
            settled_until=Time(sec=98),
            newest=Time(sec=130, nanosec=250),
        )
    raise KeyError(name)


def plain(value):
    """Messages, sequences and numpy arrays as comparable Python structures."""
    if hasattr(value, 'get_fields_and_field_types'):
        return {f: plain(getattr(value, f)) for f in value.get_fields_and_field_types()}
    if isinstance(value, (list, tuple, array.array, np.ndarray)):
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def assert_same(a, b, path: str) -> None:
    """Field-by-field equality with the failing field's path in the message."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for key in a:
            assert_same(a[key], b[key], f'{path}.{key}')
    elif isinstance(a, list):
        assert len(a) == len(b), f'{path}: length {len(a)} != {len(b)}'
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f'{path}[{i}]')
    else:
        assert type(a) is type(b) and a == b, f'{path}: {a!r} != {b!r}'


@pytest.mark.parametrize('name', MESSAGES)
def test_every_field_is_filled(name):
    cls = msg_class(name)
    default, msg = plain(cls()), plain(filled(name))
    same = [f for f in default if default[f] == msg[f]]
    assert not same, f'{name}: fields left at their default: {same}'


@pytest.mark.parametrize('name', MESSAGES)
def test_round_trip(name):
    cls = msg_class(name)
    msg = filled(name)
    data = serialize_message(msg)
    assert isinstance(data, bytes) and len(data) > 4
    back = deserialize_message(data, cls)
    assert type(back) is cls
    assert_same(plain(msg), plain(back), name)
    assert back == msg


def test_round_trip_keeps_extreme_values():
    Detection = msg_class('Detection')
    msg = Detection(
        header=header(sec=-(2**31), nanosec=999_999_999),
        sensor_id=U32_MAX,
        position=math.ulp(0.0),
        velocity=-1.7976931348623157e308,
    )
    back = deserialize_message(serialize_message(msg), Detection)
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (-(2**31), 999_999_999)
    assert back.sensor_id == U32_MAX
    assert back.position == math.ulp(0.0)
    assert back.velocity == -1.7976931348623157e308


def test_constants():
    assert msg_class('GroundTruth').FALSE_ALARM == U32_MAX
    EpisodeInfo = msg_class('EpisodeInfo')
    assert (EpisodeInfo.STATUS_STARTED, EpisodeInfo.STATUS_ENDED) == (0, 1)


def test_track_array_travels_over_loopback_dds(rclpy_context, spin_until):
    """The built messages work end to end: publish and receive one on a private domain."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy

    TrackArray = msg_class('TrackArray')
    qos = QoSProfile(
        depth=1,
        reliability=QoSReliabilityPolicy.RELIABLE,
        durability=QoSDurabilityPolicy.TRANSIENT_LOCAL,
    )
    pub_node = Node('msg_test_pub', context=rclpy_context)
    sub_node = Node('msg_test_sub', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    try:
        received = []
        pub_node.create_publisher(TrackArray, 'tracks', qos).publish(filled('TrackArray'))
        sub_node.create_subscription(TrackArray, 'tracks', received.append, qos)
        executor.add_node(pub_node)
        executor.add_node(sub_node)
        assert spin_until(executor, lambda: received, timeout=20.0), 'nothing received'
        assert_same(plain(filled('TrackArray')), plain(received[0]), 'TrackArray')
    finally:
        executor.shutdown()
        pub_node.destroy_node()
        sub_node.destroy_node()


def field_comments(text: str) -> dict[str, str]:
    """{field or constant name: its own comment}: the trailing comment on its line, or else
    the comment block right above it (no blank line and no other field in between)."""
    found: dict[str, str] = {}
    block: list[str] = []
    for raw in text.splitlines():
        line = raw.strip()
        if not line:
            block = []
        elif line.startswith('#'):
            block.append(line.lstrip('#').strip())
        else:
            code, _, trailing = line.partition('#')
            name = code.split()[1].split('=')[0]
            found[name] = trailing.strip() or ' '.join(block)
            block = []
    return found


def test_msg_files_are_the_built_ones():
    assert sorted(p.stem for p in MSG_DIR.glob('*.msg')) == sorted(MESSAGES)


@pytest.mark.parametrize('name', MESSAGES)
def test_every_field_has_its_own_comment_with_a_unit(name):
    comments = field_comments((MSG_DIR / f'{name}.msg').read_text())
    fields = msg_class(name).get_fields_and_field_types()
    assert set(fields) <= set(comments), (
        f'{name}: fields not parsed: {set(fields) - set(comments)}'
    )
    missing = [f for f, c in comments.items() if not UNIT.search(c)]
    assert not missing, f'{name}: fields without their own comment with a [unit]: {missing}'


@pytest.mark.parametrize('name', MESSAGES)
def test_parallel_array_counts_are_right(name):
    """A comment that says 'the N arrays are parallel' counts the message's array fields."""
    words = {'two': 2, 'three': 3, 'four': 4, 'five': 5, 'six': 6}
    text = ' '.join((MSG_DIR / f'{name}.msg').read_text().lower().replace('#', ' ').split())
    fields = msg_class(name).get_fields_and_field_types()
    claims = re.findall(r'the (\w+) (?:(\w+)\* )?(?:per-detection )?arrays are parallel', text)
    assert claims or name not in ('Track', 'TrackArray')
    for word, prefix in claims:
        arrays = [
            f for f, t in fields.items() if t.startswith('sequence<') and f.startswith(prefix)
        ]
        assert words[word] == len(arrays), f'{name}: says {word} arrays, has {arrays}'
