"""Road networks (``mlkm_core.network``): hand-made junctions, the ways between stations with
their distances computed by hand, the single road as its simple case, and every refusal."""

from __future__ import annotations

import numpy as np
import pytest

from mlkm_core.layout_file import RoadLayout
from mlkm_core.network import RoadLink, RoadNetwork, StationStep
from mlkm_core.types import Layout


def net(links, connections, stations, entries=(), exits=()) -> RoadNetwork:
    """links: (id, length [m]); stations: (id, link, position [m]), named s<id>."""
    return RoadNetwork(
        links=tuple(RoadLink(i, f'l{i}', length) for i, length in links),
        connections=tuple(connections),
        station_ids=np.array([s[0] for s in stations]),
        station_names=tuple(f's{s[0]}' for s in stations),
        station_links=np.array([s[1] for s in stations]),
        station_offsets=np.array([s[2] for s in stations], float),
        entries=tuple(entries),
        exits=tuple(exits),
    )


def steps(found: list[StationStep]) -> list[tuple]:
    return [(s.index, s.distance_m, s.links, s.may_leave, s.may_join) for s in found]


def diverge() -> RoadNetwork:
    # the contract's example: 0 splits into a main road 1 and a ramp 2
    return net([(0, 800.0), (1, 900.0), (2, 300.0)], [(0, 1), (0, 2)],
               [(0, 0, 200.0), (1, 1, 500.0), (2, 2, 150.0)])  # fmt: skip


def test_a_diverge_two_ways_on_from_the_station_before_it():
    d = diverge()
    assert d.n_stations == 3
    # to the ramp station: 600 m to the end of link 0, 150 m on link 2
    assert steps(d.successors(0)) == [(2, 750.0, (2,), False, False),
                                      (1, 1100.0, (1,), False, False)]  # fmt: skip
    assert d.successors(1) == [] and d.successors(2) == []  # they leave at the link ends
    assert d.entries == ((0, 0.0),)  # implicit: nothing leads into link 0
    assert d.exits == ((1, 900.0), (2, 300.0))  # implicit: nothing leaves links 1 and 2
    assert steps(d.first_stations()) == [(0, 200.0, (), False, False)]
    assert not d.is_single_road()
    with pytest.raises(
        ValueError, match=r'not a single road: link 0 branches into links \[1, 2\]'
    ):
        d.road_layout()


def test_a_merge_two_stations_lead_to_one():
    m = net([(0, 500.0), (1, 400.0), (2, 1000.0)], [(0, 2), (1, 2)],
            [(10, 0, 100.0), (11, 1, 300.0), (12, 2, 50.0)])  # fmt: skip
    assert steps(m.successors(0)) == [(2, 450.0, (2,), False, False)]
    assert steps(m.successors(1)) == [(2, 150.0, (2,), False, False)]
    assert m.entries == ((0, 0.0), (1, 0.0)) and m.exits == ((2, 1000.0),)
    assert steps(m.first_stations()) == [(0, 100.0, (), False, False),
                                         (1, 300.0, (), False, False)]  # fmt: skip
    with pytest.raises(ValueError, match='link 2 is where 2 links merge'):
        m.road_layout()


def test_a_link_without_station_between_two_stations():
    chain = [(0, 300.0), (1, 250.0), (2, 400.0)]
    stations = [(0, 0, 100.0), (1, 2, 40.0)]
    n = net(chain, [(0, 1), (1, 2)], stations)
    # 200 m to the end of link 0, all 250 m of link 1, 40 m on link 2
    assert steps(n.successors(0)) == [(1, 490.0, (1, 2), False, False)]
    assert n.is_single_road()
    road = n.road_layout()
    assert road.layout.road_length == 950.0
    assert road.layout.positions.tolist() == [100.0, 590.0]
    assert (road.entries, road.exits) == ((), ())
    # an exit and an entry on the link between: a vehicle may leave, another may join
    ramps = net(chain, [(0, 1), (1, 2)], stations, entries=[(1, 200.0), (0, 0.0)],
                exits=[(1, 100.0)])  # fmt: skip
    assert steps(ramps.successors(0)) == [(1, 490.0, (1, 2), True, True)]
    assert ramps.entries == ((0, 0.0), (1, 200.0))  # sorted by link order, then position
    assert ramps.exits == ((1, 100.0), (2, 400.0))  # link 2's end still implicit
    assert ramps.road_layout().entries == (500.0,) and ramps.road_layout().exits == (400.0,)


def test_a_ring_with_one_station_leads_back_to_it():
    ring = net([(0, 100.0), (1, 200.0), (2, 300.0)], [(0, 1), (1, 2), (2, 0)],
               [(5, 0, 50.0)], entries=[(1, 0.0)], exits=[(2, 100.0)])  # fmt: skip
    # 50 m to the end of link 0, round links 1 and 2, 50 m on link 0
    assert steps(ring.successors(0)) == [(0, 600.0, (1, 2, 0), True, True)]
    assert ring.entries == ((1, 0.0),) and ring.exits == ((2, 100.0),)  # nothing implicit
    assert steps(ring.first_stations()) == [(0, 550.0, (2, 0), True, False)]
    assert not ring.is_single_road()
    with pytest.raises(ValueError, match='its links form a cycle'):
        ring.road_layout()


