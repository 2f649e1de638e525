"""Association on road networks (``mlkm_core.network_assoc``) on hand-made junctions: tracks
through a diverge and a merge where the vehicles swap order, a vehicle held at a red light,
a vehicle that leaves at a junction, the single road as the one-link network, and the hops
between stations with their distances computed by hand; the one-road tracking methods on a
network (per link, then the network model across the junctions)."""

from __future__ import annotations

import numpy as np
import pytest

from mlkm_core.associators import make_associator
from mlkm_core.layout_file import RoadLayout
from mlkm_core.metrics import accuracy
from mlkm_core.model.motion import MotionParams
from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_core.network_assoc import associate_network, network_hops
from mlkm_core.network_assoc.fit import calibrate_and_link
from mlkm_core.network_assoc.junctions import JunctionModel
from mlkm_core.network_assoc.linking import solve
from mlkm_core.simulator import SimConfig, simulate
from mlkm_core.types import Detections


def network(links, connections, stations, exits=()) -> RoadNetwork:
    """links: (id, length [m]); stations: (link, position [m]), ids 0.. in order."""
    return RoadNetwork(
        links=tuple(RoadLink(i, f'l{i}', length) for i, length in links),
        connections=tuple(connections),
        station_ids=np.arange(len(stations)),
        station_names=tuple(f's{k}' for k in range(len(stations))),
        station_links=np.array([s[0] for s in stations]),
        station_offsets=np.array([s[1] for s in stations], float),
        exits=tuple(exits),
    )


def detections(vehicles: list[list[tuple[int, float, float]]]) -> Detections:
    """vehicles[v]: its (station, stamp [s], speed [m/s]) passages; target v."""
    rows = [(s, t, v, k) for k, passes in enumerate(vehicles) for s, t, v in passes]
    s, t, v, k = (np.array(c) for c in zip(*rows, strict=True))
    return Detections(s.astype(np.int64), t.astype(float), v.astype(float), k.astype(np.int64))


def same_tracks(labels: np.ndarray, target: np.ndarray) -> bool:
    """Each vehicle is one track of its own (the labels partition the detections as the
    targets do)."""
    pairs = set(zip(labels.tolist(), target.tolist(), strict=True))
    return (
        len(pairs) == len(set(labels.tolist())) == len(set(target.tolist())) and min(labels) >= 0
    )


#: the network methods that track (``gmlkm`` is the baseline)
TRACKING = ('assignment', 'multiframe', 'mlkm_robust')


def diverge() -> RoadNetwork:
    # link 0 (1000 m) splits into links 1 and 2 (600 m each)
    return network([(0, 1000.0), (1, 600.0), (2, 600.0)], [(0, 1), (0, 2)],
                   [(0, 300.0), (0, 800.0), (1, 200.0), (2, 300.0)])  # fmt: skip


def test_the_hops_of_a_diverge_with_their_distances_and_junctions():
    hops = network_hops(diverge(), max_skip=1)
    got = {(int(a), int(b), int(k)): (float(x), t)
           for a, b, k, x, t in zip(hops.src, hops.dst, hops.skipped, hops.distance,
                                    hops.turns, strict=True)}  # fmt: skip
    assert got == {
        (0, 1, 0): (500.0, ()),
        (1, 2, 0): (400.0, ((0, 1),)),  # 200 m to the end of link 0, 200 m on link 1
        (1, 3, 0): (500.0, ((0, 2),)),
        (0, 2, 1): (900.0, ((0, 1),)),  # over station 1, unseen
        (0, 3, 1): (1000.0, ((0, 2),)),
    }
    # an entry lies before station 0 only; exits after stations 2 and 3 only
    assert hops.before.tolist() == [0, 1, 2, 2] and hops.after.tolist() == [2, 1, 0, 0]


def test_two_vehicles_that_swap_order_at_a_diverge_keep_their_tracks():
    # A (20 m/s) leads at both stations of link 0 and turns onto link 1; B (25 m/s) passes A
    # after the diverge on link 2 and is seen first there
    a = [(0, 0.0, 20.0), (1, 25.0, 20.0), (2, 45.0, 20.0)]
    b = [(0, 2.0, 25.0), (1, 22.1, 25.0), (3, 42.1, 25.0)]
    d = detections([a, b])
    for method in ('assignment', 'gmlkm', 'multiframe', 'mlkm_robust'):
        labels = associate_network(diverge(), d, method)
        assert same_tracks(labels, d.target), (method, labels)


def test_two_vehicles_that_swap_order_at_a_merge_keep_their_tracks():
    # links 0 and 1 merge into link 2; the vehicle from link 1 reaches the merge first
    net = network([(0, 800.0), (1, 500.0), (2, 1000.0)], [(0, 2), (1, 2)],
                  [(0, 400.0), (1, 300.0), (2, 300.0)])  # fmt: skip
    a = [(0, 10.0, 20.0), (2, 10.0 + 700 / 20, 20.0)]  # 400 + 300 m: arrives at 45 s
    b = [(1, 30.0, 25.0), (2, 30.0 + 500 / 25, 25.0)]  # 200 + 300 m: arrives at 50 s
    d = detections([a, b])
    for method in TRACKING:
        labels = associate_network(net, d, method)
        assert same_tracks(labels, d.target), (method, labels)


