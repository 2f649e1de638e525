"""A damaged chunk costs its own messages only: the chunks after it are read and played.

The damage is one flipped byte inside a chunk's compressed data of the repository's sample bag
(about 6,000 messages). What should survive is computed independently with the mcap library alone:
every message of every other chunk.
"""

from __future__ import annotations

import shutil
from io import BytesIO
from pathlib import Path

import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from road_sensor_msgs.msg import GroundTruth
from rosbag_mcap.reader import BagReader

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / 'bags' / 'sample'
KEEP_ALL = QoSProfile(
    history=HistoryPolicy.KEEP_ALL, depth=0, reliability=ReliabilityPolicy.RELIABLE
)


def chunk_indexes(mcap_file: Path) -> list:
    with open(mcap_file, 'rb') as stream:
        summary = make_reader(stream).get_summary()
    return sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)


def intact_messages(mcap_file: Path, damaged: set[int]) -> list[tuple[str, bytes]]:
    """(topic, payload) of every message outside the damaged chunks, in log-time order,
    decoded from the undamaged original with the mcap library only."""
    with open(mcap_file, 'rb') as stream:
        summary = make_reader(stream).get_summary()
    topics = {c.id: c.topic for c in summary.channels.values()}
    data = mcap_file.read_bytes()
    out = []
    for index in summary.chunk_indexes:
        if index.chunk_start_offset in damaged:
            continue
        body = data[index.chunk_start_offset + 9 : index.chunk_start_offset + index.chunk_length]
        for record in breakup_chunk(Chunk.read(ReadDataStream(BytesIO(body))), True):
            if isinstance(record, Message):
                out.append((record.log_time, topics[record.channel_id], record.data))
    return [(topic, payload) for _, topic, payload in sorted(out, key=lambda m: m[0])]


def damaged_copy(tmp_path: Path, which: list[int]) -> tuple[Path, Path, set[int]]:
    """A copy of the sample with one byte flipped in the compressed data of chunks ``which``."""
    bag = tmp_path / 'sample'
    shutil.copytree(SAMPLE, bag)
    mcap_file = bag / 'sample_0.mcap'
    chunks = chunk_indexes(mcap_file)
    data = bytearray(mcap_file.read_bytes())
    damaged = set()
    for i in which:
        chunk = chunks[i]
        # Past the record header and the chunk's own header fields: inside the zstd data.
        data[chunk.chunk_start_offset + chunk.chunk_length - chunk.compressed_size // 2] ^= 0x5A
        damaged.add(chunk.chunk_start_offset)
    mcap_file.write_bytes(bytes(data))
    return bag, mcap_file, damaged


def test_reader_skips_a_damaged_chunk_and_reads_the_ones_after_it(tmp_path):
    chunks = chunk_indexes(SAMPLE / 'sample_0.mcap')
    which = [0, len(chunks) // 2]
    bag, mcap_file, damaged = damaged_copy(tmp_path, which)
    expected = intact_messages(SAMPLE / 'sample_0.mcap', damaged)
    total = len(intact_messages(SAMPLE / 'sample_0.mcap', set()))
    lost = total - len(expected)
    assert 0 < lost < total // 2

    reader = BagReader(bag)
    got = [(m.topic, m.data) for m in reader.messages()]
    assert got == expected
    assert reader.skipped_chunks == 2 and reader.skipped_messages == lost
    assert reader.damaged
    skipped = [p for p in reader.problems if 'corrupt chunk' in p]
    assert len(skipped) == 2
    for offset, problem in zip(sorted(damaged), skipped):
        assert f'{mcap_file}: corrupt chunk at byte {offset}' in problem
    assert sum('CRC mismatch' in p or 'zstd' in p for p in skipped) == 2

    # Reading again reports each damaged chunk once, and selects topics as usual.
    truth = [m.data for m in reader.messages(topics=['/road/ground_truth'])]
    assert truth == [d for t, d in expected if t == '/road/ground_truth']
    assert len([p for p in reader.problems if 'corrupt chunk' in p]) == 2


def test_unfinished_file_with_a_damaged_chunk_reads_the_chunks_after_it(tmp_path):
    bag, mcap_file, damaged = damaged_copy(tmp_path, [1])
    chunks = chunk_indexes(SAMPLE / 'sample_0.mcap')
    last = chunks[-1]
    with open(mcap_file, 'r+b') as stream:  # no summary: the reader must walk the records
        stream.truncate(last.chunk_start_offset + last.chunk_length // 2)
    (bag / 'metadata.yaml').unlink()
    expected = intact_messages(SAMPLE / 'sample_0.mcap', damaged | {last.chunk_start_offset})

    reader = BagReader(bag)
    assert not reader.complete and reader.skipped_chunks == 1
    assert [(m.topic, m.data) for m in reader.messages()] == expected
    assert reader.readable_message_count == len(expected)
    assert any(
        f'corrupt chunk at byte {chunks[1].chunk_start_offset}' in p for p in reader.problems
    )
    assert any('truncated or corrupt' in p for p in reader.problems)


@pytest.mark.ros
def test_player_plays_the_chunks_after_a_damaged_one_and_exits_3(
    ros_process, rclpy_context, spin_until, tmp_path
):
    chunks = chunk_indexes(SAMPLE / 'sample_0.mcap')
    bag, mcap_file, damaged = damaged_copy(tmp_path, [0, len(chunks) // 2])
    expected = [
        d
        for t, d in intact_messages(SAMPLE / 'sample_0.mcap', damaged)
        if t == '/road/ground_truth'
    ]
    assert 0 < len(expected) < 3000
    node = Node('damaged_bag_listener', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    received = []
    node.create_subscription(
        GroundTruth, '/road/ground_truth', received.append, KEEP_ALL, raw=True
    )
    player = ros_process(
        'rosbag_mcap',
        'bag_player',
        '--ros-args',
        '-p',
        f'bag:={bag}',
        '-p',
        'topics:=[/road/ground_truth]',
        '-p',
        'rate:=0.0',
        '-p',
        'wait_for_subscribers:=1',
    )
    assert spin_until(executor, lambda: len(received) >= len(expected), 120.0), player.output()
    assert player.proc.wait(60.0) == 3, player.output()
    out = player.output()
    assert 'Traceback' not in out, out
    assert received == expected
    assert f'corrupt chunk at byte {min(damaged)}' in out
    assert f'played the readable part, {len(expected)} messages' in out
