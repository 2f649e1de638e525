"""Shards across processes: three association nodes, each in its own namespace and owning a
third of a road, hand tracks over on /mlkm/handoff; ``track_merge`` publishes the one view.

The source is the shipped NGSIM I-80 traffic (real vehicles) seen by 20 virtual loops,
replayed by ``log_source`` in continuous mode. The merged committed tracks equal the offline
shards (``mlkm_core.shards.sharded``) on the same detections, every vehicle's id is the same
from one end of the road to the other, and the accuracy equals one node's.
"""

from __future__ import annotations

import math
import signal
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from mlkm_core.csvout import write_detections
from mlkm_core.layout_file import RoadLayout, write_layout_file
from mlkm_core.loops import even_positions, virtual_loops
from mlkm_core.metrics import accuracy
from mlkm_core.shards.regions import split_road
from mlkm_core.shards.sharded import associate_sharded
from mlkm_core.streaming import StreamConfig, StreamTracker
from mlkm_core.trajectories import read_trajectories
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import TrackArray

pytestmark = [pytest.mark.ros, pytest.mark.slow]

STATIONS, START, END = 20, 50.0, 450.0
SHARDS = 3
LAG = 30.0
#: [s] of quiet wall time before the shards flush the road, once the log (replayed as fast as
#: delivery allows) has ended; far less than the lag of stamps, far more than any pause of
#: the replay
QUIET_FLUSH = 8.0
METHOD = 'multiframe'
DATA = Path(__file__).resolve().parents[2] / 'data' / 'ngsim_i80' / 'i80_trajectories_a.csv.gz'
NS_PER_S = 1_000_000_000


