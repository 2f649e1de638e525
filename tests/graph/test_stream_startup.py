"""A freshly started association node in stream mode on a busy machine: it subscribes to the
sensors at once and its tracker is ready within seconds, so a source that starts publishing
right away loses nothing and gets its tracks at once.

The load: CPU burners, one more than the machine has cores, for the whole test. The node is
the installed executable (``ros_process``); the test's node publishes the layout and the
detections and collects the tracks and /diagnostics.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from mlkm_assoc.stream_ingest import StreamIngest
from mlkm_core.bounds import Bounds
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import Detection, SensorLayout, Track, TrackArray

pytestmark = [pytest.mark.ros, pytest.mark.slow]

IDS = [21, 22, 23]
NAMES = ['up', 'mid', 'down']
POS = [100.0, 150.0, 200.0]  # 2 s apart at 25 m/s, less than the lag
LAYOUT = Layout(300.0, np.array(POS), np.array(IDS), tuple(NAMES))
#: the issue's bound on the tracker's start and a detection's wait for its first track [s]
START_LIMIT = 5.0


def rows() -> list[tuple[int, int, float]]:
    """(sensor index, stamp ns, speed) of 4 vehicles 20 s apart at 25 m/s, in stamp order."""
    out = [
        (s, conv.seconds_to_ns(10.0 + 20.0 * v + POS[s] / 25.0), 25.0)
        for v in range(4)
        for s in range(3)
    ]
    return sorted(out, key=lambda r: r[1])


class Source:
    def __init__(self, context) -> None:
        self.node = Node('startup_source', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.layout_pub = self.node.create_publisher(
            SensorLayout, qos.LAYOUT_TOPIC, qos.LAYOUT_QOS
        )
        self.det_pubs = [
            self.node.create_publisher(Detection, qos.detections_topic(n), qos.DETECTIONS_QOS)
            for n in NAMES
        ]
        self.tracks: list[tuple[float, TrackArray]] = []
        self.diag: dict[str, str] = {}
        self.diag_level = -1
        self.node.create_subscription(
            TrackArray,
            qos.TRACKS_TOPIC,
            lambda m: self.tracks.append((time.monotonic(), m)),
            qos.TRACKS_QOS,
        )
        self.node.create_subscription(
            DiagnosticArray, qos.DIAGNOSTICS_TOPIC, self._on_diag, qos.DIAGNOSTICS_QOS
        )

    def _on_diag(self, msg: DiagnosticArray) -> None:
        values = conv.diagnostics_values(msg, '/association_node')
        if values is not None:
            self.diag = values

    def latest(self) -> dict[tuple[int, int], int]:
        """(sensor id, stamp ns) -> status of every published detection's latest state."""
        out = {}
        for _, msg in self.tracks:
            d = conv.stream_tracks_from_msg(msg)
            for i in range(d.labels.size):
                out[(int(d.sensor_ids[i]), int(d.stamps_ns[i]))] = int(d.status[i])
        return out

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.fixture
def load():
    """CPU burners, one more than the cores, stopped by their pid at the end."""
    burners = [
        subprocess.Popen([sys.executable, '-c', 'while True: pass'])
        for _ in range((os.cpu_count() or 1) + 1)
    ]
    yield
    for p in burners:
        p.kill()
        p.wait(10.0)


@pytest.mark.parametrize('mode', ['stream', 'auto'])
def test_node_subscribes_at_once_and_its_tracker_is_ready_under_load(
    mode, load, ros_process, rclpy_context, spin_until
) -> None:
    source = Source(rclpy_context)
    ex = source.executor
    try:
        source.layout_pub.publish(conv.layout_to_msg(LAYOUT, conv.seconds_to_ns(1.0)))
        node = ros_process(
            'mlkm_assoc',
            'association_node',
            '--ros-args',
            '-p',
            f'mode:={mode}',
            '-p',
            'lag:=3.0',
            '-p',
            'diagnostics_period:=0.5',
        )
        # the node's process is up: its layout subscription exists
        assert spin_until(ex, lambda: source.layout_pub.get_subscription_count() >= 1, 180.0), (
            node.output()
        )
        up = time.monotonic()
        # it subscribes to every sensor at once, not after its tracker warmed up
        assert spin_until(
            ex, lambda: all(p.get_subscription_count() >= 1 for p in source.det_pubs), 180.0
        ), node.output()
        subscribed = time.monotonic() - up
        # a source that publishes right away
        data = rows()
        first = time.monotonic()
        for s, ns, v in data:
            source.det_pubs[s].publish(conv.detection_to_msg(IDS[s], ns, POS[s], v, -1))
        first_key = (IDS[data[0][0]], data[0][1])
        assert spin_until(ex, lambda: first_key in source.latest(), 180.0), node.output()
        first_track = next(t for t, m in source.tracks if first_key in _keys(m)) - first
        # nothing lost: every detection ends in a FINAL track once the road fell quiet
        keys = {(IDS[s], ns) for s, ns, _ in data}
        assert spin_until(
            ex,
            lambda: all(source.latest().get(k) == Track.STATUS_FINAL for k in keys),
            180.0,
        ), (source.latest(), node.output())
        assert spin_until(
            ex,
            lambda: (
                source.diag.get('stream.working_set') == '0'
                and source.diag.get('received') == str(len(data))
            ),
            60.0,
        ), source.diag
        d = source.diag
        assert d['accepted'] == str(len(data)) and d['rejected'] == '0', d
        assert d['stream.tracker_ready'] == 'True', d
        ready_after = float(d['stream.tracker_ready_after'])
    finally:
        source.close()
    timings = f'subscribed {subscribed:.2f} s, first track {first_track:.2f} s'
    timings += f', tracker ready {ready_after:.2f} s'
    print(timings)
    assert subscribed < START_LIMIT, timings
    assert first_track < START_LIMIT, timings
    assert ready_after < START_LIMIT, timings


def _keys(msg: TrackArray) -> set[tuple[int, int]]:
    d = conv.stream_tracks_from_msg(msg)
    return {(int(d.sensor_ids[i]), int(d.stamps_ns[i])) for i in range(d.labels.size)}


def test_detections_beyond_the_tracker_queue_are_refused_and_counted() -> None:
    """While the tracker process takes nothing, its queue fills: a detection it refuses is
    rejected as buffer_full (counted), and the same detection sent again once there is room
    is taken, not refused as a duplicate."""
    room = [True]
    taken: list[tuple] = []

    def send(item: tuple) -> bool:
        if item[0] == 'det' and not room[0]:
            return False
        taken.append(item)
        return True

    ingest = StreamIngest(Bounds(), 100, send)
    ingest.set_layout(LAYOUT, None, (), ())
    ns = conv.seconds_to_ns(14.0)
    ingest.add(IDS[0], ns, POS[0], 25.0, -1, math.nan, 0.0)
    room[0] = False
    ingest.add(IDS[1], ns + 2 * conv.NS_PER_S, POS[1], 25.0, -1, math.nan, 0.1)
    assert (ingest.accepted, dict(ingest.rejected)) == (1, {'buffer_full': 1})
    room[0] = True
    ingest.add(IDS[1], ns + 2 * conv.NS_PER_S, POS[1], 25.0, -1, math.nan, 0.2)
    assert (ingest.accepted, dict(ingest.rejected)) == (2, {'buffer_full': 1})
    assert [item[0] for item in taken] == ['layout', 'det', 'det']
    assert [item[1] for item in taken[1:]] == [0, 1]  # keys numbered without a gap
