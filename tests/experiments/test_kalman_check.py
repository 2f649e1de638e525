"""``python -m mlkm_experiments.kalman_check``: a vehicle's deviation from the traffic around
it, its persistence along links, and the two forced searches on a simulated road."""

from __future__ import annotations

import numpy as np
import pytest

from mlkm_core.associators import AssociatorConfig
from mlkm_core.simulator import SimConfig, simulate
from mlkm_core.types import Detections
from mlkm_experiments.kalman_check import check, deviations, persistence


def test_a_deviation_is_from_the_median_of_the_neighbours_in_time():
    # one station, five vehicles (slowness 0.1, 0.2, 0.05, 0.1, 0.125 s/m), rows out of
    # time order; with one neighbour each side the windows are (0,1,2) for the first two,
    # then (1,2,3) and (2,3,4) for the rest
    stamp = np.array([4.0, 0.0, 2.0, 1.0, 3.0])
    slowness = np.array([0.125, 0.1, 0.05, 0.2, 0.1])
    d = Detections(np.zeros(5, np.int64), stamp, 1.0 / slowness)
    e = deviations(d, neighbours=1)
    # in time order: 0.1, 0.2, 0.05, 0.1, 0.125; medians 0.1, 0.1, 0.1, 0.1, 0.1
    assert e[np.argsort(stamp)] == pytest.approx([0.0, 0.1, -0.05, 0.0, 0.025])


def test_persistence_is_one_where_each_vehicle_keeps_its_deviation_and_minus_one_where_it_flips():
    # two stations, ten vehicles 2 s apart; at the second station each keeps (or flips) its
    # deviation from the common slowness 0.05 s/m
    n = 10
    dev = np.linspace(-0.01, 0.01, n)
    sensor = np.repeat([0, 1], n)
    stamp = np.concatenate([2.0 * np.arange(n), 2.0 * np.arange(n) + 10.0])
    target = np.tile(np.arange(n), 2)
    for sign, expected in ((1.0, 1.0), (-1.0, -1.0)):
        slowness = 0.05 + np.concatenate([dev, sign * dev])
        d = Detections(sensor, stamp, 1.0 / slowness, target)
        assert persistence(d, target) == pytest.approx(expected)


def test_the_forced_searches_on_a_road_where_vehicles_keep_their_speed():
    ds = simulate(SimConfig(n_targets=30, n_sensors=10), 3)
    row = check(ds, AssociatorConfig())
    # the simulator's vehicles keep a cruise speed: the check takes the Kalman model, the
    # deviations persist, and multiframe is the forced Kalman search
    assert row['kalman_fits'] is True
    assert row['persistence'] > 0.8
    assert row['multiframe'] == row['kalman_search']
    assert 0.9 <= row['pairwise_search'] <= 1.0
