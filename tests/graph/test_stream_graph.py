"""Stream mode across processes: SUMO sensors on the ramps scenario (continuous) feed the
association node in stream mode while bag_recorder records; the labels the live node
commits equal ``mlkm associate --stream`` on the recorded bag's detections.

Every process is started through the ``ros_process`` fixture, which stops it at teardown
even when the test fails.
"""

from __future__ import annotations

import csv
import math
import subprocess

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message

from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import Detection, SensorLayout, TrackArray
from rosbag_mcap.reader import BagReader

pytestmark = [pytest.mark.ros, pytest.mark.slow]

LAG = 15.0
#: [s] of quiet wall time before the node flushes the road once SUMO (as fast as it runs) ended
QUIET_FLUSH = 5.0
#: Stations about 400 m apart on the first 1.6 km, an on-ramp (1.2 km) between the last two.
STATIONS = '300,700,1100,1550'


class Listener:
    def __init__(self, context) -> None:
        self.node = Node('stream_graph_listener', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.tracks: list[TrackArray] = []
        self.diag: dict[str, str] = {}
        self.node.create_subscription(
            TrackArray, qos.TRACKS_TOPIC, self.tracks.append, qos.TRACKS_QOS
        )
        self.node.create_subscription(
            DiagnosticArray, qos.DIAGNOSTICS_TOPIC, self._on_diag, qos.DIAGNOSTICS_QOS
        )

    def _on_diag(self, msg: DiagnosticArray) -> None:
        values = conv.diagnostics_values(msg, '/association_node')
        if values is not None:
            self.diag = values

    def labels(self) -> dict[tuple[int, int, int], int]:
        """(sensor id, lane, stamp ns) -> the latest track of every published detection."""
        out = {}
        for msg in self.tracks:
            d = conv.stream_tracks_from_msg(msg)
            for i in range(d.labels.size):
                out[(int(d.sensor_ids[i]), int(d.lanes[i]), int(d.stamps_ns[i]))] = int(
                    d.labels[i]
                )
        return out

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


def partition(labels: dict) -> set[frozenset]:
    """The association as a set of tracks (each a set of keys); unassigned ones alone."""
    groups: dict[int, set] = {}
    alone = []
    for key, label in labels.items():
        if label < 0:
            alone.append(frozenset([key]))
        else:
            groups.setdefault(label, set()).add(key)
    return {frozenset(g) for g in groups.values()} | set(alone)


def test_live_stream_commits_what_the_offline_cli_commits(
    ros_process, rclpy_context, spin_until, tmp_path
) -> None:
    bag = tmp_path / 'stream_bag'
    listener = Listener(rclpy_context)
    try:
        ros_process(
            'mlkm_assoc',
            'association_node',
            '--ros-args',
            '-p',
            'mode:=stream',
            '-p',
            f'lag:={LAG}',
            '-p',
            f'quiet_flush:={QUIET_FLUSH}',
            '-p',
            'diagnostics_period:=0.5',
        )
        recorder = ros_process(
            'rosbag_mcap',
            'bag_recorder',
            '--ros-args',
            '-p',
            f'output:={bag}',
            '-p',
            'exclude_regex:=^/(rosout|parameter_events)$',
        )
        assert spin_until(
            listener.executor,
            lambda: (
                listener.node.count_publishers(qos.TRACKS_TOPIC) >= 1
                and listener.node.count_subscribers(qos.TRACKS_TOPIC) >= 2
            ),
            60.0,
        )
        sumo = ros_process(
            'road_sensors',
            'sumo_sensors',
            '--ros-args',
            '-p',
            'mode:=continuous',
            '-p',
            'scenario:=ramps',
            '-p',
            f'stations_at:={STATIONS}',
            '-p',
            'duration:=60.0',
            '-p',
            'real_time_factor:=0.0',
            '-p',
            'wait_for_subscribers:=2',
            '-p',
            'wait_for_truth_subscribers:=1',
        )
        assert spin_until(listener.executor, lambda: sumo.proc.poll() is not None, 240.0)
        assert sumo.proc.returncode == 0, sumo.output()
        # The road falls quiet: after QUIET_FLUSH seconds the node flushes; every link is
        # committed.
        assert spin_until(
            listener.executor,
            lambda: (
                listener.diag.get('stream.working_set') == '0'
                and int(listener.diag.get('stream.pushed', '0')) > 0
                and listener.diag.get('stream.reorder_held', '0') == '0'
                and listener.tracks
                and conv.time_to_ns(listener.tracks[-1].committed_until)
                > max(k[2] for k in listener.labels())
            ),
            LAG + 120.0,
        ), listener.diag
        spin_until(listener.executor, lambda: False, 1.0)  # anything still on its way
        live = listener.labels()
        pushed = int(listener.diag['stream.pushed'])
        assert recorder.stop() == 0, recorder.output()
    finally:
        listener.close()

    # The recorded detections, in a CSV for the offline CLI.
    reader = BagReader(bag)
    rows, layout_msg = [], None
    for m in reader.messages():
        if m.topic == '/road/sensor_layout':
            layout_msg = deserialize_message(m.data, SensorLayout)
        elif m.topic.startswith('/road/sensors/'):
            d = deserialize_message(m.data, Detection)
            rows.append(
                (
                    d.sensor_id,
                    d.position,
                    conv.time_to_ns(d.header.stamp),
                    d.velocity,
                    d.lane,
                    conv.detection_length(d),
                )
            )
    assert layout_msg is not None and len(rows) == pushed == len(live) > 50
    assert len({r[0] for r in rows}) == 4  # every station saw traffic
    rows.sort(key=lambda r: (r[2], r[1], r[4]))
    src, out = tmp_path / 'detections.csv', tmp_path / 'tracks.csv'
    with open(src, 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(['sensor_id', 'position_m', 'stamp_s', 'velocity_mps', 'lane', 'length_m'])
        for sensor, position, ns, velocity, lane, length in rows:
            w.writerow(
                [
                    sensor,
                    repr(position),
                    repr(ns / conv.NS_PER_S),
                    repr(velocity),
                    lane,
                    'nan' if math.isnan(length) else repr(length),
                ]
            )
    entries, exits = conv.layout_ramps(layout_msg)
    argv = ['mlkm', 'associate', '--stream', '--lag', str(LAG), '--method', 'multiframe']
    argv += ['--input', str(src), '--output', str(out)]
    if entries:
        argv += ['--entries', ','.join(repr(x) for x in entries)]
    if exits:
        argv += ['--exits', ','.join(repr(x) for x in exits)]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    offline = {}
    with open(out, newline='') as f:
        for r in csv.DictReader(f):
            key = (int(r['sensor_id']), int(r['lane']), conv.seconds_to_ns(float(r['stamp_s'])))
            offline[key] = int(r['track_id'])
    assert set(offline) == set(live)
    assert partition(live) == partition(offline)
    assert sum(1 for v in live.values() if v >= 0) > len(live) // 2  # mostly tracked
