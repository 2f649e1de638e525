"""The lane cue across a hop (``network_assoc.lanes``) on hand-made cases: a table learned
from links where the lanes persist and shift by one at a junction, a table that is 0 where
the lanes tell nothing, and a junction where pairs of vehicles side by side are told apart by
their lanes only (the layout says nothing of how the lanes continue; the data does)."""

from __future__ import annotations

import numpy as np

from mlkm_core.metrics import score
from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_core.network_assoc import associate_network
from mlkm_core.network_assoc.lanes import fit_lanes
from mlkm_core.types import Detections

# link 0 (2 lanes) continues on link 1 (3 lanes): a lane is added on the right at the
# junction, so lane k of link 0 is lane k + 1 of link 1
NET = RoadNetwork(
    links=(RoadLink(0, 'in', 600.0, 2), RoadLink(1, 'out', 600.0, 3)),
    connections=((0, 1),),
    station_ids=np.array([0, 1]),
    station_names=('s0', 's1'),
    station_links=np.array([0, 1]),
    station_offsets=np.array([400.0, 200.0]),
    station_lanes=np.array([2, 3]),
)


def side_by_side(pairs: int, noise: float, seed: int = 0) -> Detections:
    """Pairs of vehicles, one per lane, 1 s apart, 20 m/s; every stamp with ``noise`` [s]."""
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(pairs):
        for lane in (0, 1):
            t0 = 8.0 * k + 1.0 * lane
            v = 20.0 + rng.normal(0, 0.2)
            target = 2 * k + lane
            rows.append((0, t0 + rng.normal(0, noise), v, target, lane))
            rows.append((1, t0 + 400.0 / v + rng.normal(0, noise), v, target, lane + 1))
    s, t, v, k, lane = (np.array(c) for c in zip(*rows, strict=True))
    return Detections(s.astype(np.int64), t, v, k.astype(np.int64),
                      lane=lane.astype(np.int64))  # fmt: skip


def test_the_table_learns_the_lane_shift_at_the_junction():
    d = side_by_side(40, 0.0)
    a = np.flatnonzero(d.sensor_index == 0)
    b = np.array([np.flatnonzero((d.sensor_index == 1) & (d.target == d.target[i]))[0]
                  for i in a])  # fmt: skip
    table = fit_lanes(d, a, b, np.zeros(a.size, np.int64)).tables[0]
    # lane 0 -> 1 and 1 -> 2 are likelier than the station's shares say, the others less
    assert table[0, 1] > 0.5 and table[1, 2] > 0.5
    assert table[0, 2] < -1.0 and table[1, 1] < -1.0
    assert np.all(table[:, 0] == 0.0)  # lane 0 of link 1 is never seen: no evidence


def test_lanes_that_tell_nothing_weigh_nothing():
    rng = np.random.default_rng(3)
    d = side_by_side(200, 0.0)
    d.lane[:] = rng.integers(0, 2, len(d))  # every lane drawn independently of the vehicle
    a = np.flatnonzero(d.sensor_index == 0)
    b = a + 1  # each vehicle's two detections are adjacent rows
    table = fit_lanes(d, a, b, np.zeros(a.size, np.int64)).tables[0]
    assert np.abs(table).max() < 0.15
    assert fit_lanes(Detections(d.sensor_index, d.stamp, d.velocity), a, b, a * 0) is None


def test_vehicles_side_by_side_are_told_apart_by_their_lanes():
    d = side_by_side(40, 0.8, seed=3)
    without = Detections(d.sensor_index, d.stamp, d.velocity, d.target)
    assert score(without, associate_network(NET, without)).accuracy < 0.9
    assert score(d, associate_network(NET, d)).accuracy == 1.0
