"""Order of passage along a one-lane link (``network_assoc.order``): which hops keep their
vehicles' order, crossed links of two vehicles on such a hop exchanged by hand-made costs,
and a queue's scatter that crosses two tracks on two lanes but not on one."""

from __future__ import annotations

import numpy as np
from test_network_assoc import detections

from mlkm_core.model.motion import MotionParams
from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_core.network_assoc import network_hops
from mlkm_core.network_assoc.junctions import JunctionModel
from mlkm_core.network_assoc.linking import solve
from mlkm_core.network_assoc.order import keep_order, pair_costs


def one_link(lanes: int) -> RoadNetwork:
    # one link of 1000 m, stations at 100 m and 300 m
    return RoadNetwork(
        links=(RoadLink(0, 'l0', 1000.0, lanes),),
        connections=(),
        station_ids=np.arange(2),
        station_names=('s0', 's1'),
        station_links=np.array([0, 0]),
        station_offsets=np.array([100.0, 300.0]),
    )


def test_only_hops_along_one_lane_with_nothing_on_the_way_keep_order():
    # link 0 (one lane) with stations 0, 1, 2; link 1 (two lanes) with 3, 4; link 2
    # (lanes unknown) with 5, 6; an exit on link 0 between stations 1 and 2
    net = RoadNetwork(
        links=(RoadLink(0, 'l0', 900.0, 1), RoadLink(1, 'l1', 500.0, 2),
               RoadLink(2, 'l2', 500.0)),
        connections=((0, 1), (1, 2)),
        station_ids=np.arange(7),
        station_names=tuple(f's{k}' for k in range(7)),
        station_links=np.array([0, 0, 0, 1, 1, 2, 2]),
        station_offsets=np.array([100.0, 300.0, 700.0, 100.0, 300.0, 100.0, 300.0]),
        exits=((0, 500.0),),
    )  # fmt: skip
    hops = network_hops(net, max_skip=1)
    kept = {(int(a), int(b)) for a, b, k in zip(hops.src, hops.dst, hops.in_order) if k}
    # 1 -> 2 passes the exit, 0 -> 2 an unseen station, 2 -> 3 a junction; link 1 has two
    # lanes (overtaking), link 2 an unknown number
    assert kept == {(0, 1)}


def test_crossed_neighbours_are_exchanged_unless_the_model_objects():
    # three vehicles pass station 0 at 0, 1, 2 s; the links reach station 1 at 12, 10, 11 s
    net = one_link(1)
    hops = network_hops(net, max_skip=0)
    d = detections([[(0, 0.0, 10.0)], [(0, 1.0, 10.0)], [(0, 2.0, 10.0)],
                    [(1, 10.0, 10.0)], [(1, 11.0, 10.0)], [(1, 12.0, 10.0)]])  # fmt: skip
    a, b, hop = np.array([0, 1, 2]), np.array([5, 3, 4]), np.zeros(3, np.int64)

    def costs(objection: float):
        # every pair costs 1 nat, but 2 -> 5 (the last vehicle to the last detection)
        # costs ``objection`` more
        keys = np.array([x * 6 + y for x in range(3) for y in range(3, 6)])
        c = np.ones(keys.size)
        c[keys == 2 * 6 + 5] += objection
        return pair_costs(6, keys, c)

    # exchanges within -log(0.01) = 4.6 nats: sorted into 0 -> 3, 1 -> 4, 2 -> 5
    assert keep_order(hops.in_order, d, a, b, hop, costs(1.0)).tolist() == [3, 4, 5]
    # 2 -> 5 costs 10 nats more: 0 -> 3 and 1 -> 5 are exchanged, 2 -> 4 stays
    assert keep_order(hops.in_order, d, a, b, hop, costs(10.0)).tolist() == [3, 5, 4]
    # a pair the gate did not offer is never made
    no_03 = pair_costs(6, np.array([0 * 6 + 5, 1 * 6 + 3, 2 * 6 + 4]), np.ones(3))
    assert keep_order(hops.in_order, d, a, b, hop, no_03).tolist() == [5, 3, 4]
    # on a hop that may overtake nothing changes
    assert keep_order(np.zeros(1, bool), d, a, b, hop, costs(1.0)).tolist() == [5, 3, 4]


def test_a_queues_scatter_crosses_two_tracks_on_two_lanes_but_not_on_one():
    # A (0 s, 10 m/s) and B (2 s) reach station 1 at 24 s (12 m/s) and 25 s (6 m/s), held
    # in a queue whose time lost scatters by 5 s: by their costs alone (0.53 + 3.06 nats
    # against 2.87 + 0.17) the links cross, which on one lane no vehicle can do
    d = detections([[(0, 0.0, 10.0), (1, 24.0, 12.0)], [(0, 2.0, 10.0), (1, 25.0, 6.0)]])
    queue = JunctionModel(hops={0: (0.0, 25.0)})
    for lanes, expected in ((2, [0, 1, 1, 0]), (1, [0, 0, 1, 1])):
        labels, links = solve(network_hops(one_link(lanes), 1), d, MotionParams(), queue)
        assert labels.tolist() == expected
        assert links.hop.tolist() == [0, 0]
