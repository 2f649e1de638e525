"""gmlkm, the G-MLKM baseline on a road network: hand-made junctions with hand-computed
labels (a diverge, a merge where vehicles swap order, a vehicle leaving at an exit, the
physical-rule gates), determinism, a label for every detection, and (slow) its accuracy on a
seeded SUMO interchange.

Tracks are numbered by their first stamp, so the expected labels are written out by hand.
Speeds are [m/s], stamps [s], positions [m]."""

import numpy as np
import pytest

from mlkm_core.metrics import accuracy
from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_core.network_assoc.gmlkm import MAX_WAIT_S, gmlkm_associate, link_tracks
from mlkm_core.types import Detections


def network(links, connections, stations, entries=(), exits=()):
    """links: {id: length [m]}; stations: [(link id, position along it [m])], station i has
    id i."""
    n = len(stations)
    return RoadNetwork(
        links=tuple(RoadLink(k, f'link_{k}', length) for k, length in links.items()),
        connections=tuple(connections),
        station_ids=np.arange(n, dtype=np.int64),
        station_names=tuple(f'sensor_{i}' for i in range(n)),
        station_links=np.array([k for k, _ in stations], np.int64),
        station_offsets=np.array([x for _, x in stations], float),
        station_lanes=np.zeros(n, np.int64),
        entries=tuple(entries),
        exits=tuple(exits),
    )


def detections(rows):
    """rows: (station index, stamp [s], speed [m/s], true vehicle)."""
    s, t, v, target = zip(*rows)
    return Detections(np.array(s), np.array(t, float), np.array(v, float), np.array(target))


# link 0 (300 m, stations 0 and 1) branches into link 1 (station 2) and link 2 (station 3)
DIVERGE = network(
    {0: 300.0, 1: 300.0, 2: 300.0},
    [(0, 1), (0, 2)],
    [(0, 100.0), (0, 200.0), (1, 100.0), (2, 100.0)],
)


def test_two_vehicles_diverge_onto_two_links():
    # A at 15 m/s: station 0 at 0 s, station 1 at 100/15 s, then 100 m to the end of link 0
    # and 100 m on link 2: station 3 at 100/15 + 200/15 = 20 s.
    # B at 30 m/s, 2 s behind A at station 0: station 1 at 2 + 100/30 s, then link 1:
    # station 2 at 2 + 300/30 = 12 s. Close in time, apart in speed: MLKM separates them on
    # link 0, and each tail's predicted arrival (t + 200 m / v) hits its own head exactly.
    rows = [
        (3, 20.0, 15.0, 0),  # A on link 2
        (0, 0.0, 15.0, 0),
        (1, 2.0 + 100 / 30, 30.0, 1),
        (2, 12.0, 30.0, 1),  # B on link 1
        (1, 100 / 15, 15.0, 0),
        (0, 2.0, 30.0, 1),
    ]
    labels = gmlkm_associate(DIVERGE, detections(rows))
    # A is first seen (0 s): track 0; B (2 s): track 1
    np.testing.assert_array_equal(labels, [0, 0, 1, 1, 0, 1])


def test_merge_where_the_vehicles_swap_order():
    # link 0 (200 m, station 0 at 100 m) and link 1 (200 m, station 1 at 100 m) merge into
    # link 2 (300 m, stations 2 at 100 m and 3 at 200 m); 200 m from station 0 or 1 to 2.
    net = network(
        {0: 200.0, 1: 200.0, 2: 300.0},
        [(0, 2), (1, 2)],
        [(0, 100.0), (1, 100.0), (2, 100.0), (2, 200.0)],
    )
    # A at 20 m/s from link 0: stations 0, 2, 3 at 0, 10, 15 s.
    # B at 30 m/s from link 1, 1 s later but faster: stations 1, 2, 3 at 1, 1 + 200/30,
    # 1 + 300/30 = 11 s; B passes station 2 before A does.
    rows = [
        (0, 0.0, 20.0, 0),
        (1, 1.0, 30.0, 1),
        (2, 1.0 + 200 / 30, 30.0, 1),
        (2, 10.0, 20.0, 0),
        (3, 11.0, 30.0, 1),
        (3, 15.0, 20.0, 0),
    ]
    labels = gmlkm_associate(net, detections(rows))
    np.testing.assert_array_equal(labels, [0, 1, 1, 0, 1, 0])


# link 0 (200 m, stations 0 at 50 m and 1 at 150 m) ends at an exit and also continues into
# link 1 (300 m, station 2 at 100 m), which has a driveway (entry) at 50 m
EXIT = network(
    {0: 200.0, 1: 300.0},
    [(0, 1)],
    [(0, 50.0), (0, 150.0), (1, 100.0)],
    entries=[(1, 50.0)],
    exits=[(0, 200.0)],
)


