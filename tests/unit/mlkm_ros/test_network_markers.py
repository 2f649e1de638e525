"""/mlkm/markers on a road network without a graph: where stations and tracks lie in the
network's plane, the message built from them, and a network track ordered by stamp."""

from __future__ import annotations

import math

import numpy as np
import pytest
from visualization_msgs.msg import Marker

from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_ros.conversions import stream_tracks_to_msg, tracks_to_msg
from mlkm_ros.markers import TrackView
from mlkm_ros.network_markers import build_network_markers, network_geometry

# a diverge: 'in' runs east 1000 m, 'left' turns north from its end, 'right' goes south-east
NET = RoadNetwork(
    links=(
        RoadLink(0, 'in', 1000.0, 2, ((0.0, 0.0), (1000.0, 0.0))),
        RoadLink(1, 'left', 500.0, 1, ((1000.0, 0.0), (1000.0, 250.0), (1000.0, 500.0))),
        RoadLink(2, 'right', 500.0, 1, ((1000.0, 0.0), (1300.0, -400.0))),
    ),
    connections=((0, 1), (0, 2)),
    station_ids=np.array([10, 11, 12, 13]),
    station_names=('a', 'b', 'c', 'd'),
    station_links=np.array([0, 0, 1, 2]),
    station_offsets=np.array([200.0, 800.0, 100.0, 250.0]),
)


def test_stations_stand_on_their_links_and_tracks_move_to_the_next_clamp():
    g = network_geometry(NET)
    assert np.allclose(g.station_xy, [(200, 0), (800, 0), (1000, 100), (1150, -200)])
    assert g.limits == (800.0, 1000.0, 500.0, 500.0)  # next station on the link, or its end
    assert g.size == pytest.approx(1300.0 / 250.0)  # the extent: 1300 m by 900 m
    # seen at 'a' (200 m) at t = 10 s, 20 m/s: at t = 20 s 400 m along 'in'
    assert g.place(0, 10.0, 20.0, 20.0) == pytest.approx((400.0, 0.0, False))
    # ... and waits at 'b' (800 m) once there
    assert g.place(0, 10.0, 20.0, 100.0) == pytest.approx((800.0, 0.0, True))
    # seen at 'd' 250 m along 'right' (5/3 of the way per 100 m): after 5 s at 20 m/s 350 m
    x, y, reached = g.place(3, 0.0, 20.0, 5.0)
    assert (x, y) == pytest.approx((1000.0 + 0.7 * 300.0, -0.7 * 400.0)) and not reached
    assert g.place(3, 0.0, math.nan, 5.0)[:2] == pytest.approx((1150.0, -200.0))


def test_a_network_without_shapes_has_no_geometry():
    plain = RoadNetwork(
        links=tuple(RoadLink(k.link_id, k.name, k.length, k.lanes) for k in NET.links),
        connections=NET.connections,
        station_ids=NET.station_ids,
        station_names=NET.station_names,
        station_links=NET.station_links,
        station_offsets=NET.station_offsets,
    )
    assert network_geometry(plain) is None


def test_the_message_draws_links_stations_and_tracks():
    g = network_geometry(NET)
    tracks = [TrackView(7, 400.0, None, 0.0), TrackView(8, 1000.0, False, 100.0)]
    msg = build_network_markers(g, 20 * 10**9, tracks, 'stream')
    by_ns: dict[str, list[Marker]] = {}
    for m in msg.markers[1:]:
        by_ns.setdefault(m.ns, []).append(m)
    assert msg.markers[0].action == Marker.DELETEALL
    assert all(m.header.frame_id == 'road' for m in msg.markers)
    links = by_ns['links']
    assert [[(p.x, p.y) for p in m.points] for m in links] == [
        [(0.0, 0.0), (1000.0, 0.0)],
        [(1000.0, 0.0), (1000.0, 250.0), (1000.0, 500.0)],
        [(1000.0, 0.0), (1300.0, -400.0)],
    ]
    poles = by_ns['stations']
    assert np.allclose([(m.pose.position.x, m.pose.position.y) for m in poles], g.station_xy)
    assert [m.text for m in by_ns['station_names']] == ['a', 'b', 'c', 'd']
    dots = by_ns['tracks']
    assert [(m.id, m.pose.position.x, m.pose.position.y) for m in dots] == [
        (7, 400.0, 0.0),
        (8, 1000.0, 100.0),
    ]
    assert dots[0].color.a == 1.0 and dots[1].color.a < 1.0  # revisable: faint
    assert [m.text for m in by_ns['track_ids']] == ['7', '8 (revisable)']
    assert by_ns['status'][0].text == 'stream'


def test_a_network_track_is_ordered_by_stamp():
    # a vehicle seen at 'b' (800 m along 'in') and then at 'c' (100 m along 'left')
    ids, stamps, v, pos = [11, 12], [30 * 10**9, 45 * 10**9], [20.0, 18.0], [800.0, 100.0]
    kwargs = dict(episode_id=1, method='assignment', final=True, segments_done=1,
                  segments_total=1, sensor_ids=np.array(ids), stamps_ns=np.array(stamps),
                  velocities=np.array(v), positions=np.array(pos), labels=np.array([4, 4]),
                  solve_time=0.0, stamp_ns=0)  # fmt: skip
    road = tracks_to_msg(**kwargs).tracks[0]
    assert list(road.sensor_ids) == [12, 11]  # by position: meaningless across links
    network = tracks_to_msg(**kwargs, by_stamp=True).tracks[0]
    assert list(network.sensor_ids) == [11, 12] and list(network.positions) == [800.0, 100.0]
    rows = [(11, 30 * 10**9, 20.0, 800.0, -1, math.nan), (12, 45 * 10**9, 18.0, 100.0, -1, 0.0)]
    stream = stream_tracks_to_msg(method='assignment', tracks=[(4, 1, rows)], unassigned=[],
                                  committed_until_ns=0, solve_time=0.0, stamp_ns=0,
                                  by_stamp=True)  # fmt: skip
    assert list(stream.tracks[0].sensor_ids) == [11, 12]