def test_a_cycle_without_stations_ends_and_the_shortest_way_counts():
    # link 1 and 2 go round without a station; link 2 has an exit; b on link 3
    loop = net([(0, 100.0), (1, 200.0), (2, 50.0), (3, 100.0)],
               [(0, 1), (1, 2), (2, 1), (1, 3)], [(0, 0, 50.0), (1, 3, 10.0)],
               exits=[(2, 25.0)])  # fmt: skip
    # shortest: 50 + 200 + 10; the way round 1 -> 2 -> 1 passes the exit on link 2
    assert steps(loop.successors(0)) == [(1, 260.0, (1, 3), True, False)]


def test_of_two_ways_the_shorter_gives_the_distance_both_the_exits():
    diamond = net([(0, 100.0), (1, 500.0), (2, 200.0), (3, 100.0)],
                  [(0, 1), (0, 2), (1, 3), (2, 3)], [(0, 0, 90.0), (1, 3, 20.0)],
                  exits=[(1, 250.0)])  # fmt: skip
    assert steps(diamond.successors(0)) == [(1, 230.0, (2, 3), True, False)]


def test_explicit_entries_replace_the_implicit_one_of_their_link():
    n = net([(0, 1000.0)], [], [(0, 0, 100.0), (1, 0, 200.0), (2, 0, 300.0)],
            entries=[(0, 150.0)], exits=[(0, 300.0)])  # fmt: skip
    assert n.entries == ((0, 150.0),) and n.exits == ((0, 300.0),)
    # station 0 stands before the only entry: no vehicle can reach it first
    assert steps(n.first_stations()) == [(1, 50.0, (), False, False)]
    assert steps(n.successors(1)) == [(2, 100.0, (), False, False)]
    assert n.successors(2) == []  # nothing beyond; the exit at 300 m lies after station 2


def test_entry_and_exit_at_a_station_lie_before_and_after_it():
    n = net([(0, 500.0)], [], [(0, 0, 0.0), (1, 0, 200.0), (2, 0, 400.0)],
            entries=[(0, 0.0), (0, 400.0)], exits=[(0, 200.0), (0, 500.0)])  # fmt: skip
    assert steps(n.first_stations()) == [(0, 0.0, (), False, False),
                                         (2, 0.0, (), False, False)]  # fmt: skip
    assert steps(n.successors(0)) == [(1, 200.0, (), False, False)]
    assert steps(n.successors(1)) == [(2, 200.0, (), True, True)]


def test_single_road_and_back():
    layout = Layout(1000.0, np.array([100.0, 400.0, 800.0]), np.array([7, 8, 9]), ('a', 'b', 'c'))
    road = RoadLayout(layout, np.array([3, 0, 2]), (250.0,), (600.0,))
    n = RoadNetwork.single_road(road)
    assert [(k.link_id, k.name, k.length, k.lanes) for k in n.links] == [(0, 'link_0', 1000.0, 0)]
    assert n.entries == ((0, 0.0), (0, 250.0)) and n.exits == ((0, 600.0), (0, 1000.0))
    assert n.station_ids.tolist() == [7, 8, 9] and n.station_lanes.tolist() == [3, 0, 2]
    assert steps(n.successors(0)) == [(1, 300.0, (), False, True)]
    assert steps(n.successors(1)) == [(2, 400.0, (), True, False)]
    assert n.successors(2) == []
    assert n.is_single_road()
    back = n.road_layout()
    assert back.layout.positions.tolist() == [100.0, 400.0, 800.0]
    assert back.layout.names == ('a', 'b', 'c') and back.layout.road_length == 1000.0
    assert back.lanes.tolist() == [3, 0, 2]
    assert (back.entries, back.exits) == ((250.0,), (600.0,))
    assert RoadNetwork.single_road(back) == n


def test_networks_compare_by_content():
    assert diverge() == diverge()
    other = net([(0, 800.0), (1, 900.0), (2, 300.0)], [(0, 1), (0, 2)],
                [(0, 0, 200.0), (1, 1, 500.0), (2, 2, 151.0)])  # fmt: skip
    assert diverge() != other


L2 = [(0, 100.0), (1, 100.0)]