def test_a_vehicle_that_leaves_at_an_exit_ends_its_track():
    # A (20 m/s) passes stations 0 and 1 at 0 and 5 s and leaves at the exit.
    # B (20 m/s) passes them at 30 and 35 s and continues: 150 m to station 2, at 42.5 s.
    # C (15 m/s) comes in at the driveway and passes station 2 at 400 s, far beyond any
    # plausible wait after A or B.
    rows = [
        (0, 0.0, 20.0, 0),
        (1, 5.0, 20.0, 0),
        (0, 30.0, 20.0, 1),
        (1, 35.0, 20.0, 1),
        (2, 42.5, 20.0, 1),
        (2, 400.0, 15.0, 2),
    ]
    labels = gmlkm_associate(EXIT, detections(rows))
    # A's tail could reach B's head (gap 37.5 s, admissible) but B's own tail predicts it
    # exactly and is joined first; A's track ends at station 1
    np.testing.assert_array_equal(labels, [0, 0, 1, 1, 1, 2])


def test_a_missed_last_station_of_a_link_does_not_split_the_track():
    # B (20 m/s) is seen at station 0 (30 s) but missed at station 1; from station 0 it is
    # 100 m to station 1 and 150 m more to station 2: predicted at 30 + 250/20 = 42.5 s
    rows = [
        (0, 0.0, 20.0, 0),
        (1, 5.0, 20.0, 0),
        (0, 30.0, 20.0, 1),
        (2, 42.5, 20.0, 1),
    ]
    labels = gmlkm_associate(EXIT, detections(rows))
    np.testing.assert_array_equal(labels, [0, 0, 1, 1])


@pytest.mark.parametrize(
    ('head_stamp', 'joined'),
    [
        (12.5, True),  # on time: 150 m at 20 m/s after 5 s
        (4.0, False),  # before the departure (rule b)
        (8.0, False),  # 150 m in 3 s = 50 m/s > 1.5 x 20 m/s (rule c)
        (5.0 + 150 / 20 + MAX_WAIT_S + 1.0, False),  # later than one wait allows (rule d)
        (5.0 + 150 / 20 + MAX_WAIT_S - 1.0, True),  # a long red light, still plausible
    ],
)
def test_physical_rules_gate_a_join(head_stamp, joined):
    rows = [(0, 0.0, 20.0, 0), (1, 5.0, 20.0, 0), (2, head_stamp, 20.0, 0)]
    labels = gmlkm_associate(EXIT, detections(rows))
    assert (labels[2] == labels[0]) == joined
    assert labels[0] == labels[1] == 0


def random_diverge(rng, n_vehicles=12):
    """Vehicles through DIVERGE, each turning to link 1 or 2, plus one false alarm."""
    rows = []
    for k in range(n_vehicles):
        t0, v = rng.uniform(0, 120), rng.uniform(12, 32)
        rows += [(0, t0, v, k), (1, t0 + 100 / v, v, k)]
        rows.append((2 + int(rng.integers(2)), t0 + 300 / v, v + rng.normal(0, 1), k))
    rows.append((1, 60.0, 20.0, -1))
    order = rng.permutation(len(rows))
    return detections([rows[i] for i in order])


def test_every_detection_gets_a_track_and_the_result_is_deterministic():
    d = random_diverge(np.random.default_rng(7))
    first = gmlkm_associate(DIVERGE, d, seed=3)
    assert first.shape == (len(d),) and first.dtype == np.int64
    assert np.all(first >= 0)
    # tracks are numbered 0.. without gaps
    np.testing.assert_array_equal(np.unique(first), np.arange(first.max() + 1))
    np.testing.assert_array_equal(gmlkm_associate(DIVERGE, d, seed=3), first)
    # the order detections are given in does not matter
    perm = np.random.default_rng(1).permutation(len(d))
    np.testing.assert_array_equal(gmlkm_associate(DIVERGE, d.subset(perm), seed=3), first[perm])


def test_a_one_station_link_gives_one_link_track_per_detection():
    d = random_diverge(np.random.default_rng(2))
    pieces = link_tracks(DIVERGE, d)
    on_link_1 = d.sensor_index == 2
    assert np.unique(pieces[on_link_1]).size == int(on_link_1.sum())


def test_no_detections_and_unknown_stations():
    empty = Detections(np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
    assert gmlkm_associate(DIVERGE, empty).shape == (0,)
    with pytest.raises(ValueError, match='outside'):
        gmlkm_associate(DIVERGE, detections([(4, 0.0, 20.0, 0)]))


@pytest.mark.slow
def test_accuracy_on_a_seeded_sumo_interchange(tmp_path):
    road_networks = pytest.importorskip('mlkm_sumo.road_networks')
    from mlkm_core.network import network_from_mapping
    from mlkm_sumo import SumoError

    try:
        ds = road_networks.generate_network(
            road_networks.draw_network('interchange', 1, vehicles=120), tmp_path
        )
    except SumoError as exc:  # pragma: no cover (SUMO missing)
        pytest.skip(f'SUMO unavailable: {exc}')
    net = network_from_mapping(ds.mapping, 'interchange seed 1')
    d = ds.detections()
    labels = gmlkm_associate(net, d, seed=0)
    acc = accuracy(labels, d.target).accuracy
    print(f'gmlkm on the SUMO interchange (seed 1, 120 vehicles): accuracy {acc:.1%}')
    # a baseline: far better than chance, far from perfect
    assert 0.3 < acc < 0.99
