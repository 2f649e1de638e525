"""Stream mode of the association node, in process (private rclpy Context, a test publisher).

A hand-made open road: 4 sensors, 3 vehicles passing 50 s apart, no EpisodeInfo at all, so
the right tracks are certain. Every TrackArray is decoded: stream mode, episode 0, never
final, stable track ids; once the road falls quiet (``lag`` seconds of wall time) every track
is FINAL and committed, and the tracks are exactly the vehicles.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import MarkerArray

from mlkm_assoc.association_node import AssociationNode
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from mlkm_ros.params import ParameterError
from road_sensor_msgs.msg import (
    Detection,
    EpisodeInfo,
    SensorLayout,
    Track,
    TrackArray,
)

pytestmark = pytest.mark.ros

IDS = [10, 11, 12, 13]
NAMES = ['s_a', 's_b', 's_c', 's_d']
POS = [100.0, 200.0, 300.0, 400.0]
LANES = [2, 2, 2, 2]
LAYOUT = Layout(500.0, np.array(POS), np.array(IDS), tuple(NAMES))
#: vehicle -> (entry time [s], speed [m/s], lane, length [m]); 50 s apart: certain answer.
VEHICLES = {0: (5.0, 40.0, 0, 4.5), 1: (55.0, 25.0, 1, 12.0), 2: (105.0, 50.0, 0, 4.0)}


def passages(offset: float = 0.0) -> list[tuple[int, int, float, int, int, float]]:
    """(sensor index, stamp ns, velocity, vehicle, lane, length) in stamp order."""
    out = []
    for vehicle, (t0, v, lane, length) in VEHICLES.items():
        for s, p in enumerate(POS):
            out.append((s, conv.seconds_to_ns(offset + t0 + p / v), v, vehicle, lane, length))
    return sorted(out, key=lambda r: r[1])


class Harness:
    """The node under test plus a test node publishing inputs and collecting outputs."""

    def __init__(self, context, spin_until, **params) -> None:
        overrides = [Parameter('diagnostics_period', value=0.2)]
        overrides += [Parameter(k, value=v) for k, v in params.items()]
        self.node = AssociationNode(context=context, parameter_overrides=overrides)
        self.test = Node('stream_test', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.test)
        self.spin_until = spin_until
        self.layout_pub = self.test.create_publisher(
            SensorLayout, qos.LAYOUT_TOPIC, qos.LAYOUT_QOS
        )
        self.det_pubs = [
            self.test.create_publisher(Detection, qos.detections_topic(n), qos.DETECTIONS_QOS)
            for n in NAMES
        ]
        self.tracks: list[TrackArray] = []
        self.diag: dict[str, str] = {}
        self.test.create_subscription(
            TrackArray, qos.TRACKS_TOPIC, self.tracks.append, qos.TRACKS_QOS
        )
        self.test.create_subscription(
            DiagnosticArray, qos.DIAGNOSTICS_TOPIC, self._on_diag, qos.DIAGNOSTICS_QOS
        )

    def _on_diag(self, msg: DiagnosticArray) -> None:
        values = conv.diagnostics_values(msg, self.node.get_fully_qualified_name())
        if values is not None:
            self.diag = values

    def wait(self, predicate, timeout: float = 60.0) -> None:
        assert self.spin_until(self.executor, predicate, timeout), 'timed out'

    def start(self) -> None:
        self.layout_pub.publish(
            conv.layout_to_msg(LAYOUT, conv.seconds_to_ns(1.0), lane_counts=LANES)
        )
        self.wait(lambda: self.node.assembler.layout is not None)
        self.wait(lambda: all(p.get_subscription_count() >= 1 for p in self.det_pubs))

    def detect(self, s, stamp_ns, velocity, lane=-1, length=math.nan, **kw) -> None:
        self.det_pubs[s].publish(
            conv.detection_to_msg(
                kw.get('sensor_id', IDS[s]),
                stamp_ns,
                kw.get('position', POS[s]),
                velocity,
                lane,
                length,
            )
        )

    def latest(self, mode: int = TrackArray.MODE_STREAM) -> dict[tuple, tuple[int, int]]:
        """(sensor id, lane, stamp ns) -> (track id or -1, status or -1), the latest state
        of every detection published in ``mode``."""
        out = {}
        for msg in self.tracks:
            if msg.mode != mode:
                continue
            d = conv.stream_tracks_from_msg(msg)
            for i in range(d.labels.size):
                key = (int(d.sensor_ids[i]), int(d.lanes[i]), int(d.stamps_ns[i]))
                out[key] = (int(d.labels[i]), int(d.status[i]))
        return out

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.test.destroy_node()


@pytest.fixture
def harness(rclpy_context, spin_until):
    made = []

    def make(**params) -> Harness:
        h = Harness(rclpy_context, spin_until, **params)
        made.append(h)
        return h

    yield make
    for h in made:
        h.close()


def test_stream_without_episode_info_gets_final_tracks(harness) -> None:
    h = harness(lag=5.0)  # mode auto, and no /road/episode publisher anywhere
    h.start()
    rows = passages()
    for s, ns, v, _, lane, length in rows:
        h.detect(s, ns, v, lane, length)
        if ns == rows[0][1]:  # duplicate (within the lag: recognised)
            h.detect(s, ns, v, lane, length)
    bad_ns = conv.seconds_to_ns(30.0)
    h.detect(0, bad_ns, math.nan)  # nan_velocity
    h.detect(1, bad_ns, 15.0, sensor_id=99)  # unknown_sensor
    h.detect(2, bad_ns, 15.0, position=250.0)  # position_mismatch
    h.detect(3, bad_ns, 15.0, lane=2)  # lane_out_of_range: the station has lanes 0 and 1
    keys = {(IDS[s], lane, ns): vehicle for s, ns, _, vehicle, lane, _ in rows}
    # The road falls quiet: after lag seconds of wall time every track is FINAL.
    last_ns = max(ns for _, ns, *_ in rows)
    h.wait(
        lambda: (
            h.tracks
            and conv.time_to_ns(h.tracks[-1].committed_until) > last_ns
            and all(h.latest().get(k, (-1, -1))[1] == Track.STATUS_FINAL for k in keys)
        )
    )
    for msg in h.tracks:
        assert (msg.mode, msg.episode_id, msg.final) == (TrackArray.MODE_STREAM, 0, False)
    latest = h.latest()
    assert set(latest) == set(keys)  # nothing lost, nothing invented
    track_of = {}
    for k, vehicle in keys.items():
        track_of.setdefault(vehicle, set()).add(latest[k][0])
    assert all(len(t) == 1 for t in track_of.values())  # one track per vehicle
    assert len({next(iter(t)) for t in track_of.values()}) == 3  # three distinct tracks
    # The last state of each track: its four detections in road order, with their values.
    final = {}
    for msg in h.tracks:
        for t in msg.tracks:
            final[t.track_id] = t
    for vehicle, (_, v, lane, length) in VEHICLES.items():
        t = final[next(iter(track_of[vehicle]))]
        assert list(t.sensor_ids) == IDS and list(t.positions) == POS
        assert list(t.lanes) == [lane] * 4 and list(t.lengths) == [length] * 4
        assert list(t.velocities) == [v] * 4 and t.status == Track.STATUS_FINAL
    # committed_until never goes down and, after the flush, covers every detection
    cu = [conv.time_to_ns(m.committed_until) for m in h.tracks]
    assert cu == sorted(cu) and cu[-1] > last_ns
    # final tracks left the working set, and the node forgot their detections
    h.wait(lambda: h.diag.get('stream.working_set') == '0')
    assert h.diag['stream.tracks_final'] == '3'
    d = h.diag
    assert (d['mode'], d['mode_setting']) == ('stream', 'auto')
    assert (d['received'], d['accepted'], d['rejected']) == ('17', '12', '5')
    for reason in (
        'nan_velocity',
        'unknown_sensor',
        'position_mismatch',
        'lane_out_of_range',
        'duplicate',
    ):
        assert d[f'rejected.{reason}'] == '1', reason
    assert d['stream.detections_held'] == '0'
    assert float(d['stream.latency_p95']) >= 0.0 and d['stream.latency_count'] == '12'
    # the latency's parts (node -> tracker queue, reorder hold, tracker, publication) are
    # each shorter than the whole
    for part in ('queue', 'hold', 'tracker', 'publish'):
        assert 0.0 <= float(d[f'stream.latency_{part}_p50']) <= float(d['stream.latency_max'])
    assert d['incompatible_publishers'] == '0'


def test_publishers_that_cannot_reach_the_node_are_reported(harness) -> None:
    """The detection subscriptions carry no QoS event handlers; the node finds the best-effort
    publishers on two sensor topics (its subscriptions are reliable) from the graph, and
    reports each once."""
    h = harness(mode='stream')
    h.start()
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    for name in NAMES[:2]:
        h.test.create_publisher(Detection, qos.detections_topic(name), best_effort)
    h.wait(lambda: h.diag.get('incompatible_publishers') == '2')
    h.spin_until(h.executor, lambda: False, 2.5)  # the graph is looked at again: no repeats
    assert h.diag['incompatible_publishers'] == '2'

    # the good publishers still deliver
    s, ns, v, _, lane, length = passages()[0]
    h.detect(s, ns, v, lane, length)
    h.wait(lambda: len(h.latest()) == 1)


def test_auto_switches_to_episodes_when_an_episode_publisher_appears(harness) -> None:
    h = harness(lag=30.0, method='mlkm', segment_size=2, completion_timeout=1.0)
    h.start()
    rows = passages()
    first = [r for r in rows if r[3] == 0]
    for s, ns, v, _, lane, length in first:
        h.detect(s, ns, v, lane, length)
    stream_keys = {(IDS[r[0]], r[4], r[1]) for r in first}
    h.wait(lambda: set(h.latest()) == stream_keys)
    assert h.node._modes.mode == 'stream'
    # A source with episodes appears: the stream is flushed (its track FINAL) and the
    # node works in episodes mode.
    episode_pub = h.test.create_publisher(EpisodeInfo, qos.EPISODE_TOPIC, qos.EPISODE_QOS)
    h.wait(lambda: h.node._modes.mode == 'episodes')
    h.wait(lambda: {v[1] for v in h.latest().values()} == {Track.STATUS_FINAL})
    offset = 1000.0
    ep_rows = passages(offset)
    start, end = ep_rows[0][1], ep_rows[-1][1] + conv.seconds_to_ns(20.0)
    episode_pub.publish(conv.episode_started_msg(0, 3, start, end, conv.seconds_to_ns(2.0)))
    h.wait(lambda: h.node.assembler.knows_episode(0))
    for s, ns, v, _, lane, length in ep_rows:
        h.detect(s, ns, v, lane, length)
    counts = {i: 3 for i in IDS}
    episode_pub.publish(conv.episode_ended_msg(0, 3, start, end, conv.seconds_to_ns(3.0), counts))
    h.wait(lambda: any(m.final for m in h.tracks))
    final = next(m for m in h.tracks if m.final)
    assert final.mode == TrackArray.MODE_EPISODES and final.episode_id == 0
    ids, stamps, _, labels = conv.tracks_from_msg(final)
    label = dict(zip(zip(ids.tolist(), stamps.tolist()), labels.tolist()))
    truth = {(IDS[s], ns): vehicle for s, ns, _, vehicle, _, _ in ep_rows}
    assert set(label) == set(truth)
    groups = {}
    for k, vehicle in truth.items():
        groups.setdefault(vehicle, set()).add(label[k])
    assert all(len(g) == 1 for g in groups.values()) and len(set(label.values())) == 3
    h.wait(lambda: h.diag.get('mode') == 'episodes')
    assert h.diag['mode_switches'] == '1'


@pytest.mark.parametrize('name,value', [('mode', 'sometimes'), ('stream_method', 'nope')])
def test_refused_stream_parameters(rclpy_context, name, value) -> None:
    with pytest.raises(ParameterError, match=name):
        AssociationNode(context=rclpy_context, parameter_overrides=[Parameter(name, value=value)])


def _drawn(array: MarkerArray) -> tuple[str, int, dict[int, tuple[float, bool, str]]]:
    """(status text, stamp ns, marker id -> (x, solid, text) of each track drawn)."""
    texts = {m.id: m.text for m in array.markers if m.ns == 'track_ids'}
    tracks = {
        m.id: (round(m.pose.position.x, 6), m.color.a == 1.0, texts[m.id])
        for m in array.markers
        if m.ns == 'tracks'
    }
    status = next((m.text for m in array.markers if m.ns == 'status'), '')
    return status, conv.time_to_ns(array.markers[0].header.stamp), tracks


def _consumer_view(arrays: list[TrackArray], now_ns: int) -> tuple[str, dict]:
    """What the markers should show after ``arrays``, merged as a stream consumer does
    (latest state per track id), at stamp ``now_ns``: a track moves on from its last station
    at its last speed, up to the next station; a FINAL one that got there is gone."""
    latest: dict[int, Track] = {}
    for msg in arrays:
        for t in msg.tracks:
            latest[t.track_id] = t
    cu = conv.time_to_ns(arrays[-1].committed_until)
    out = {}
    for track_id, t in latest.items():
        if not len(t.positions):
            continue
        last, stamp = t.positions[-1], conv.time_to_ns(t.stamps[-1])
        nxt = next((p for p in POS if p > last), LAYOUT.road_length)
        x = min(last + t.velocities[-1] * max(0, now_ns - stamp) / 1e9, nxt)
        if t.status == Track.STATUS_FINAL and x >= nxt:
            continue
        committed = stamp < cu
        text = str(track_id) + ('' if committed else ' (revisable)')
        out[track_id % 2**31] = (round(x, 6), committed, text)
    status = 'stream' + (f', committed until {cu / 1e9:.1f} s' if cu > 0 else '')
    return status, out


def test_markers_tell_committed_from_revisable_tracks(harness) -> None:
    """Stream mode's /mlkm/markers: the published tracks merged by id, each placed along the
    road; one whose links are all committed is solid, one whose links may still be revised
    translucent with "(revisable)" after its id."""
    h = harness(mode='stream', lag=1.0, markers_rate=50.0)
    arrays: list[MarkerArray] = []
    h.test.create_subscription(MarkerArray, qos.MARKERS_TOPIC, arrays.append, qos.MARKERS_QOS)
    h.start()
    # vehicle A (12.5 m/s) passes stations a, b, c at 100, 108, 116 s; the road falls quiet
    # and is flushed (after the lag, wall time): A's links are committed, A is FINAL but is
    # still on its way to station d
    for s, t in ((0, 100), (1, 108), (2, 116)):
        h.detect(s, conv.seconds_to_ns(t), 12.5, 0, 4.5)
    h.wait(lambda: any(m.committed_until.sec >= 116 for m in h.tracks))
    # vehicle B (25 m/s) passes a and b at 118 and 122 s: its links may still be revised
    for s, t in ((0, 118), (1, 122)):
        h.detect(s, conv.seconds_to_ns(t), 25.0, 0, 4.5)
    h.wait(lambda: any(_drawn(a)[0] == 'stream, committed until 122.0 s' for a in arrays))
    h.wait(lambda: any(m.committed_until.sec >= 122 for m in h.tracks))  # its TrackArray too
    both = []
    for array in arrays:
        status, now_ns, drawn = _drawn(array)
        # the tracks the node had when it drew this: some prefix of what it published
        views = [('', {})]  # before the first TrackArray
        views += [_consumer_view(h.tracks[:k], now_ns) for k in range(1, len(h.tracks) + 1)]
        assert (status, drawn) in views, (status, drawn)
        if {solid for _, solid, _ in drawn.values()} == {True, False}:
            both.append(drawn)
    assert both, [_drawn(a) for a in arrays]  # one array showed a committed and a revisable
    # A solid between stations c and d (6 s at 12.5 m/s past c), B translucent at b
    assert any(sorted(d.values())[1][:2] == (375.0, True) for d in both)
    assert any(sorted(d.values())[0][:2] == (200.0, False) for d in both)


def test_quiet_flush_flushes_a_quiet_road_long_before_the_lag(harness) -> None:
    """A log replayed faster than real time: ``quiet_flush`` 0.5 s, lag 600 s. The road's
    tracks become FINAL half a second of quiet wall time after the last detection (with the
    flush after the lag, they would stay open for ten minutes)."""
    h = harness(mode='stream', lag=600.0, quiet_flush=0.5)
    h.start()
    rows = passages()
    for s, ns, v, _, lane, length in rows:
        h.detect(s, ns, v, lane, length)
    keys = {(IDS[s], lane, ns) for s, ns, _, _, lane, _ in rows}
    h.wait(
        lambda: all(h.latest().get(k, (-1, -1))[1] == Track.STATUS_FINAL for k in keys),
        timeout=120.0,
    )
    assert conv.time_to_ns(h.tracks[-1].committed_until) > max(ns for _, ns, *_ in rows)
    assert len({h.latest()[k][0] for k in keys}) == 3  # one track per vehicle
    h.wait(lambda: h.diag.get('stream.quiet_flush') == '0.5')
    assert h.diag['stream.lag'] == '600.0'
