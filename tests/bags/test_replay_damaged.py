"""scripts/replay.py on a damaged bag: replays the readable part, says so, exits 3.

The bag is built from the repository's sample (episodes 1 and 2, whose stamps the nodes
accept), written in small chunks so that one flipped byte costs a few hundred messages; a
replay of it cannot claim to reproduce the recorded accuracy.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader
from rclpy.serialization import deserialize_message

from road_sensor_msgs.msg import Detection, EpisodeInfo, GroundTruth
from rosbag_mcap.reader import BagReader
from rosbag_mcap.storage import BagWriter

pytestmark = pytest.mark.ros
REPO = Path(__file__).resolve().parents[2]


def keep(topic: str, data: bytes) -> bool:
    """Episodes 1 and 2 only: a bag of two whole episodes, smaller than the sample."""
    if topic == '/road/episode':
        return deserialize_message(data, EpisodeInfo).episode_id != 0
    if topic == '/road/ground_truth':
        return deserialize_message(data, GroundTruth).episode_id != 0
    if topic.endswith('/detections'):
        return deserialize_message(data, Detection).header.stamp.sec >= 0
    return topic != '/mlkm/score'


def build_bag(path: Path) -> int:
    reader = BagReader(REPO / 'bags' / 'sample')
    count = 0
    with BagWriter(path, chunk_size=16 * 1024) as writer:
        for message in reader.messages():
            if not keep(message.topic, message.data):
                continue
            if not writer.has_topic(message.topic):
                info = reader.topics[message.topic]
                writer.add_topic(
                    message.topic,
                    info.type,
                    reader.definition(message.topic),  # the bytes' own definition
                    info.offered_qos,
                    info.type_hash,
                )
            writer.write(message.topic, message.data, message.log_time, message.publish_time)
            count += 1
    return count


def replay(bag: Path, ros_env: dict) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(REPO / 'scripts' / 'replay.py'), str(bag), '--timeout', '300'],
        env=ros_env,
        capture_output=True,
        text=True,
        timeout=600,
        cwd=REPO,
    )


def test_replay_of_a_damaged_bag_warns_and_exits_3(tmp_path, ros_env):
    bag = tmp_path / 'two_episodes'
    total = build_bag(bag)
    mcap_file = bag / 'two_episodes_0.mcap'
    with open(mcap_file, 'rb') as stream:
        chunks = sorted(
            make_reader(stream).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset
        )
    chunk = chunks[len(chunks) // 2]
    data = bytearray(mcap_file.read_bytes())
    data[chunk.chunk_start_offset + chunk.chunk_length - chunk.compressed_size // 2] ^= 0x5A
    mcap_file.write_bytes(bytes(data))
    reader = BagReader(bag)
    readable = sum(1 for _ in reader.messages())
    assert 0 < readable < total

    result = replay(bag, ros_env)
    out = result.stdout + result.stderr
    assert result.returncode == 3, out
    assert 'Traceback' not in out, out
    assert f'replay: WARNING: {bag} is damaged' in result.stderr
    assert f'corrupt chunk at byte {chunk.chunk_start_offset}' in result.stderr
    assert f'{readable} of the {total} recorded messages are readable' in result.stderr
    assert 'same accuracy' not in out
    assert 'recorded run: not compared, the bag is damaged' in result.stdout
    rows = [line.split() for line in result.stdout.splitlines()]
    assert {r[0] for r in rows if len(r) > 3 and r[1] == 'mlkm'} == {'1', '2'}
    assert 'mean accuracy over 2 episode(s)' in result.stdout
