"""Multi-process tests of the installed bag_recorder and bag_player over loopback DDS.

Each test has its own ROS_DOMAIN_ID; every process is stopped at teardown (tests/conftest.py).
"""

from __future__ import annotations

import shutil
import signal
import subprocess
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosbags.highlevel import AnyReader
from std_msgs.msg import String

from mlkm_ros.publishing import ReliablePublisher
from road_sensor_msgs.msg import Detection
from rosbag_mcap.reader import BagReader
from rosbag_mcap.storage import BagWriter

pytestmark = pytest.mark.ros

N = 40  # messages per volatile topic
KEEP_ALL = QoSProfile(
    history=HistoryPolicy.KEEP_ALL, depth=0, reliability=ReliabilityPolicy.RELIABLE
)
LATCHED = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)


def make_detection(i: int) -> Detection:
    msg = Detection(sensor_id=7, position=125.5, velocity=20.0 + 0.25 * i)
    msg.header.stamp.sec = 1000 + i
    msg.header.stamp.nanosec = 17
    msg.header.frame_id = 'road'
    return msg


def make_diagnostics(i: int) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.frame_id = f'diag{i}'
    msg.status = [
        DiagnosticStatus(
            level=DiagnosticStatus.WARN,
            name='assoc',
            message=f'rejected {i}',
            values=[KeyValue(key='nan_velocity', value=str(i))],
        )
    ]
    return msg


TOPICS = {
    '/bagtest/chatter': (String, lambda i: String(data=f'hello {i}')),
    '/bagtest/detections': (Detection, make_detection),
    '/bagtest/diagnostics': (DiagnosticArray, make_diagnostics),
}
LATCHED_TOPIC = '/bagtest/latched'
LATCHED_MSG = String(data='published before the recorder started')


def assert_clean_output(text: str) -> None:
    assert 'Traceback' not in text, text


