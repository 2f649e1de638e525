"""bag_reindex: a recording killed with SIGKILL becomes a bag that rosbags and mcap-ros2 open.

The killed recording has no metadata.yaml and its MCAP no summary or footer; rosbags refuses
it. After bag_reindex both independent readers decode every message that was flushed.
"""

from __future__ import annotations

import shutil
import signal
import subprocess
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import Reader as Rosbag2Reader
from rosbags.typesys import Stores, get_typestore
from std_msgs.msg import String

from rosbag_mcap.reader import BagReader

KEEP_ALL = QoSProfile(
    history=HistoryPolicy.KEEP_ALL, depth=0, reliability=ReliabilityPolicy.RELIABLE
)
LATCHED = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
N = 150


def installed(repo_root: Path, executable: str) -> Path:
    return repo_root / 'ros2_ws' / 'install' / 'rosbag_mcap' / 'lib' / 'rosbag_mcap' / executable


def run_reindex(repo_root: Path, ros_env: dict, *args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(installed(repo_root, 'bag_reindex')), *map(str, args)],
        env=ros_env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def rosbags_strings(bag: Path) -> dict[str, list[str]]:
    store = get_typestore(Stores.ROS2_JAZZY)
    out: dict[str, list[str]] = {}
    with Rosbag2Reader(bag) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for connection, _, raw in reader.messages():
            msg = store.deserialize_cdr(raw, connection.msgtype)
            out.setdefault(connection.topic, []).append(msg.data)
    assert {t: len(v) for t, v in out.items()} == counts
    return out


def mcap_ros2_strings(mcap_file: Path) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    with open(mcap_file, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append(msg.data)
    return out


@pytest.mark.ros
def test_sigkilled_recording_is_reindexed_for_rosbags_and_mcap_ros2(
    ros_process, rclpy_context, spin_until, tmp_path, repo_root, ros_env
):
    node = Node('reindex_source', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    chatter = node.create_publisher(String, '/reindex/chatter', KEEP_ALL)
    latched = node.create_publisher(String, '/reindex/latched', LATCHED)
    latched.publish(String(data='latched'))
    bag = tmp_path / 'killed'
    recorder = ros_process(
        'rosbag_mcap',
        'bag_recorder',
        '--ros-args',
        '-p',
        f'output:={bag}',
        '-p',
        'include_regex:=^/reindex/',
        '-p',
        'chunk_size:=2048',
        '-p',
        'flush_period:=0.1',
        '-p',
        'discovery_period:=0.2',
    )
    assert spin_until(
        executor,
        lambda: chatter.get_subscription_count() >= 1 and latched.get_subscription_count() >= 1,
        30.0,
    ), recorder.output()
    sent = [f'message {i:03d} ' + 'x' * 30 for i in range(N)]
    for text in sent:
        chatter.publish(String(data=text))
    assert chatter.wait_for_all_acked()

    def flushed() -> bool:  # everything on disk (the reader walks the unfinished file)
        try:
            return BagReader(bag).readable_message_count >= N + 1
        except Exception:  # noqa: BLE001 - the file is being written
            return False

    assert spin_until(executor, flushed, 60.0), recorder.output()
    recorder.proc.send_signal(signal.SIGKILL)
    assert recorder.proc.wait(20.0) == -signal.SIGKILL
    assert not (bag / 'metadata.yaml').exists()
    with pytest.raises(Exception):  # noqa: B017 - rosbags cannot open it (any error)
        rosbags_strings(bag)

    result = run_reindex(repo_root, ros_env, bag)
    assert result.returncode == 0, result.stdout + result.stderr
    assert 'Traceback' not in result.stdout + result.stderr
    assert f'wrote {bag / "metadata.yaml"} ({N + 1} messages, 2 topics)' in result.stdout
    assert 'summary and footer written' in result.stdout
    assert not list(bag.glob('.bag_recorder_reserve'))

    expected = {'/reindex/chatter': sent, '/reindex/latched': ['latched']}
    assert rosbags_strings(bag) == expected
    assert mcap_ros2_strings(bag / 'killed_0.mcap') == expected
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['storage_identifier'] == 'mcap' and info['message_count'] == N + 1
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert topics['/reindex/chatter']['message_count'] == N
    assert (
        'transient_local' in topics['/reindex/latched']['topic_metadata']['offered_qos_profiles']
    )
    assert info['duration']['nanoseconds'] > 0
    reader = BagReader(bag)
    assert reader.complete and not reader.damaged and not reader.problems

    # A second run finds nothing to repair and writes the same counts.
    again = run_reindex(repo_root, ros_env, bag)
    assert again.returncode == 0 and 'summary intact' in again.stdout
    assert rosbags_strings(bag) == expected


def test_reindex_cuts_a_truncated_record_and_refuses_what_is_not_a_bag(
    tmp_path, repo_root, ros_env
):
    sample = repo_root / 'bags' / 'sample'
    bag = tmp_path / 'sample'
    shutil.copytree(sample, bag)
    (bag / 'metadata.yaml').unlink()
    mcap_file = bag / 'sample_0.mcap'
    with open(mcap_file, 'rb') as stream:
        chunks = sorted(
            make_reader(stream).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset
        )
    keep = chunks[5]
    with open(mcap_file, 'r+b') as stream:  # inside chunk 5: chunks 0-4 stay whole
        stream.truncate(keep.chunk_start_offset + keep.chunk_length // 2)
    with open(sample / 'sample_0.mcap', 'rb') as stream:
        reader = make_reader(stream)
        whole = [
            (c.topic, m.data)
            for _, c, m in reader.iter_messages(log_time_order=False)
            if m.log_time <= max(c.message_end_time for c in chunks[:5])
        ]
    result = run_reindex(repo_root, ros_env, bag)
    assert result.returncode == 0, result.stderr
    assert 'the file ends in the middle of a record' in result.stderr
    with Rosbag2Reader(bag) as reader:
        got = [(c.topic, bytes(raw)) for c, _, raw in reader.messages()]
    assert sorted(got) == sorted(whole)

    for bad in (tmp_path / 'nowhere', tmp_path / 'empty'):
        if bad.name == 'empty':
            bad.mkdir()
        result = run_reindex(repo_root, ros_env, bad)
        assert result.returncode == 1 and str(bad) in result.stderr
        assert 'Traceback' not in result.stderr
    junk = tmp_path / 'junk'
    junk.mkdir()
    (junk / 'junk_0.mcap').write_bytes(b'not an mcap file' * 10)
    result = run_reindex(repo_root, ros_env, junk)
    assert result.returncode == 1 and 'not an MCAP file' in result.stderr
