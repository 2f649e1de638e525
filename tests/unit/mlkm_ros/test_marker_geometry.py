"""/mlkm/markers without a graph: where a track is placed, its colour, and the message built
from a hand-made scene."""

from __future__ import annotations

import math

import pytest
from visualization_msgs.msg import Marker

from mlkm_ros.markers import (
    ID_MODULUS,
    Scene,
    TrackView,
    build_markers,
    next_station,
    track_colour,
    track_position,
)

POSITIONS = [100.0, 200.0, 300.0, 400.0]
ROAD = 500.0


def test_next_station_is_strictly_past_and_the_road_end_after_the_last() -> None:
    assert next_station(POSITIONS, 100.0, ROAD) == 200.0
    assert next_station(POSITIONS, 150.0, ROAD) == 200.0
    assert next_station(POSITIONS, 50.0, ROAD) == 100.0
    assert next_station(POSITIONS, 400.0, ROAD) == ROAD


@pytest.mark.parametrize(
    'now,expected',
    [
        (20.0, 200.0),  # at its last detection: at the station
        (24.0, 240.0),  # 4 s at 10 m/s past station 200
        (29.5, 295.0),
        (30.0, 300.0),  # reaches the next station ...
        (45.0, 300.0),  # ... and waits there for its next detection
        (10.0, 200.0),  # a stamp before its last detection: never behind its station
    ],
)
def test_track_moves_from_its_last_station_and_stops_at_the_next(now, expected) -> None:
    limit = next_station(POSITIONS, 200.0, ROAD)
    assert track_position(200.0, 20.0, 10.0, now, limit) == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize('speed', [math.nan, math.inf, 0.0, -5.0])
def test_a_speed_that_is_no_speed_keeps_the_track_at_its_station(speed) -> None:
    assert track_position(200.0, 20.0, speed, 30.0, 300.0) == 200.0


def test_colour_is_stable_per_id_and_neighbours_differ() -> None:
    assert track_colour(7) == track_colour(7)
    big = 1_764_210_000_000_000  # a stream-mode id: run start [us] + n
    assert track_colour(big) == track_colour(big)
    for a, b in ((0, 1), (1, 2), (big, big + 1)):
        hue_gap = max(abs(x - y) for x, y in zip(track_colour(a), track_colour(b)))
        assert hue_gap > 0.2, (a, b)
    assert all(0.0 <= c <= 1.0 for c in track_colour(big))


def test_scene_to_marker_array() -> None:
    big = 3 * ID_MODULUS + 5
    scene = Scene(
        stamp_ns=24_000_000_000,
        road_length=ROAD,
        positions=POSITIONS,
        names=['a', 'b', 'c', 'd'],
        detections=[[(0, 10.0), (1, 12.0)], [], [], [(-1, 20.0)]],
        tracks=[TrackView(3, 240.0), TrackView(big, 310.0, committed=False)],
        status='episode 0, 1/2 segments',
    )
    markers = build_markers(scene).markers
    assert markers[0].action == Marker.DELETEALL
    assert all(m.header.frame_id == 'road' for m in markers)
    assert all((m.header.stamp.sec, m.header.stamp.nanosec) == (24, 0) for m in markers)
    by_ns: dict[str, list[Marker]] = {}
    for m in markers[1:]:
        by_ns.setdefault(m.ns, []).append(m)
    (road,) = by_ns['road']
    assert [(p.x, p.y) for p in road.points] == [(0.0, 0.0), (ROAD, 0.0)]
    assert [m.pose.position.x for m in by_ns['stations']] == POSITIONS
    assert [m.id for m in by_ns['stations']] == [0, 1, 2, 3]
    assert [m.text for m in by_ns['station_names']] == ['a', 'b', 'c', 'd']
    assert [(m.id, len(m.points)) for m in by_ns['detections']] == [(0, 2), (3, 1)]
    tracks = {m.id: m for m in by_ns['tracks']}
    assert sorted(tracks) == [3, 5]
    assert tracks[3].pose.position.x == 240.0 and tracks[3].color.a == 1.0
    assert tracks[5].pose.position.x == 310.0 and tracks[5].color.a < 1.0
    r, g, b = track_colour(3)
    assert (tracks[3].color.r, tracks[3].color.g, tracks[3].color.b) == pytest.approx((r, g, b))
    texts = {m.id: m.text for m in by_ns['track_ids']}
    assert texts == {3: '3', 5: f'{big} (revisable)'}
    assert by_ns['status'][0].text == 'episode 0, 1/2 segments'
    for m in markers:
        p = m.pose.position
        assert all(math.isfinite(v) for v in (p.x, p.y, p.z, m.scale.x, m.scale.y, m.scale.z))