def signal_traffic(n: int = 40) -> tuple[RoadNetwork, Detections]:
    """A signal between links 0 and 1 (cycle 60 s, red for the first 30 s); vehicles every
    6 s at 15 m/s, seen 200 m before the stop line and 100 m after it; a vehicle held at the
    red leaves at green, 2 s after the one before it in the queue."""
    net = network([(0, 400.0), (1, 400.0)], [(0, 1)], [(0, 200.0), (1, 100.0)])
    rows, leave = [], -np.inf
    for k in range(n):
        t0 = 6.0 * k
        arrive = t0 + 200.0 / 15.0
        green = arrive if arrive % 60.0 >= 30.0 else arrive - arrive % 60.0 + 30.0
        leave = max(arrive, green, leave + 2.0)
        speed = 15.0 if leave == arrive else 10.0  # accelerating from the stop line
        rows.append([(0, t0, 15.0), (1, leave + 100.0 / speed, speed)])
    return net, detections(rows)


def test_a_vehicle_held_at_a_red_light_keeps_its_track():
    net, d = signal_traffic()
    hops = network_hops(net, 2)
    labels, model = calibrate_and_link(net, hops, d)
    assert same_tracks(labels, d.target), accuracy(labels, d.target)
    # the data taught it the signal: its cycle, its green (from 30 s on; the last vehicle
    # through on green leaves at 55.4 s) and the queue's headway; without a junction model
    # the held vehicles are cut off their tracks or linked wrong
    signals = model.junctions.signals
    assert signals.cycle[(0, 1)] == pytest.approx(60.0, abs=0.5)
    start, length = signals.green[(0, 1)]
    assert start == pytest.approx(30.0, abs=1.0) and 24.0 < length < 30.0, (start, length)
    assert signals.approaches[0].headway == 2.0
    blind, _ = solve(hops, d, model.motion, JunctionModel(model.junctions.shares))
    assert accuracy(blind, d.target).accuracy < 0.9


def test_a_vehicle_that_leaves_at_a_junction_ends_its_track_there():
    # link 2 has no station and ends in an exit: C leaves there; D, 3 s behind it, goes on
    # to link 1 and is seen there when C would have been
    net = network([(0, 1000.0), (1, 600.0), (2, 300.0)], [(0, 1), (0, 2)],
                  [(0, 300.0), (0, 800.0), (1, 200.0)])  # fmt: skip
    c = [(0, 0.0, 20.0), (1, 25.0, 20.0)]
    e = [(0, 3.0, 20.0), (1, 28.0, 20.0), (2, 48.0, 20.0)]
    d = detections([c, e])
    for method in TRACKING:
        labels = associate_network(net, d, method)
        assert same_tracks(labels, d.target), (method, labels)


@pytest.mark.parametrize('method', ['multiframe', 'mlkm_robust'])
def test_a_one_road_method_on_a_one_link_network_is_that_method(method):
    # one link, no junction: the method on its link is all there is, and nothing is joined
    ds = simulate(SimConfig(n_targets=30, n_sensors=8, false_alarm_rate=0.02), 5)
    net = RoadNetwork.single_road(RoadLayout(ds.layout))
    on_network = associate_network(net, ds.detections, method)
    on_road = make_associator(method).associate(ds.layout, ds.detections, ds.n_targets)
    assert np.array_equal(on_network >= 0, on_road >= 0)
    assert len(set(zip(on_network.tolist(), on_road.tolist()))) == len(set(on_road.tolist()))
    assert accuracy(on_network, ds.detections.target).accuracy > 0.9


def test_a_one_road_method_on_a_network_joins_its_link_tracks_across_the_junction():
    # three vehicles on link 0 (three stations) go on to link 1 (two stations); C is missed at
    # the last station of link 0, so its link-track there ends one station early
    net = network([(0, 1500.0), (1, 1000.0)], [(0, 1)],
                  [(0, 300.0), (0, 800.0), (0, 1300.0), (1, 200.0), (1, 700.0)])  # fmt: skip
    x = [300.0, 800.0, 1300.0, 1700.0, 2200.0]  # along the way [m]
    vehicles = []
    for t0, v, seen in ((0.0, 20.0, range(5)), (3.0, 25.0, range(5)), (5.0, 22.0, (0, 1, 3, 4))):
        vehicles.append([(s, t0 + (x[s] - 300.0) / v, v) for s in seen])
    d = detections(vehicles)
    for method in TRACKING:
        labels = associate_network(net, d, method)
        assert same_tracks(labels, d.target), (method, labels)


def test_a_single_road_as_its_one_link_network_links_as_assignment_does():
    ds = simulate(SimConfig(n_targets=30, n_sensors=8), 3)
    net = RoadNetwork.single_road(RoadLayout(ds.layout))
    on_network = accuracy(associate_network(net, ds.detections), ds.detections.target)
    on_road = accuracy(
        make_associator('assignment').associate(ds.layout, ds.detections, ds.n_targets),
        ds.detections.target,
    )
    assert on_network.accuracy >= on_road.accuracy - 0.01 and on_network.accuracy > 0.95


def test_unknown_methods_and_stations_are_refused():
    d = detections([[(0, 0.0, 20.0), (7, 30.0, 20.0)]])
    with pytest.raises(ValueError, match='station indexes outside'):
        associate_network(diverge(), d)
    with pytest.raises(ValueError, match="unknown network method 'nope'"):
        associate_network(diverge(), d, 'nope')
    none = detections([[(0, 0.0, 20.0)]]).subset(np.zeros(0, np.int64))
    assert associate_network(diverge(), none).size == 0


def test_generic_parameters_link_where_too_few_links_fit_anything():
    # two vehicles: no fit has links enough; the generic model still links each one whole
    a = [(0, 0.0, 20.0), (1, 25.0, 20.0), (2, 45.0, 20.0)]
    d = detections([a])
    labels, model = calibrate_and_link(diverge(), network_hops(diverge(), 2), d)
    assert model.motion.sigma == MotionParams().sigma
    assert same_tracks(labels, d.target)
