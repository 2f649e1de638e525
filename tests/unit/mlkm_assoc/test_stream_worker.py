"""Stream mode's tracker process and reorder buffer without ROS graph: nothing is lost when far
more detections are queued than one batch takes, and topics drained round-robin come out in
stamp order.
"""

from __future__ import annotations

import math

import numpy as np
from rclpy.serialization import deserialize_message

from mlkm_assoc.reorder import ReorderBuffer
from mlkm_assoc.stream_state import TrackerSettings
from mlkm_assoc.stream_worker import MAX_BATCH, TrackerProcess
from mlkm_core.streaming import StreamConfig, StreamTracker
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from road_sensor_msgs.msg import Track, TrackArray

NS = conv.NS_PER_S
POS = [100.0, 200.0, 300.0]
LAYOUT = Layout(400.0, np.array(POS), np.array([5, 6, 7]))


def test_a_backlog_larger_than_a_batch_loses_nothing() -> None:
    """Vehicles every 2 s at 20 m/s (5 s between stations): 3 * n detections queued at once,
    more than MAX_BATCH, all before the process answers anything."""
    n = MAX_BATCH  # vehicles
    items, key = [], 0
    for i in range(n):
        for s, p in enumerate(POS):
            stamp_ns = int((10.0 + 2.0 * i + p / 20.0) * NS)
            items.append((stamp_ns, s, key))
            key += 1
    items.sort()
    proc = TrackerProcess(TrackerSettings('multiframe', 15.0, 5, 0))
    try:
        proc.put(('layout', LAYOUT, (), ()))
        for rank, (stamp_ns, s, k) in enumerate(items):
            det = ('det', k, s, 5 + s, stamp_ns, 20.0, POS[s], -1, math.nan, rank * 1e-6)
            proc.put(det)
        proc.put(('flush', 1.0))
        proc.put(None)
        latest: dict[tuple[int, int], tuple[int, int]] = {}
        pushed = 0
        while (answer := proc.get(timeout=120.0)) is not None:
            pushed += len(answer.received_at)
            assert answer.error is None, answer.error
            if answer.data is None:
                continue
            msg = deserialize_message(answer.data, TrackArray)
            d = conv.stream_tracks_from_msg(msg)
            for i in range(d.labels.size):
                latest[(int(d.sensor_ids[i]), int(d.stamps_ns[i]))] = (
                    int(d.labels[i]),
                    int(d.status[i]),
                )
    finally:
        proc.close()
    assert pushed == len(items)
    assert len(latest) == len(items)
    assert {status for _, status in latest.values()} == {Track.STATUS_FINAL}
    tracks: dict[int, set] = {}
    for (sensor, _stamp), (label, _) in latest.items():
        tracks.setdefault(label, set()).add(sensor)
    assert len(tracks) == n and all(len(t) == 3 for t in tracks.values())


def test_round_robin_backlog_comes_out_in_stamp_order() -> None:
    """Three topics with a backlog, taken one message per topic in turn: vehicles every 2 s,
    10 s of travel between stations, so the i-th message of the downstream topic is stamped
    up to 20 s after the upstream one's; the buffer holds the ahead ones and releases stamp
    order."""
    buf = ReorderBuffer(3, margin=0.5, wait=0.05, max_hold=1.0)
    per_topic = [[2.0 * i + 10.0 * s for i in range(20)] for s in range(3)]
    out, now = [], 0.0
    for i in range(20):
        for s in range(3):
            now += 0.001  # an executor cycle
            buf.add((per_topic[s][i], s), s, per_topic[s][i], now)
            out.extend(buf.release(now))
    assert len(out) < 60  # the last ones wait for the slow topics...
    assert [x[0] for x in out] == sorted(x[0] for x in out)
    now += 0.1  # ...until every topic has been quiet for `wait`
    out.extend(buf.release(now))
    stamps = [x[0] for x in out]
    assert len(out) == 60 and stamps == sorted(stamps)
    assert buf.released_by_timeout == 0


def test_paced_topics_pass_at_once() -> None:
    """Three topics delivering in stamp order at 50 times real time (a detection every 0.3 s
    of stamp time, 6 ms of wall time): once each topic has delivered twice (its first
    detection cannot tell whether it lags), nothing is held."""
    buf = ReorderBuffer(3, margin=0.5, wait=0.05, max_hold=1.0)
    out = []
    for i in range(60):
        stamp = 0.3 * i
        now = stamp / 50.0
        buf.add((stamp, i % 3), i % 3, stamp, now)
        released = [x[0] for x in buf.release(now)]
        out += released
        if i >= 6:
            assert released == [stamp]
    assert out == [0.3 * i for i in range(60)]
    assert len(buf) == 0 and buf.released_by_timeout == 0


def test_window_solves_beside_the_tracker_commit_as_the_core_tracker() -> None:
    """Vehicles every 3 s at 20 m/s for 60 s of stamp time, a false alarm among them, through
    the tracker process (its window solves in the solver process): commits reach 55 s (the
    last due boundary, 70 s, minus the lag) before any flush, and the committed labels after
    the flush equal the core tracker's, solving inline, on the same detections."""
    rows = []
    for i in range(20):
        rows += [(s, 3.0 * i + p / 20.0, 20.0) for s, p in enumerate(POS)]
    rows.append((1, 31.3, 35.0))  # a false alarm
    rows.sort(key=lambda r: r[1])
    core = StreamTracker(LAYOUT, StreamConfig(method='assignment', lag=15.0))
    committed = {}
    for key, (s, stamp, v) in enumerate(rows):
        committed.update(core.push(key, s, stamp, v).committed.tolist())
    committed.update(core.flush().committed.tolist())
    expected = {(5 + rows[k][0], round(rows[k][1] * NS)): t for k, t in committed.items()}

    proc = TrackerProcess(TrackerSettings('assignment', 15.0, 5, 0))
    latest: dict[tuple[int, int], int] = {}
    stats: dict = {}

    def take(answer) -> None:
        assert answer.error is None, answer.error
        stats.update(answer.stats)
        if answer.data is not None:
            d = conv.stream_tracks_from_msg(deserialize_message(answer.data, TrackArray))
            for i in range(d.labels.size):
                latest[(int(d.sensor_ids[i]), int(d.stamps_ns[i]))] = int(d.labels[i])

    try:
        proc.put(('layout', LAYOUT, (), ()))
        for key, (s, stamp, v) in enumerate(rows):
            det = ('det', key, s, 5 + s, round(stamp * NS), v, POS[s], -1, math.nan, key * 1e-6)
            proc.put(det)
        proc.put(('tick', 10.0))  # the node's clock: the reorder buffer lets everything go
        committed_until = -math.inf
        while committed_until < 55.0:
            answer = proc.get(timeout=120.0)
            assert answer is not None and not answer.flushed
            take(answer)
            committed_until = answer.committed_until
        proc.put(('flush', 11.0))
        proc.put(None)
        while (answer := proc.get(timeout=120.0)) is not None:
            take(answer)
    finally:
        proc.close()
    assert len(latest) == len(rows) == len(expected)
    assert stats['tracker.solves'] == core.stats()['solves'] >= 7
    assert stats['tracker.executor_errors'] == 0

    def partition(labels):
        out = {}
        for det, t in labels.items():
            if t >= 0:
                out.setdefault(t, set()).add(det)
        return sorted(sorted(g) for g in out.values())

    assert partition(latest) == partition(expected)
    assert len(partition(expected)) == 20
    assert sorted(k for k, t in latest.items() if t < 0) == [(6, round(31.3 * NS))]
