"""Stream mode's reliability, in process: detections that arrive before any layout wait for
it in mode ``auto`` (they decide no mode), a ``method`` given for stream mode runs its window
solves, and the track ids of a tracker run never meet those of an earlier run.

The hand-made road and the harness are those of ``test_stream_association``.
"""

from __future__ import annotations

import pytest
from rclpy.serialization import deserialize_message
from test_stream_association import IDS, LAYOUT, VEHICLES, Harness, passages

from mlkm_assoc.association_params import stream_associator
from mlkm_assoc.stream_state import TrackerSettings, TrackerState, encode_tracks
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import EpisodeInfo, Track, TrackArray

pytestmark = pytest.mark.ros


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


def held_before_layout(node) -> int:
    """Detections the node holds because no layout is known, wherever it holds them."""
    d = node.diagnostics()
    return sum(
        int(d.get(name, 0) or 0)
        for name in ('held_before_mode', 'held_before_layout', 'stream.held_before_layout')
    )


def test_detections_before_any_layout_wait_for_it_in_auto(harness) -> None:
    """A source with episodes whose detections reach the node before its layout (and before
    its /road/episode publisher is discovered): the detections wait, the layout comes with
    the episode publisher, and they all end up in the episode's final association; no stream
    track is ever published."""
    h = harness(method='mlkm', segment_size=2, completion_timeout=1.0)  # mode auto
    # before the layout the node subscribes to the sensor topics that exist
    h.wait(lambda: all(p.get_subscription_count() >= 1 for p in h.det_pubs))
    rows = passages(1000.0)
    for s, ns, v, _, lane, length in rows:
        h.detect(s, ns, v, lane, length)
    h.wait(lambda: held_before_layout(h.node) == len(rows))
    episode_pub = h.test.create_publisher(EpisodeInfo, qos.EPISODE_TOPIC, qos.EPISODE_QOS)
    h.wait(lambda: h.node.count_publishers(h.node.resolve_topic_name(qos.EPISODE_TOPIC)) >= 1)
    h.start()  # the layout; the mode is episodes (decided once the publisher was known)
    start, end = rows[0][1], rows[-1][1] + conv.seconds_to_ns(20.0)
    episode_pub.publish(conv.episode_started_msg(0, 3, start, end, conv.seconds_to_ns(2.0)))
    counts = {i: 3 for i in IDS}
    episode_pub.publish(conv.episode_ended_msg(0, 3, start, end, conv.seconds_to_ns(3.0), counts))
    h.wait(lambda: any(m.final for m in h.tracks))
    assert not [m for m in h.tracks if m.mode == TrackArray.MODE_STREAM]
    final = next(m for m in h.tracks if m.final)
    assert final.mode == TrackArray.MODE_EPISODES and final.episode_id == 0
    ids, stamps, _, labels = conv.tracks_from_msg(final)
    label = dict(zip(zip(ids.tolist(), stamps.tolist()), labels.tolist()))
    truth = {(IDS[s], ns): vehicle for s, ns, _, vehicle, _, _ in rows}
    assert set(label) == set(truth)  # nothing lost
    groups: dict[int, set[int]] = {}
    for k, vehicle in truth.items():
        groups.setdefault(vehicle, set()).add(label[k])
    assert all(len(g) == 1 for g in groups.values()) and len(set(label.values())) == 3
    assert h.node._modes.mode == 'episodes' and h.node._modes.switches == 0
    assert held_before_layout(h.node) == 0


@pytest.mark.parametrize(
    'given,expected',
    [
        ({}, 'multiframe'),
        ({'method'}, 'mlkm'),
        ({'stream_method'}, 'assignment'),
        ({'method', 'stream_method'}, 'assignment'),
    ],
)
def test_stream_associator_follows_the_parameters_given(given, expected) -> None:
    method = 'mlkm'
    stream_method = 'assignment' if 'stream_method' in given else 'multiframe'
    assert stream_associator(method, stream_method, given) == expected


def test_method_given_runs_stream_window_solves(harness) -> None:
    """``-p method:=mlkm`` in stream mode: the window solves run mlkm (the TrackArrays say
    so), and they still find the three vehicles."""
    h = harness(mode='stream', method='mlkm', lag=5.0)
    assert h.node._modes.stream.settings.method == 'mlkm'
    h.start()
    rows = passages()
    for s, ns, v, _, lane, length in rows:
        h.detect(s, ns, v, lane, length)
    keys = {(IDS[s], lane, ns): vehicle for s, ns, _, vehicle, lane, _ in rows}
    h.wait(lambda: all(h.latest().get(k, (-1, -1))[1] == Track.STATUS_FINAL for k in keys))
    assert {m.method for m in h.tracks} == {'mlkm'}
    latest = h.latest()
    tracks: dict[int, set[int]] = {}
    for k, vehicle in keys.items():
        tracks.setdefault(vehicle, set()).add(latest[k][0])
    assert all(len(t) == 1 for t in tracks.values()) and len(set(latest.values())) == 3
    assert h.node.diagnostics()['stream.method'] == 'mlkm'


def test_track_ids_of_a_later_run_never_meet_an_earlier_runs() -> None:
    """Two tracker states one after the other (a node and the same node restarted, or a new
    layout) number the same traffic: their runs increase and their ids are disjoint, and
    the first message of a run announces it."""
    settings = TrackerSettings('multiframe', 5.0, 5, 0)
    items = [
        ('det', k, s, IDS[s], ns, v, float(LAYOUT.positions[s]), lane, length, 0.0)
        for k, (s, ns, v, _, lane, length) in enumerate(passages())
    ]

    def run_ids(state: TrackerState) -> tuple[int, set[int]]:
        announce = deserialize_message(state.set_layout(LAYOUT, (), ()).data, TrackArray)
        assert (announce.mode, len(announce.tracks), announce.run) == (
            TrackArray.MODE_STREAM,
            0,
            state.run,
        )
        msgs = [state.push_batch(items), state.flush(0.0)]
        ids = set()
        for answer in msgs:
            msg = deserialize_message(answer.data, TrackArray)
            assert msg.run == state.run
            ids |= {t.track_id for t in msg.tracks}
        return state.run, ids

    run1, ids1 = run_ids(TrackerState(settings, encode_tracks))
    run2, ids2 = run_ids(TrackerState(settings, encode_tracks))
    assert run1 < run2 and len(ids1) == len(ids2) == len(VEHICLES)
    assert not ids1 & ids2
    assert all(run1 <= i < run2 for i in ids1) and all(i >= run2 for i in ids2)
    assert max(ids2) < 2**53  # exact in a float (JSON, numpy float64)
    # a new layout in the same process starts a later run too
    state = TrackerState(settings, encode_tracks)
    first, ids_a = run_ids(state)
    flushed = deserialize_message(state.set_layout(LAYOUT, (), ()).data, TrackArray)
    assert flushed.run == first and state.run > max(ids_a)
