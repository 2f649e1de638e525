"""A full disk ends a recording cleanly and keeps a readable bag of what was written.

In-process: the MCAP stream refuses bytes past a limit with ENOSPC (as a full disk does).
Process-level: bag_recorder writes onto a 1 MiB tmpfs until it is full (needs root to mount;
skipped elsewhere, the in-process test covers the writer).
"""

from __future__ import annotations

import errno
import io
import subprocess
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import Reader as Rosbag2Reader
from rosbags.typesys import Stores, get_typestore
from std_msgs.msg import String

from rosbag_mcap import storage
from rosbag_mcap.definitions import DefinitionCache
from rosbag_mcap.reader import BagReader
from rosbag_mcap.storage import RESERVE_FILE, BagWriteError, BagWriter

STORE = get_typestore(Stores.ROS2_JAZZY)
KEEP_ALL = QoSProfile(
    history=HistoryPolicy.KEEP_ALL, depth=0, reliability=ReliabilityPolicy.RELIABLE
)


def text(i: int) -> str:
    return f'message {i:05d} ' + 'abcdefghij' * (5 + i % 7)


def rosbags_texts(bag: Path) -> list[str]:
    with Rosbag2Reader(bag) as reader:
        assert reader.message_count == sum(c.msgcount for c in reader.connections)
        return [STORE.deserialize_cdr(raw, c.msgtype).data for c, _, raw in reader.messages()]


def mcap_ros2_texts(mcap_file: Path) -> list[str]:
    with open(mcap_file, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [m.data for _, _, _, m in reader.iter_decoded_messages()]


class _FullDisk(io.FileIO):
    """A file on a disk with ``room`` bytes left: writes past it fail with ENOSPC."""

    def __init__(self, path, mode, room: int):
        super().__init__(path, mode)
        self.room = room

    def write(self, data) -> int:
        if self.room <= 0:
            raise OSError(errno.ENOSPC, 'No space left on device')
        part = bytes(data)[: self.room]
        written = super().write(part)
        self.room -= written
        return written


def test_writer_on_a_full_disk_stops_and_keeps_a_readable_bag(tmp_path, monkeypatch):
    real_open = open

    def fake_open(path, mode='r', *args, **kwargs):
        if str(path).endswith('.mcap') and 'w' in mode:
            return io.BufferedWriter(_FullDisk(path, 'wb', room=40_000))
        return real_open(path, mode, *args, **kwargs)

    monkeypatch.setattr(storage, 'open', fake_open, raising=False)
    bag = tmp_path / 'full'
    writer = BagWriter(bag, chunk_size=2048)
    assert (bag / RESERVE_FILE).is_file()
    writer.add_topic(
        '/full/chatter', 'std_msgs/msg/String', DefinitionCache().full_text('std_msgs/msg/String')
    )
    written = 0
    with pytest.raises(BagWriteError, match='No space left on device'):
        for i in range(100_000):
            data = bytes(
                STORE.serialize_cdr(
                    STORE.types['std_msgs/msg/String'](text(i)), 'std_msgs/msg/String'
                )
            )
            writer.write('/full/chatter', data, log_time=1_000_000_000 + i)
            written += 1
    assert 100 < written < 100_000
    assert 'writing failed: No space left on device' in writer.failure
    with pytest.raises(BagWriteError):  # the recording is over
        writer.write('/full/chatter', b'', log_time=2_000_000_000)

    info = writer.close()
    kept = info['message_count']
    assert 0 < kept <= written
    assert info['topics_with_message_count'][0]['message_count'] == kept
    assert not (bag / RESERVE_FILE).exists()
    expected = [text(i) for i in range(kept)]
    assert rosbags_texts(bag) == expected  # metadata.yaml + a finished MCAP
    assert mcap_ros2_texts(bag / 'full_0.mcap') == expected
    reader = BagReader(bag)
    assert reader.complete and reader.readable_message_count == kept
    assert writer.close() == info  # idempotent


@pytest.fixture
def tiny_disk(tmp_path):
    mount = tmp_path / 'tiny'
    mount.mkdir()
    result = subprocess.run(
        ['mount', '-t', 'tmpfs', '-o', 'size=1m', 'tmpfs', str(mount)],
        capture_output=True,
        text=True,
    )
    if result.returncode != 0:
        pytest.skip(f'cannot mount a tmpfs here: {result.stderr.strip()}')
    try:
        yield mount
    finally:
        subprocess.run(['umount', '-l', str(mount)], check=False)


@pytest.mark.ros
def test_recorder_on_a_full_disk_exits_4_and_leaves_a_readable_bag(
    ros_process, rclpy_context, spin_until, tiny_disk
):
    node = Node('disk_full_source', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    pub = node.create_publisher(String, '/full/chatter', KEEP_ALL)
    bag = tiny_disk / 'bag'
    recorder = ros_process(
        'rosbag_mcap',
        'bag_recorder',
        '--ros-args',
        '-p',
        f'output:={bag}',
        '-p',
        'topics:=[/full/chatter]',
        '-p',
        'compression:=none',
        '-p',
        'chunk_size:=4096',
        '-p',
        'flush_period:=0.1',
        '-p',
        'discovery_period:=0.2',
    )
    assert spin_until(executor, lambda: pub.get_subscription_count() >= 1, 30.0), recorder.output()
    sent = 0
    while recorder.proc.poll() is None and sent < 50_000:  # ~1 MiB fills after ~5,000
        for _ in range(200):
            pub.publish(String(data=text(sent)))
            sent += 1
        spin_until(executor, lambda: recorder.proc.poll() is not None, 0.05)
    assert recorder.proc.wait(120.0) == 4, recorder.output()
    out = recorder.output()
    assert 'Traceback' not in out, out
    assert 'recording failed' in out and 'No space left on device' in out
    assert 'messages written before the failure (finished, with metadata.yaml)' in out
    texts = rosbags_texts(bag)
    assert 0 < len(texts) < sent
    assert f'/full/chatter: {len(texts)}' in out
    assert texts == [text(i) for i in range(len(texts))]  # in order, nothing skipped
    assert mcap_ros2_texts(bag / 'bag_0.mcap') == texts
    assert not (bag / RESERVE_FILE).exists()
