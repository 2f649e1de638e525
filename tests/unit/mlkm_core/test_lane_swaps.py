"""The multi-frame search's price of an order broken within a lane (``search.lane_swap_cost``
and the exchange it prices), on hand-made tracks."""

import math

import numpy as np
import pytest

from mlkm_core.associators import make_associator, search
from mlkm_core.associators.search import SWAP_PROB, _swaps, lane_swap_cost
from mlkm_core.metrics import accuracy
from mlkm_core.types import Detections


def platoon(n: int = 21, crossed: int = 0, lanes: int = 2):
    """``n`` vehicles 2 s apart in lane 0 at sensors 0 and 1 (500 m, 20 m/s); the first
    ``crossed`` neighbour pairs pass sensor 1 in the other order; with ``lanes`` 2 one more
    vehicle in lane 1 (the lanes tell vehicles apart). Tracks: one per vehicle of lane 0."""
    t0 = 2.0 * np.arange(n)
    t1 = t0 + 25.0
    for k in range(crossed):
        i = 2 * k
        t1[i], t1[i + 1] = t1[i + 1], t1[i]
    extra = lanes - 1
    d = Detections(
        np.concatenate([np.repeat([0, 1], n), np.zeros(extra, np.int64)]),
        np.concatenate([t0, t1, np.full(extra, 1.0)]),
        np.full(2 * n + extra, 20.0),
        target=np.concatenate([np.tile(np.arange(n), 2), np.full(extra, n)]),
        lane=np.concatenate([np.zeros(2 * n, np.int64), np.ones(extra, np.int64)]),
        length=np.full(2 * n + extra, 4.5),
    )
    M = np.column_stack([np.arange(n), n + np.arange(n)])  # track x sensor -> detection
    return d, M


def test_the_price_is_the_log_odds_of_the_crossings_the_tracks_show() -> None:
    d, M = platoon(21, crossed=3)  # 20 neighbour pairs, 3 of them crossed
    prob = (3 + 1) / (20 + 2)
    assert lane_swap_cost(d, M) == pytest.approx(math.log((1 - prob) / prob))
    d, M = platoon(21, crossed=0)  # none crossed: the smallest probability allowed
    low = max(1 / 22, SWAP_PROB[0])
    assert lane_swap_cost(d, M) == pytest.approx(math.log((1 - low) / low))


def test_no_lanes_no_price() -> None:
    d, M = platoon()
    plain = Detections(d.sensor_index, d.stamp, d.velocity, target=d.target)
    assert lane_swap_cost(plain, M) == 0.0


def test_one_lane_for_every_detection_tells_nothing_and_has_no_price() -> None:
    """A sensor that reports one lane for all (as the lane cue, ``model.lane.bind``)."""
    assert lane_swap_cost(*platoon(21, crossed=3, lanes=2)) > 0
    assert lane_swap_cost(*platoon(21, crossed=3, lanes=1)) == 0.0


def test_an_exchange_that_makes_neighbours_cross_is_priced_and_one_that_mends_them_credited():
    d, M = platoon(4, crossed=1)  # vehicles 0 and 1 crossed, 2 and 3 in order
    ca, cb = np.array([0, 2]), np.array([1, 3])
    # exchanging the tracks' detections from sensor 1 on: 0/1 uncross, 2/3 cross
    assert _swaps(d, M, ca, cb, np.array([0, 0])).tolist() == [-1, 1]
    other_lane = d.lane.copy()
    other_lane[M[3, 1]] = 1  # vehicle 3 changed lanes: no in-lane order to break
    moved = Detections(d.sensor_index, d.stamp, d.velocity, d.target, other_lane, d.length)
    assert _swaps(moved, M, ca, cb, np.array([0, 0])).tolist() == [-1, 0]


def test_multiframe_keeps_the_order_of_a_lane_on_real_traffic(ngsim_loops, monkeypatch) -> None:
    """NGSIM I-80, five loops 100 m apart from 60.9 m (the real bench's first placement),
    lane and length: two cars of 3.9 m, 2 s apart in lane 0, whose tails the search exchanged
    at the fourth loop (their speeds fit either way). Priced, every vehicle is one track."""
    ds = ngsim_loops(5, True)
    d = ds.detections

    def found() -> float:
        labels = make_associator('multiframe').associate(ds.layout, d, ds.n_targets)
        return accuracy(labels, d.target).accuracy

    assert found() == 1.0
    monkeypatch.setattr(search, 'lane_swap_cost', lambda *args: 0.0)
    assert found() < 1.0