def test_record_decode_and_replay_round_trip(ros_process, rclpy_context, spin_until, tmp_path):
    node = Node('bagtest_source', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    latched_pub = node.create_publisher(String, LATCHED_TOPIC, LATCHED)
    latched_pub.publish(LATCHED_MSG)  # before the recorder exists
    pubs = {topic: node.create_publisher(t, topic, KEEP_ALL) for topic, (t, _) in TOPICS.items()}

    bag = tmp_path / 'roundtrip'
    recorder = ros_process(
        'rosbag_mcap',
        'bag_recorder',
        '--ros-args',
        '-p',
        f'output:={bag}',
        '-p',
        'include_regex:=^/bagtest/',
        '-p',
        'discovery_period:=0.2',
    )
    assert spin_until(
        executor,
        lambda: all(p.get_subscription_count() >= 1 for p in [latched_pub, *pubs.values()]),
        20.0,
    ), recorder.output()
    sent = {topic: [] for topic in TOPICS}
    for i in range(N):
        for topic, (_, make) in TOPICS.items():
            msg = make(i)
            pubs[topic].publish(msg)
            sent[topic].append(msg)
    for pub in pubs.values():
        assert pub.wait_for_all_acked()
    assert recorder.wait_for_output('recording /bagtest/latched', 5.0)
    assert recorder.stop() == 0
    out = recorder.output()
    assert_clean_output(out)
    assert f'bag written: {bag}' in out and f'{LATCHED_TOPIC}: 1' in out
    sent[LATCHED_TOPIC] = [LATCHED_MSG]
    types = {LATCHED_TOPIC: String, **{topic: t for topic, (t, _) in TOPICS.items()}}

    def same_messages(raw_by_topic: dict) -> bool:
        """The raw CDR payloads decode (with rclpy) to exactly the messages sent, in order."""
        return {
            t: [deserialize_message(r, types[t]) for r in raws] for t, raws in raw_by_topic.items()
        } == sent

    # Independent decode 1: rosbags on the bag directory (checks type hashes too).
    with AnyReader([bag]) as reader:
        by_topic = {}
        for connection, _, raw in reader.messages():
            by_topic.setdefault(connection.topic, []).append(
                (bytes(raw), reader.deserialize(raw, connection.msgtype))
            )
        qos = {c.topic: c.ext.offered_qos_profiles[0] for c in reader.connections}
    recorded = {t: [r for r, _ in v] for t, v in by_topic.items()}
    assert same_messages(recorded)
    assert [m.data for _, m in by_topic['/bagtest/chatter']] == [f'hello {i}' for i in range(N)]
    assert [(m.header.stamp.sec, m.velocity) for _, m in by_topic['/bagtest/detections']] == [
        (1000 + i, 20.0 + 0.25 * i) for i in range(N)
    ]
    assert by_topic['/bagtest/diagnostics'][3][1].status[0].values[0].value == '3'
    assert by_topic[LATCHED_TOPIC][0][1].data == LATCHED_MSG.data
    assert qos[LATCHED_TOPIC].durability.name == 'TRANSIENT_LOCAL'

    # Independent decode 2: mcap-ros2-support's decoder on the .mcap file.
    with open(bag / 'roundtrip_0.mcap', 'rb') as stream:
        decoded = {}
        mcap = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, ros_msg in mcap.iter_decoded_messages():
            decoded.setdefault(channel.topic, []).append((message.data, ros_msg))
    assert {t: [r for r, _ in v] for t, v in decoded.items()} == recorded
    assert [m.velocity for _, m in decoded['/bagtest/detections']] == [
        20.0 + 0.25 * i for i in range(N)
    ]
    assert decoded['/bagtest/diagnostics'][-1][1].status[0].message == f'rejected {N - 1}'

    # Replay into raw subscribers: every message, in order, byte for byte.
    node.destroy_publisher(latched_pub)
    for pub in pubs.values():
        node.destroy_publisher(pub)
    received = {topic: [] for topic in TOPICS}
    for topic, (msg_type, _) in TOPICS.items():
        node.create_subscription(msg_type, topic, received[topic].append, KEEP_ALL, raw=True)
    player = ros_process(
        'rosbag_mcap',
        'bag_player',
        '--ros-args',
        '-p',
        f'bag:={bag}',
        '-p',
        'wait_for_subscribers:=1',
        '-p',
        'linger:=20.0',
    )
    assert spin_until(executor, lambda: all(len(v) >= N for v in received.values()), 30.0), (
        player.output()
    )
    assert received == {topic: recorded[topic] for topic in TOPICS}  # byte for byte
    late = []
    node.create_subscription(String, LATCHED_TOPIC, late.append, LATCHED, raw=True)
    assert spin_until(executor, lambda: bool(late), 10.0), player.output()
    assert late == recorded[LATCHED_TOPIC]
    assert same_messages({**received, LATCHED_TOPIC: late})
    assert player.wait_for_output('played 121 messages', 5.0), player.output()
    assert player.stop() == 0  # SIGINT while lingering is a normal end
    assert_clean_output(player.output())


def test_sigterm_closes_the_recording_and_truncated_bag_plays_its_readable_part(
    ros_process, rclpy_context, spin_until, tmp_path, repo_root
):
    node = Node('bagtest_source', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    pub = node.create_publisher(String, '/bagtest/chatter', KEEP_ALL)
    bag = tmp_path / 'stopped'
    recorder = ros_process(
        'rosbag_mcap',
        'bag_recorder',
        '--ros-args',
        '-p',
        f'output:={bag}',
        '-p',
        'topics:=[/bagtest/chatter]',
        '-p',
        'chunk_size:=1024',
        '-p',
        'discovery_period:=0.2',
    )
    assert spin_until(executor, lambda: pub.get_subscription_count() >= 1, 20.0), recorder.output()
    for i in range(200):
        pub.publish(String(data=f'message {i:03d} ' + 'x' * 40))
    assert pub.wait_for_all_acked()
    recorder.proc.send_signal(signal.SIGTERM)
    assert recorder.proc.wait(10.0) == 0, recorder.output()
    assert_clean_output(recorder.output())
    whole = BagReader(bag)
    assert whole.complete and whole.readable_message_count == 200

    # A copy cut in half (inside the data): the player names the file, plays the readable
    # first part in order and exits with status 3.
    cut = tmp_path / 'cut'
    shutil.copytree(bag, cut)
    mcap_file = cut / 'stopped_0.mcap'
    with open(mcap_file, 'rb') as stream:
        data_end = make_reader(stream).get_summary().chunk_indexes[-1]
    with open(mcap_file, 'r+b') as stream:
        stream.truncate((data_end.chunk_start_offset + data_end.chunk_length) // 2)
    readable = BagReader(cut).readable_message_count
    assert 0 < readable < 200
    node.destroy_publisher(pub)
    received = []
    # Also: the installed defaults file and a ROS remap rule are honoured.
    node.create_subscription(String, '/bagtest/renamed', received.append, KEEP_ALL)
    params = repo_root / 'ros2_ws/src/rosbag_mcap/config/bag_player.param.yaml'
    player = ros_process(
        'rosbag_mcap',
        'bag_player',
        '--ros-args',
        '--params-file',
        params,
        '-p',
        f'bag:={cut}',
        '-p',
        'rate:=0.0',
        '-p',
        'wait_for_subscribers:=1',
        '-r',
        '/bagtest/chatter:=/bagtest/renamed',
    )
    assert spin_until(executor, lambda: len(received) >= readable, 30.0), player.output()
    assert player.proc.wait(20.0) == 3, player.output()
    out = player.output()
    assert_clean_output(out)
    assert str(mcap_file) in out and 'truncated or corrupt' in out
    assert f'played the readable part, {readable} messages of 200 recorded' in out
    assert [m.data[:11] for m in received] == [f'message {i:03d}' for i in range(readable)]


def installed(repo_root: Path, executable: str) -> Path:
    return repo_root / 'ros2_ws' / 'install' / 'rosbag_mcap' / 'lib' / 'rosbag_mcap' / executable


def run_player(repo_root: Path, ros_env: dict, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(installed(repo_root, 'bag_player')), '--ros-args', *args],
        env=ros_env,
        capture_output=True,
        text=True,
        timeout=30,
    )


def test_player_refuses_bad_input_with_a_reason(repo_root, ros_env, tmp_path):
    junk = tmp_path / 'junk.mcap'
    junk.write_bytes(b'this is not a bag\n' * 10)
    result = run_player(repo_root, ros_env, '-p', f'bag:={junk}')
    assert result.returncode == 1
    assert f'{junk}: not an MCAP file' in result.stderr
    assert_clean_output(result.stdout + result.stderr)

    result = run_player(repo_root, ros_env, '-p', f'bag:={tmp_path / "nowhere"}')
    assert result.returncode == 1 and 'no such bag' in result.stderr

    with BagWriter(tmp_path / 'ok') as writer:  # a valid, empty bag
        pass
    result = run_player(repo_root, ros_env, '-p', f'bag:={writer.directory}', '-p', 'rate:=-2.0')
    assert result.returncode == 2 and 'parameter rate' in result.stderr
    assert 'refused' in result.stderr
    assert_clean_output(result.stdout + result.stderr)


def test_recorder_refuses_bad_parameters_and_a_used_output(repo_root, ros_env, tmp_path):
    exe = installed(repo_root, 'bag_recorder')
    results = []

    def run(*args: str) -> subprocess.CompletedProcess:
        results.append(
            subprocess.run(
                [str(exe), '--ros-args', *args],
                env=ros_env,
                capture_output=True,
                text=True,
                timeout=30,
                cwd=tmp_path,
            )
        )
        return results[-1]

    result = run('-p', 'discovery_period:=0.0', '-p', f'output:={tmp_path / "a"}')
    assert result.returncode == 2 and 'parameter discovery_period' in result.stderr
    result = run('-p', 'include_regex:=(unclosed', '-p', f'output:={tmp_path / "b"}')
    assert result.returncode == 2 and 'not a valid regular expression' in result.stderr
    used = tmp_path / 'used'
    used.mkdir()
    (used / 'keep.txt').write_text('do not overwrite')
    result = run('-p', f'output:={used}')
    assert result.returncode == 1 and 'not an empty directory' in result.stderr
    assert (used / 'keep.txt').read_text() == 'do not overwrite'
    for r in results:
        assert_clean_output(r.stdout + r.stderr)
    assert not (tmp_path / 'a').exists() and not (tmp_path / 'b').exists()


def test_stop_takes_the_whole_backlog_of_a_recorder_that_fell_behind(
    ros_process, rclpy_context, spin_until, tmp_path
):
    # A burst faster than the recorder can write: when the publisher has every message
    # acknowledged, the recorder still holds a backlog; a SIGINT right then must keep it all.
    node = Node('bagtest_burst', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    pub = node.create_publisher(Detection, '/bagtest/burst', KEEP_ALL)
    bag = tmp_path / 'burst'
    recorder = ros_process(
        'rosbag_mcap',
        'bag_recorder',
        '--ros-args',
        '-p',
        f'output:={bag}',
        '-p',
        'topics:=[/bagtest/burst]',
        '-p',
        'discovery_period:=0.2',
    )
    assert spin_until(executor, lambda: pub.get_subscription_count() >= 1, 20.0), recorder.output()
    burst = 12000
    # No flow-control pauses (a real burst), but a full writer waits instead of failing.
    sender = ReliablePublisher(pub, rclpy_context, window=burst)
    for i in range(burst):
        assert sender.publish(make_detection(i))
    assert pub.wait_for_all_acked()
    assert recorder.stop() == 0, recorder.output()
    assert_clean_output(recorder.output())
    reader = BagReader(bag)
    assert reader.complete and reader.readable_message_count == burst