@pytest.mark.parametrize(
    ('build', 'words'),
    [
        (lambda: net([(0, 1.0), (0, 2.0)], [], [(0, 0, 0.0)]), 'link id 0 is used twice'),
        (lambda: net(L2, [(0, 5)], [(0, 0, 0.0)]), 'connection 0 -> 5: link 5 is not in'),
        (lambda: net(L2, [(1, 1)], [(0, 0, 0.0)]), 'connection 1 -> 1 joins a link to itself'),
        (lambda: net(L2, [(0, 1), (0, 1)], [(0, 0, 0.0)]), "connection '0 -> 1' is used twice"),
        (lambda: net(L2, [], []), 'at least one station'),
        (lambda: net([], [], [(0, 0, 0.0)]), 'at least one RoadLink'),
        (
            lambda: net(L2, [], [(0, 1, 100.5)]),
            r'station 0 \(s0\): position 100.5 m is off link 1',
        ),
        (lambda: net(L2, [], [(0, 2, 1.0)]), r'station 0 \(s0\): link 2 is not in the network'),
        (lambda: net(L2, [], [(0, 0, 5.0), (1, 0, 5.0)]), 'another station stands on link 0 at 5'),
        (lambda: net(L2, [], [(0, 0, 5.0), (0, 1, 5.0)]), 'station id 0 is used twice'),
        (lambda: net(L2, [], [(0, 0, 5.0)], entries=[(3, 0.0)]), 'entry on link 3: link 3 is not'),
        (lambda: net(L2, [], [(0, 0, 5.0)], exits=[(1, 101.0)]), 'exit on link 1 at 101 m: off'),
        (
            lambda: net(L2, [], [(0, 0, 5.0)], entries=[(1, 2.0), (1, 2.0)]),
            'entry on link 1 at 2 m is given twice',
        ),
        (lambda: RoadLink(0, 'a b', 1.0), "link 0: name 'a b' is not a topic name token"),
        (lambda: RoadLink(1, 'x', 0.0), r'link 1: length must be finite and > 0 m'),
        (lambda: RoadLink(-1, 'x', 1.0), 'link id must be >= 0'),
    ],
)
def test_bad_networks_are_refused_with_the_reason(build, words):
    with pytest.raises(ValueError, match=words):
        build()


def test_station_names_unique_and_arrays_parallel():
    with pytest.raises(ValueError, match="station name 's' is used twice"):
        RoadNetwork((RoadLink(0, 'a', 10.0),), (), np.array([0, 1]), ('s', 's'),
                    np.array([0, 0]), np.array([1.0, 2.0]))  # fmt: skip
    with pytest.raises(ValueError, match='differ in length'):
        RoadNetwork((RoadLink(0, 'a', 10.0),), (), np.array([0, 1]), ('s', 't'),
                    np.array([0]), np.array([1.0, 2.0]))  # fmt: skip


def test_successors_of_a_station_that_does_not_exist():
    with pytest.raises(IndexError, match=r'station index 3 outside \[0, 3\)'):
        diverge().successors(3)


@pytest.mark.parametrize(
    ('links', 'connections', 'reason'),
    [
        ([(0, 10.0), (1, 10.0)], [], 'it has 2 separate roads'),
        (
            [(0, 10.0), (1, 10.0), (2, 10.0), (3, 10.0)],
            [(0, 1), (2, 3), (3, 2)],
            'some of its links form a cycle apart from the road',
        ),
    ],
)
def test_what_is_not_a_single_road_says_why(links, connections, reason):
    n = net(links, connections, [(0, 0, 5.0)])
    assert not n.is_single_road()
    with pytest.raises(ValueError, match=f'not a single road: {reason}'):
        n.road_layout()


def test_a_chain_with_stations_at_one_junction_is_no_road_layout():
    # the end of link 0 and the start of link 1 are one place of the road
    n = net([(0, 10.0), (1, 10.0)], [(0, 1)], [(0, 0, 10.0), (1, 1, 0.0)])
    assert n.is_single_road()
    assert steps(n.successors(0)) == [(1, 0.0, (1,), False, False)]
    with pytest.raises(ValueError, match='strictly increasing'):
        n.road_layout()


def grid(n: int) -> RoadNetwork:
    """An n x n grid of junctions 100 m apart, a link each way between neighbours, no U-turn;
    a station in the middle (50 m) of every fourth link, the other links without one."""
    ends = {}
    for i in range(n):
        for j in range(n):
            for di, dj in ((0, 1), (1, 0), (0, -1), (-1, 0)):
                if 0 <= i + di < n and 0 <= j + dj < n:
                    ends[len(ends)] = ((i, j), (i + di, j + dj))
    turns = [
        (k, m)
        for k, (a, b) in ends.items()
        for m, (c, d) in ends.items()
        if b == c != d and d != a
    ]
    return net([(k, 100.0) for k in ends], turns, [(k, k, 50.0) for k in ends if k % 4 == 0])


def test_a_grid_every_way_ends_at_the_first_station_and_measures_its_links():
    g = grid(6)
    allowed = set(g.connections)
    for i in range(g.n_stations):
        found = g.successors(i)
        assert found and len({s.index for s in found}) == len(found)
        for s in found:
            # 50 m to the end of the own link, 100 m per link between, 50 m on the last one
            assert s.distance_m == 100.0 * len(s.links)
            start = int(g.station_links[i])
            assert all(p in allowed for p in zip((start, *s.links), s.links))
            assert int(g.station_links[s.index]) == s.links[-1]
            assert all(g.stations_along[k] == [] for k in s.links[:-1])  # passes no station