class TrackListener:
    """The merged /mlkm/tracks: the latest track of every detection and the FINAL ids; and
    every shard's own /shard_<k>/mlkm/tracks, so that a detection missing from the merged view
    is told apart from one that no shard published."""

    def __init__(self, context) -> None:
        self.node = Node('shards_listener', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.labels: dict[tuple[int, int, int], int] = {}
        self.final: set[int] = set()
        self.committed_ns = 0
        self.node.create_subscription(TrackArray, qos.TRACKS_TOPIC, self._on, qos.TRACKS_QOS)
        self.shard_labels: list[dict[tuple[int, int, int], int]] = [{} for _ in range(SHARDS)]
        for k in range(SHARDS):
            self.node.create_subscription(
                TrackArray,
                f'/shard_{k}/{qos.TRACKS_TOPIC}',
                lambda msg, k=k: _take(self.shard_labels[k], msg),
                qos.TRACKS_QOS,
            )
        self.diag: dict[str, dict[str, str]] = {}
        self.node.create_subscription(
            DiagnosticArray, qos.DIAGNOSTICS_TOPIC, self._on_diag, qos.DIAGNOSTICS_QOS
        )

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.diag[status.name] = {kv.key: kv.value for kv in status.values}

    def _on(self, msg: TrackArray) -> None:
        self.committed_ns = max(self.committed_ns, _take(self.labels, msg))
        self.final.update(int(t.track_id) for t in msg.tracks if t.status == 2)

    def published_by(self, key: tuple[int, int, int]) -> list[tuple[int, int]]:
        """(shard, its track) of every shard that published the detection ``key``."""
        return [(k, s[key]) for k, s in enumerate(self.shard_labels) if key in s]

    def subscribers(self, topic: str) -> int:
        return self.node.count_subscribers(topic)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


def _take(labels: dict[tuple[int, int, int], int], msg: TrackArray) -> int:
    """The latest track of every detection of a stream TrackArray into ``labels``; its
    committed_until [ns]."""
    d = conv.stream_tracks_from_msg(msg)
    for i in range(d.labels.size):
        labels[(int(d.sensor_ids[i]), int(d.lanes[i]), int(d.stamps_ns[i]))] = int(d.labels[i])
    return d.committed_until_ns


@pytest.fixture
def listener(rclpy_context):
    lst = TrackListener(rclpy_context)
    yield lst
    lst.close()


@pytest.fixture(scope='module')
def ngsim_stream(tmp_path_factory):
    """(log, layout file, dataset) of 20 virtual loops on the NGSIM trajectories."""
    traj = read_trajectories(DATA)
    loops = virtual_loops(traj, even_positions(STATIONS, START, END), closed=False)
    ds = loops.dataset
    out = tmp_path_factory.mktemp('shards_log')
    log, layout = out / 'i80_loops.csv', out / 'i80_loops.layout.yaml'
    road = Layout(ds.layout.road_length, np.round(ds.layout.positions, 3))
    write_detections(log, road, ds.detections, decimals=(3, 3, 3, 2))
    write_layout_file(layout, RoadLayout(road, np.full(STATIONS, loops.lanes)))
    return log, layout, ds, road


def _keys(road: Layout, d) -> list[tuple[int, int, int]]:
    """The join key of every detection, with the stamps as the log's 3 decimals give them."""
    return [
        (int(road.sensor_ids[s]), int(lane), round(round(float(t), 3) * NS_PER_S))
        for s, lane, t in zip(d.sensor_index, d.lane, d.stamp, strict=True)
    ]


def _same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    pairs = set(zip(a.tolist(), b.tolist(), strict=True))
    return len(pairs) == len(set(a.tolist())) == len(set(b.tolist()))


def test_three_shards_equal_the_offline_shards_and_one_node(
    ros_process, listener, spin_until, ngsim_stream
) -> None:
    log, layout, ds, road = ngsim_stream
    d = ds.detections
    config = StreamConfig(method=METHOD, lag=LAG)
    offline = associate_sharded(road, d, SHARDS, config)
    one = StreamTracker(road, config)
    assert offline.accepted[1] > 50 and offline.accepted[2] > 50  # vehicles cross borders

    shards = []  # each waits for its two track subscribers: track_merge and the listener
    for k in range(SHARDS):
        shards.append(
            ros_process(
                'mlkm_assoc', 'association_node', '--ros-args',
                '-r', f'__ns:=/shard_{k}', '-p', 'source_namespace:=/',
                '-p', 'mode:=stream', '-p', f'stream_method:={METHOD}', '-p', f'lag:={LAG}',
                '-p', f'quiet_flush:={QUIET_FLUSH}',
                '-p', f'shard_count:={SHARDS}', '-p', f'shard_index:={k}',
                '-p', 'wait_for_track_subscribers:=2',
            )
        )  # fmt: skip
    merge = ros_process(
        'mlkm_assoc', 'track_merge', '--ros-args',
        '-p', f'shard_count:={SHARDS}', '-p', 'wait_for_track_subscribers:=1',
    )  # fmt: skip
    # every station's topic has its owner and the shards that take it as margin
    regions = split_road(STATIONS, SHARDS)
    wanted = {
        qos.detections_topic(road.names[s]): sum(s in r.stations for r in regions)
        for s in range(STATIONS)
    }
    # the layout comes from the source; the shards subscribe to their stations once it
    # reached them: the source holds its detections until every shard did (a topic has its
    # owner and the shards that take it as margin)
    source = ros_process(
        'road_sensors', 'log_source', '--ros-args',
        '-p', f'log:={log}', '-p', f'layout:={layout}', '-p', 'mode:=continuous',
        '-p', 'wait_for_subscribers:=1', '-p', 'keep_running:=true',
        '-p', f'wait_for_subscriptions:={sum(wanted.values())}',
    )  # fmt: skip
    procs = [*shards, merge, source]
    topics_ok = spin_until(
        listener.executor,
        lambda: all(listener.subscribers('/' + t) >= n for t, n in wanted.items()),
        90.0,
    )
    assert topics_ok, ''.join(p.output() for p in procs)
    keys = _keys(road, d)
    everything = spin_until(
        listener.executor,
        lambda: (
            all(k in listener.labels for k in keys)
            and listener.committed_ns > max(k[2] for k in keys)
        ),
        180.0,
    )
    missing = [k for k in keys if k not in listener.labels]
    unpublished = [k for k in missing if not listener.published_by(k)]
    lost = [listener.published_by(k) for k in missing if k not in unpublished]
    assert everything, (
        f'{len(missing)} detections without a track (sensor id, lane, stamp ns: '
        f'{missing[:20]}), {len(unpublished)} of them published by no shard, the others by '
        f'(shard, track) {lost[:20]}'
        f'; committed until {listener.committed_ns} ns of '
        f'{max(k[2] for k in keys)}; diagnostics {listener.diag}\n'
        + ''.join(p.output() for p in procs)
    )
    source.proc.send_signal(signal.SIGINT)
    assert source.proc.wait(30) == 0, source.output()
    live = np.array([listener.labels[k] for k in keys])
    assert _same_partition(live, offline.labels)
    # one id from one end of the road to the other: a vehicle seen at the first and the
    # last station is one track, which began in shard 0
    for target in set(d.target[d.sensor_index == 0]) & set(d.target[d.sensor_index == 19]):
        ids = set(live[d.target == target].tolist())
        if len(ids) == 1:
            assert next(iter(ids)) % 1024 == 0
    a_live = accuracy(live, d.target).accuracy
    one_labels = _one_node(one, d)
    assert math.isclose(a_live, accuracy(one_labels, d.target).accuracy, abs_tol=1e-9)
    out = ''.join(p.output() for p in shards)
    assert 'ERROR' not in out and 'Traceback' not in out


def _one_node(tracker: StreamTracker, d) -> np.ndarray:
    n = len(d.stamp)
    labels = np.full(n, -1, np.int64)
    for i in np.lexsort((np.arange(n), d.sensor_index, d.stamp)).tolist():
        up = tracker.push(i, int(d.sensor_index[i]), float(d.stamp[i]), float(d.velocity[i]),
                          int(d.lane[i]), float(d.length[i]))  # fmt: skip
        for key, track in up.committed.tolist():
            labels[key] = track
    for key, track in tracker.flush().committed.tolist():
        labels[key] = track
    return labels
