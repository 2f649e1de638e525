"""Shards of a long road (``mlkm_core.shards``): regions, the hand-off desk, the merge, and
the offline shards against one tracker on real traffic."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mlkm_core.loops import even_positions, virtual_loops
from mlkm_core.metrics import accuracy
from mlkm_core.shards.desk import HandoffDesk
from mlkm_core.shards.merge import CONFIRMED, FINAL, TrackMerge
from mlkm_core.shards.regions import MAX_SHARDS, shard_track_id, split_road
from mlkm_core.shards.sharded import associate_sharded
from mlkm_core.streaming import StreamConfig, StreamTracker
from mlkm_core.trajectories import read_trajectories

DATA = Path(__file__).resolve().parents[3] / 'data' / 'ngsim_i80' / 'i80_trajectories_a.csv.gz'
NS = 1_000_000_000


def det(sensor: int, stamp: float, v: float = 10.0, lane: int = 0):
    return (sensor, lane, round(stamp * NS), v)


# --- regions ---------------------------------------------------------------------------------
def test_regions_split_the_stations_evenly_with_margins_on_both_sides() -> None:
    r = split_road(10, 3, margin=2)
    assert [x.own for x in r] == [(0, 1, 2), (3, 4, 5, 6), (7, 8, 9)]
    assert [x.margin for x in r] == [(), (1, 2), (5, 6)]
    assert [x.after for x in r] == [(3, 4), (7, 8), ()]
    assert [x.offered for x in r] == [(1, 2), (5, 6), ()]  # the next one's margin
    assert r[1].stations == (1, 2, 3, 4, 5, 6, 7, 8)


def test_regions_follow_the_load() -> None:
    loads = np.array([10, 10, 10, 10, 1, 1, 1, 1, 1, 1], float)
    r = split_road(10, 2, margin=1, loads=loads)
    assert r[0].own == (0, 1) and r[1].own[0] == 2  # half the load in two stations


@pytest.mark.parametrize(
    'args', [(5, 0), (5, 6), (5, 2, 0), (5, MAX_SHARDS + 1)], ids=['none', 'many', 'margin', 'max']
)
def test_regions_refuse_what_cannot_be_split(args) -> None:
    with pytest.raises(ValueError):
        split_road(*args)


def test_track_ids_name_their_shard_and_never_meet() -> None:
    ids = {shard_track_id(2048, n, k) for n in range(50) for k in range(3)}
    assert len(ids) == 150 and {i % MAX_SHARDS for i in ids} == {0, 1, 2}


# --- the desk --------------------------------------------------------------------------------
def _desk() -> HandoffDesk:
    """Shard 1 of a road with stations 0..5: margin 1, 2 (its own 3..5), nothing offered."""
    return HandoffDesk({1: 1, 2: 2}, (), horizon=60.0)


def test_a_vehicle_crossing_the_border_keeps_its_upstream_track() -> None:
    desk = _desk()
    desk.take_offers([(7, det(1, 10.0)), (7, det(2, 14.0))], upstream_until=20.0)
    out = desk.commit([(40, det(1, 10.0)), (40, det(2, 14.0)), (40, det(3, 18.0))], 19.0)
    assert out.accepts == [(7, 40)]
    assert desk.settled_until == 19.0


def test_two_vehicles_that_swap_order_at_the_border_are_continued_by_identity() -> None:
    """A (track 7) passes the last upstream station first, B (track 8) overtakes it right
    after: the local tracker has B's margin detection in its first track. Each local track
    continues the upstream track of its own margin detection, not the one in arrival order."""
    desk = _desk()
    a, b = det(2, 10.0, 20.0), det(2, 10.5, 30.0)
    desk.take_offers([(7, a), (8, b)], upstream_until=30.0)
    out = desk.commit([(50, b), (51, a), (50, det(3, 13.5, 30.0)), (51, det(3, 15.0, 20.0))], 20.0)
    assert sorted(out.accepts) == [(7, 51), (8, 50)]


def test_the_choice_waits_for_the_upstream_commit_and_then_for_nothing_else() -> None:
    desk = _desk()
    out = desk.commit([(40, det(2, 14.0)), (40, det(3, 18.0))], 19.0)
    assert out.accepts == [] and desk.pending == 1
    assert desk.settled_until == 18.0  # the link at 18 s waits for its continuation
    desk.take_offers([], upstream_until=12.0)  # not yet past the margin detection
    assert desk.decide() == []
    desk.take_offers([(9, det(2, 14.0))], upstream_until=16.0)
    assert desk.decide() == [(9, 40)] and desk.settled_until == 19.0


def test_no_offer_means_a_new_track_and_an_offer_is_taken_once() -> None:
    desk = _desk()
    desk.take_offers([(7, det(2, 14.0))], upstream_until=30.0)
    # the upstream left 1@10 s unassigned: no offer; the track at 3 starts anew
    out = desk.commit([(40, det(1, 10.0)), (40, det(3, 13.0))], 20.0)
    assert out.accepts == []
    # two local tracks share upstream track 7's detections: the later margin detection wins
    out = desk.commit([(41, det(2, 14.0)), (41, det(3, 18.0))], 25.0)
    assert out.accepts == [(7, 41)]
    desk.take_offers([(7, det(1, 19.0))], upstream_until=40.0)
    out = desk.commit([(42, det(1, 19.0)), (42, det(3, 25.0))], 30.0)
    assert out.accepts == []  # track 7 was continued already


def test_a_first_own_detection_beyond_the_horizon_starts_anew() -> None:
    desk = HandoffDesk({2: 2}, (), horizon=5.0)
    desk.take_offers([(7, det(2, 10.0))], upstream_until=30.0)
    assert desk.commit([(40, det(2, 10.0)), (40, det(3, 16.0))], 20.0).accepts == []


def test_offers_are_the_committed_detections_at_the_offered_stations() -> None:
    desk = HandoffDesk({}, (4, 5), after_ids=(6,))
    out = desk.commit([(1, det(3, 1.0)), (1, det(4, 2.0)), (-1, det(5, 2.5)), (1, det(6, 3))], 9)
    assert out.offers == [(1, det(4, 2.0))]
    assert out.accepts == [] and desk.pending == 0  # the first shard continues nothing


# --- the merge -------------------------------------------------------------------------------
def row(sensor: int, stamp: float, position: float):
    return (sensor, round(stamp * NS), 10.0, position, 0, math.nan)


@pytest.mark.parametrize('handoff_first', [False, True], ids=['tracks_first', 'handoff_first'])
def test_the_merge_joins_pieces_under_the_upstream_id_in_either_order(handoff_first) -> None:
    m = TrackMerge(2, horizon=60.0)
    up, here = 0 * MAX_SHARDS + 0, 1 * MAX_SHARDS + 1
    out = m.add_tracks(0, 1, [(up, FINAL, [row(0, 1, 0), row(1, 2, 10)])], [], 5.0)
    assert out.tracks[0][1] == CONFIRMED  # shard 0 has not settled past it yet
    handoff = (m.add_handoff, (1, 1, [], [(up, here)], 5.0, 9.0))
    tracks = (m.add_tracks, (1, 1, [(here, FINAL, [row(2, 3, 20)])], [], 9.0))
    outs = [f(*a) for f, a in ([handoff, tracks] if handoff_first else [tracks, handoff])]
    outs.append(m.add_handoff(0, 1, [(up, 2.0)], [], 5.0, 2.0))
    merged = {t: (st, rows) for o in outs for t, st, rows in o.tracks}
    assert merged[up][1] == [row(0, 1, 0), row(1, 2, 10), row(2, 3, 20)]
    assert any(t == up and st == FINAL for t, st, _ in outs[-1].tracks)
    if not handoff_first:  # the downstream piece was shown on its own first: retired
        assert merged[here] == (FINAL, [])
        assert m.retired == 1


def test_a_continued_track_waits_for_the_piece_its_continuation_names() -> None:
    # shard 1's hand-off (the continuation) overtakes its TrackArray (another topic): the
    # upstream piece is final and settled, yet the track is not final until the downstream
    # piece is in, and then it carries both
    m = TrackMerge(2, horizon=60.0)
    up, here = 0 * MAX_SHARDS + 0, 1 * MAX_SHARDS + 1
    m.add_tracks(0, 1, [(up, FINAL, [row(0, 1, 0), row(1, 2, 10)])], [], 5.0)
    m.add_handoff(0, 1, [(up, 2.0)], [], 5.0, 2.0)
    out = m.add_handoff(1, 1, [], [(up, here)], 70.0, 70.0)
    assert [(t, s) for t, s, _ in out.tracks] == [(up, CONFIRMED)]
    out = m.add_tracks(1, 1, [(here, FINAL, [row(2, 3, 20)])], [], 70.0)
    assert out.tracks == [(up, FINAL, [row(0, 1, 0), row(1, 2, 10), row(2, 3, 20)])]


def test_a_continuation_of_an_ended_run_waits_for_nothing() -> None:
    # the downstream shard restarted before its piece reached the merge: that piece will
    # never come, and the upstream track ends as it stands
    m = TrackMerge(2, horizon=60.0)
    up, here = 0, 1 * MAX_SHARDS + 1
    m.add_tracks(0, 1, [(up, FINAL, [row(0, 1, 0)])], [], 5.0)
    m.add_handoff(0, 1, [(up, 1.0)], [], 5.0, 1.0)
    m.add_handoff(1, 1, [], [(up, here)], 3.0, 3.0)
    out = m.add_handoff(1, 2, [], [], 70.0, 70.0)  # a later run of shard 1
    assert [(t, s) for t, s, _ in out.tracks] == [(up, FINAL)]


def test_an_offer_nobody_takes_ends_the_track_after_the_horizon() -> None:
    m = TrackMerge(2, horizon=10.0)
    m.add_tracks(1, 1, [], [], 0.0)
    out = m.add_tracks(0, 1, [(0, FINAL, [row(0, 1, 0), row(1, 2, 10)])], [], 5.0)
    assert [(t, s) for t, s, _ in out.tracks] == [(0, CONFIRMED)]  # its shard not settled
    out = m.add_handoff(0, 1, [(0, 2.0)], [], 5.0, 20.0)
    assert not out.tracks  # still CONFIRMED (shard 1 may continue it): not published again
    out = m.add_handoff(1, 1, [], [], 11.0, 30.0)
    assert not out.tracks
    out = m.add_handoff(1, 1, [], [], 12.5, 30.0)
    assert [(t, s) for t, s, _ in out.tracks] == [(0, FINAL)]
    m.add_tracks(1, 1, [], [], 12.0)
    assert m.committed_until == 5.0  # shard 0 committed least


def test_a_restarted_shard_ends_its_earlier_pieces() -> None:
    m = TrackMerge(1, horizon=10.0)
    m.add_tracks(0, 1, [(1, CONFIRMED, [row(0, 1, 0)])], [], 0.0)
    out = m.add_tracks(0, 2, [], [], 0.0)  # a later run of shard 0
    assert [(t, s) for t, s, _ in out.tracks] == [(1, FINAL)]


# --- offline shards on real traffic ----------------------------------------------------------
@pytest.mark.slow
def test_shards_equal_one_tracker_on_real_traffic() -> None:
    """NGSIM I-80 through 20 virtual loops: 2 and 3 shards give one tracker's accuracy, and
    (almost) every vehicle crosses each border under one id."""
    traj = read_trajectories(DATA)
    ds = virtual_loops(traj, even_positions(20, 50, 450), closed=False).dataset
    d = ds.detections
    config = StreamConfig(method='multiframe', lag=30.0)
    one = StreamTracker(ds.layout, config)
    labels = np.full(len(d.stamp), -1)
    for i in np.lexsort((d.sensor_index, d.stamp)).tolist():
        up = one.push(i, int(d.sensor_index[i]), float(d.stamp[i]), float(d.velocity[i]),
                      int(d.lane[i]), float(d.length[i]))  # fmt: skip
        for k, t in up.committed.tolist():
            labels[k] = t
    for k, t in one.flush().committed.tolist():
        labels[k] = t
    expected = accuracy(labels, d.target).accuracy
    for n in (2, 3):
        r = associate_sharded(ds.layout, d, n, config)
        assert accuracy(r.labels, d.target).accuracy == pytest.approx(expected, abs=1e-12)
        vehicles = len(set(d.target[d.sensor_index == 19]) & set(d.target[d.sensor_index == 0]))
        assert min(r.accepted[1:]) >= vehicles - 2
