"""ROS-free tests of the bag format: write with BagWriter, decode with rosbags and mcap-ros2.

Payloads are serialized with the rosbags typestore, so no DDS and no rclpy are involved.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from rosbag_mcap.definitions import (
    SEPARATOR,
    DefinitionCache,
    dependency_names,
    msg_dependencies,
    read_msg_file,
)
from rosbag_mcap.reader import BagReader
from rosbag_mcap.storage import (
    INFINITE_NS,
    BagError,
    BagWriter,
    QosSpec,
    parse_qos,
    qos_to_yaml,
    replay_qos,
)

REPO = Path(__file__).resolve().parents[3]
ROAD_MSGS = REPO / 'ros2_ws' / 'src' / 'road_sensor_msgs' / 'msg'

LATCHED = QosSpec(
    history='unknown',
    depth=0,
    reliability='reliable',
    durability='transient_local',
    deadline=INFINITE_NS,
    lifespan=INFINITE_NS,
    liveliness='automatic',
    liveliness_lease_duration=INFINITE_NS,
)
VOLATILE = QosSpec(
    history='unknown',
    depth=0,
    reliability='reliable',
    durability='volatile',
    deadline=INFINITE_NS,
    lifespan=INFINITE_NS,
    liveliness='automatic',
    liveliness_lease_duration=INFINITE_NS,
)


def lookup(package: str, namespace: str, name: str) -> str:
    """Installed .msg files, and road_sensor_msgs straight from the source tree."""
    if package == 'road_sensor_msgs':
        return (ROAD_MSGS / f'{name}.msg').read_text(encoding='utf-8')
    return read_msg_file(package, namespace, name)


@pytest.fixture(scope='module')
def typestore():
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for msg in sorted(ROAD_MSGS.glob('*.msg')):
        types.update(
            get_types_from_msg(msg.read_text(encoding='utf-8'), f'road_sensor_msgs/msg/{msg.stem}')
        )
    store.register(types)
    return store


def make_messages(store):
    """(topic, type, qos, message object) in publication order, with known field values."""
    string_t = store.types['std_msgs/msg/String']
    header_t = store.types['std_msgs/msg/Header']
    time_t = store.types['builtin_interfaces/msg/Time']
    array_t = store.types['diagnostic_msgs/msg/DiagnosticArray']
    status_t = store.types['diagnostic_msgs/msg/DiagnosticStatus']
    kv_t = store.types['diagnostic_msgs/msg/KeyValue']
    det_t = store.types['road_sensor_msgs/msg/Detection']
    layout_t = store.types['road_sensor_msgs/msg/SensorLayout']
    import numpy as np

    def header(sec, frame='road'):
        return header_t(stamp=time_t(sec=sec, nanosec=500), frame_id=frame)

    out = [
        (
            '/road/sensor_layout',
            'road_sensor_msgs/msg/SensorLayout',
            LATCHED,
            layout_t(
                header=header(1),
                road_length=1000.0,
                sensor_ids=np.array([3, 7], dtype=np.uint32),
                sensor_names=['s3', 's7'],
                positions=np.array([10.0, 510.0]),
                lane_counts=np.array([2, 3], dtype=np.uint16),
                entry_positions=np.array([300.0]),
                exit_positions=np.array([], dtype=np.float64),
                # a single road: the road network's arrays are empty
                link_ids=np.array([], dtype=np.uint32),
                link_names=[],
                link_lengths=np.array([], dtype=np.float64),
                link_lanes=np.array([], dtype=np.uint16),
                connection_from=np.array([], dtype=np.uint32),
                connection_to=np.array([], dtype=np.uint32),
                sensor_links=np.array([], dtype=np.uint32),
                entry_links=np.array([], dtype=np.uint32),
                exit_links=np.array([], dtype=np.uint32),
                link_shape_sizes=np.array([], dtype=np.uint32),
                link_shape_x=np.array([], dtype=np.float64),
                link_shape_y=np.array([], dtype=np.float64),
            ),
        )
    ]
    for i in range(3):
        out.append(('/chatter', 'std_msgs/msg/String', VOLATILE, string_t(data=f'hello {i}')))
        out.append(
            (
                '/road/sensors/s3/detections',
                'road_sensor_msgs/msg/Detection',
                VOLATILE,
                det_t(
                    header=header(100 + i),
                    sensor_id=3,
                    position=10.0,
                    velocity=20.0 + i,
                    lane=i - 1,
                    length=4.5 + i,
                ),
            )
        )
    out.append(
        (
            '/diagnostics',
            'diagnostic_msgs/msg/DiagnosticArray',
            VOLATILE,
            array_t(
                header=header(5, ''),
                status=[
                    status_t(
                        level=b'\x01'[0],
                        name='assoc',
                        message='rejected',
                        hardware_id='',
                        values=[
                            kv_t(key='nan_velocity', value='2'),
                            kv_t(key='unknown_sensor', value='1'),
                        ],
                    )
                ],
            ),
        )
    )
    return out


def write_bag(path: Path, store, chunk_size: int = 768 * 1024) -> list:
    messages = make_messages(store)
    defs = DefinitionCache(lookup)
    with BagWriter(path, chunk_size=chunk_size) as writer:
        for i, (topic, type_name, qos, msg) in enumerate(messages):
            if not writer.has_topic(topic):
                writer.add_topic(
                    topic,
                    type_name,
                    defs.full_text(type_name),
                    [qos],
                    type_hash=store.hash_rihs01(type_name),
                )
            data = bytes(store.serialize_cdr(msg, type_name))
            writer.write(
                topic, data, log_time=1_000_000_000 + i * 1000, publish_time=999_000_000 + i * 1000
            )
    return messages


def test_definition_assembly_matches_rosbag2_layout():
    text = DefinitionCache().full_text('diagnostic_msgs/msg/DiagnosticArray')
    assert text.startswith(read_msg_file('diagnostic_msgs', 'msg', 'DiagnosticArray'))
    # Depth first, each dependency once, dependencies of one file in sorted order.
    assert list(dependency_names(text)) == [
        'diagnostic_msgs/DiagnosticStatus',
        'diagnostic_msgs/KeyValue',
        'std_msgs/Header',
        'builtin_interfaces/Time',
    ]
    assert f'\n{SEPARATOR}\nMSG: std_msgs/Header\n' in text
    assert msg_dependencies('int32 a\nstring[] b\nFoo[<=3] c  # x\npkg/Bar d\n', 'me') == [
        'me/Foo',
        'pkg/Bar',
    ]


def test_qos_yaml_round_trip_and_legacy_integers():
    text = qos_to_yaml([LATCHED, VOLATILE])
    assert text.startswith('- history: unknown\n  depth: 0\n  reliability: reliable\n')
    assert '  deadline:\n    sec: 9223372036\n    nsec: 854775807\n' in text
    assert parse_qos(text) == [LATCHED, VOLATILE]
    legacy = (
        '- history: 3\n  depth: 0\n  reliability: 1\n  durability: 1\n  deadline:\n'
        '    sec: 2147483647\n    nsec: 4294967295\n  lifespan:\n    sec: 0\n'
        '    nsec: 0\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n'
        '    nsec: 0\n  avoid_ros_namespace_conventions: false'
    )
    (parsed,) = parse_qos(legacy)
    assert (parsed.history, parsed.reliability, parsed.durability, parsed.liveliness) == (
        'unknown',
        'reliable',
        'transient_local',
        'automatic',
    )
    assert parsed.deadline == INFINITE_NS and parsed.lifespan == 0
    replay = replay_qos([LATCHED, LATCHED], message_count=3)
    assert (replay.durability, replay.reliability, replay.history, replay.depth) == (
        'transient_local',
        'reliable',
        'keep_last',
        3,
    )
    known = QosSpec(history='keep_last', depth=5, durability='transient_local')
    assert replay_qos([known], message_count=2).depth == 5
    assert replay_qos([LATCHED], message_count=10**6).depth == 1000
    mixed = replay_qos([LATCHED, VOLATILE])
    assert (mixed.durability, mixed.history) == ('volatile', 'keep_all')


def test_written_bag_decodes_with_rosbags(tmp_path, typestore):
    bag = tmp_path / 'bag'
    expected = write_bag(bag, typestore)
    got = []
    with AnyReader([bag]) as reader:  # types come from the bag's own schemas
        assert {c.topic: c.msgtype for c in reader.connections} == {
            t: ty for t, ty, _, _ in expected
        }
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
        assert qos['/road/sensor_layout'][0].durability.name == 'TRANSIENT_LOCAL'
        assert qos['/chatter'][0].durability.name == 'VOLATILE'
        for connection, timestamp, raw in reader.messages():
            got.append((connection.topic, timestamp, reader.deserialize(raw, connection.msgtype)))
    assert [g[0] for g in got] == [e[0] for e in expected]
    assert [g[1] for g in got] == [1_000_000_000 + i * 1000 for i in range(len(expected))]
    layout = got[0][2]
    assert layout.road_length == 1000.0 and list(layout.sensor_ids) == [3, 7]
    assert list(layout.sensor_names) == ['s3', 's7'] and list(layout.positions) == [10.0, 510.0]
    assert [g[2].data for g in got if g[0] == '/chatter'] == ['hello 0', 'hello 1', 'hello 2']
    dets = [g[2] for g in got if g[0] == '/road/sensors/s3/detections']
    assert [(d.header.stamp.sec, d.sensor_id, d.velocity) for d in dets] == [
        (100, 3, 20.0),
        (101, 3, 21.0),
        (102, 3, 22.0),
    ]
    diag = got[-1][2]
    assert diag.status[0].name == 'assoc' and diag.status[0].level == 1
    assert [(v.key, v.value) for v in diag.status[0].values] == [
        ('nan_velocity', '2'),
        ('unknown_sensor', '1'),
    ]


def test_written_bag_decodes_with_mcap_ros2(tmp_path, typestore):
    bag = tmp_path / 'bag'
    expected = write_bag(bag, typestore)
    mcap_file = bag / 'bag_0.mcap'
    with open(mcap_file, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == 'ros2'
        summary = reader.get_summary()
        assert summary.statistics.message_count == len(expected)
        assert summary.chunk_indexes and all(
            c.compression == 'zstd' for c in summary.chunk_indexes
        )
        schemas = {s.name: s for s in summary.schemas.values()}
        assert all(s.encoding == 'ros2msg' for s in schemas.values())
        layout_text = schemas['road_sensor_msgs/msg/SensorLayout'].data.decode()
        assert 'MSG: std_msgs/Header' in layout_text
        assert 'MSG: builtin_interfaces/Time' in layout_text
        for channel in summary.channels.values():
            assert channel.message_encoding == 'cdr'
            assert channel.metadata['topic_type_hash'] == typestore.hash_rihs01(
                summary.schemas[channel.schema_id].name
            )
            assert parse_qos(channel.metadata['offered_qos_profiles'])
        (record,) = reader.iter_metadata()
        assert record.name == 'rosbag2'
        embedded = yaml.safe_load(record.metadata['serialized_metadata'])
        assert embedded['version'] == 9 and embedded['message_count'] == len(expected)
    with open(mcap_file, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        decoded = [
            (c.topic, m.publish_time, msg)
            for _, c, m, msg in reader.iter_decoded_messages(log_time_order=True)
        ]
    assert [d[0] for d in decoded] == [e[0] for e in expected]
    assert [d[2].data for d in decoded if d[0] == '/chatter'] == ['hello 0', 'hello 1', 'hello 2']
    dets = [d[2] for d in decoded if d[0] == '/road/sensors/s3/detections']
    assert [(d.header.stamp.sec, d.header.stamp.nanosec, d.velocity) for d in dets] == [
        (100, 500, 20.0),
        (101, 500, 21.0),
        (102, 500, 22.0),
    ]
    diag = decoded[-1][2]
    assert [(v.key, v.value) for v in diag.status[0].values] == [
        ('nan_velocity', '2'),
        ('unknown_sensor', '1'),
    ]
    assert decoded[0][1] == 999_000_000


def test_metadata_yaml_is_rosbag2_v9(tmp_path, typestore):
    bag = tmp_path / 'bag'
    expected = write_bag(bag, typestore)
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert list(info) == [
        'version',
        'storage_identifier',
        'duration',
        'starting_time',
        'message_count',
        'topics_with_message_count',
        'compression_format',
        'compression_mode',
        'relative_file_paths',
        'files',
        'custom_data',
        'ros_distro',
    ]
    assert (info['version'], info['storage_identifier'], info['ros_distro']) == (
        9,
        'mcap',
        'jazzy',
    )
    assert info['message_count'] == len(expected)
    assert info['starting_time'] == {'nanoseconds_since_epoch': 1_000_000_000}
    assert info['duration'] == {'nanoseconds': (len(expected) - 1) * 1000}
    assert info['relative_file_paths'] == ['bag_0.mcap']
    assert info['files'][0]['message_count'] == len(expected)
    counts = {
        t['topic_metadata']['name']: t['message_count'] for t in info['topics_with_message_count']
    }
    assert counts == {
        '/road/sensor_layout': 1,
        '/chatter': 3,
        '/road/sensors/s3/detections': 3,
        '/diagnostics': 1,
    }
    meta = info['topics_with_message_count'][0]['topic_metadata']
    assert list(meta) == [
        'name',
        'type',
        'serialization_format',
        'offered_qos_profiles',
        'type_description_hash',
    ]
    assert isinstance(meta['offered_qos_profiles'], str)
    assert parse_qos(meta['offered_qos_profiles']) == [LATCHED]


def test_reader_reads_dir_and_lone_file(tmp_path, typestore):
    bag = tmp_path / 'bag'
    expected = write_bag(bag, typestore)
    for source in (bag, bag / 'bag_0.mcap'):
        reader = BagReader(source)
        assert reader.complete and not reader.problems
        got = list(reader.messages())
        assert [m.topic for m in got] == [e[0] for e in expected]
        assert got[1].data == bytes(typestore.serialize_cdr(expected[1][3], expected[1][1]))
        assert reader.topics['/road/sensor_layout'].offered_qos == [LATCHED]
        assert reader.start_time == 1_000_000_000
    only = list(BagReader(bag).messages(topics=['/chatter'], start_time=1_000_003_000))
    assert [m.log_time for m in only] == [1_000_003_000, 1_000_005_000]


def test_truncated_file_reads_complete_chunks_and_names_the_file(tmp_path, typestore):
    bag = tmp_path / 'bag'
    write_bag(bag, typestore, chunk_size=200)  # many small chunks
    whole = len(list(BagReader(bag).messages()))
    mcap_file = bag / 'bag_0.mcap'
    with open(mcap_file, 'rb') as stream:
        last_chunk = make_reader(stream).get_summary().chunk_indexes[-1]
    with open(mcap_file, 'r+b') as stream:  # cut in the middle of the last chunk
        stream.truncate(last_chunk.chunk_start_offset + last_chunk.chunk_length // 2)
    reader = BagReader(bag)
    assert not reader.complete
    assert reader.problems and str(mcap_file) in reader.problems[0]
    assert 'truncated or corrupt' in reader.problems[0]
    got = list(reader.messages())
    assert 0 < len(got) < whole
    assert reader.expected_message_count == whole
    assert f'{len(got)} messages are readable' in reader.problems[0]


def test_unreadable_inputs_raise_bag_error_naming_the_path(tmp_path, typestore):
    with pytest.raises(BagError, match='no such bag'):
        BagReader(tmp_path / 'missing')
    junk = tmp_path / 'junk.mcap'
    junk.write_bytes(b'not an mcap file at all')
    with pytest.raises(BagError, match=str(junk)):
        BagReader(junk)
    bag = tmp_path / 'bag'
    write_bag(bag, typestore)
    shutil.copy(bag / 'bag_0.mcap', tmp_path / 'copy.mcap')
    (bag / 'bag_0.mcap').unlink()
    with pytest.raises(BagError, match='missing'):
        BagReader(bag)
    with pytest.raises(BagError, match='not an empty directory'):
        BagWriter(bag)


def test_reader_reads_a_bag_written_by_another_implementation(tmp_path, typestore):
    """A rosbag2 v9 MCAP bag written by rosbags' Writer (not ours) plays through BagReader."""
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )
    from rosbags.rosbag2 import StoragePlugin, Writer

    infinite = QosTime(9223372036, 854775807)
    latched = Qos(
        QosHistory.KEEP_LAST,
        1,
        QosReliability.RELIABLE,
        QosDurability.TRANSIENT_LOCAL,
        infinite,
        infinite,
        QosLiveliness.AUTOMATIC,
        infinite,
        False,
    )
    string_t = typestore.types['std_msgs/msg/String']
    bag = tmp_path / 'foreign'
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        chatter = writer.add_connection('/chatter', 'std_msgs/msg/String', typestore=typestore)
        layout = writer.add_connection(
            '/layout', 'std_msgs/msg/String', typestore=typestore, offered_qos_profiles=[latched]
        )
        writer.write(
            layout, 5, bytes(typestore.serialize_cdr(string_t(data='road'), 'std_msgs/msg/String'))
        )
        for i in range(3):
            writer.write(
                chatter,
                10 + i,
                bytes(typestore.serialize_cdr(string_t(data=f'hi {i}'), 'std_msgs/msg/String')),
            )
    reader = BagReader(bag)
    assert reader.complete and not reader.problems
    assert reader.topics['/layout'].offered_qos[0].durability == 'transient_local'
    assert replay_qos(reader.topics['/layout'].offered_qos, 1).durability == 'transient_local'
    got = [
        (m.topic, m.log_time, typestore.deserialize_cdr(m.data, m.type).data)
        for m in reader.messages()
    ]
    assert got == [
        ('/layout', 5, 'road'),
        ('/chatter', 10, 'hi 0'),
        ('/chatter', 11, 'hi 1'),
        ('/chatter', 12, 'hi 2'),
    ]
