"""Queues between stations: the extra travel time of a gap, its spread and its lanes' own
(a merge), and the order of passage within a lane (hand-made traffic where they decide)."""

import math
from dataclasses import replace

import numpy as np
import pytest
from test_lane_length import N_SENSORS, SPACING, background, detections

from mlkm_core.associators import calibration, make_associator
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.associators.delays import estimate_gap_spread
from mlkm_core.associators.laneorder import restore_order
from mlkm_core.associators.linking import link, relabel
from mlkm_core.associators.merges import (
    estimate_lane_delays,
    estimate_yields,
    exchange_merge_order,
    relink_lane_delays,
)
from mlkm_core.metrics import accuracy
from mlkm_core.model import lane as lane_cue
from mlkm_core.model import length as length_cue
from mlkm_core.model.catalogue import bind_cues
from mlkm_core.model.lane_order import LaneOrder
from mlkm_core.model.motion import GapDelays, MotionParams
from mlkm_core.simulator import SimConfig, simulate
from mlkm_core.types import Detections, Layout


def test_extra_travel_time_of_a_gap_is_found_from_the_data():
    # road works between sensors 5 and 6: every vehicle loses 15 s there, which the speeds
    # measured at the sensors (outside the works) do not show
    layout, cols = background(60, 8)
    sensor = np.array(cols['sensor'])
    stamp = np.array(cols['stamp'])
    stamp[sensor >= 6] += 15.0
    cols['stamp'] = stamp.tolist()
    d = detections(cols, lane=False, length=False)
    p = estimate_params(layout, d)
    assert p.delay is not None
    extra = p.delay.gap_time
    assert extra[5] == pytest.approx(15.0, abs=0.5)
    assert np.all(np.abs(np.delete(extra, 5)) < 1e-9)
    # the same 15 s for every vehicle: no spread of its own
    assert np.all(p.delay.gap_var == 0)
    labels = make_associator('assignment').associate(layout, d, 60)
    assert accuracy(labels, d.target).accuracy == 1.0


def queue(seed: int):
    """Two lanes of 40 same-length cars each, 2.5 s apart in a lane; between sensors 5 and 6 a
    queue delays every car by 20 s plus noise (std 2.5 s) that keeps the order in each lane."""
    rng = np.random.default_rng(seed)
    layout = Layout(SPACING * (N_SENSORS + 1), SPACING * np.arange(1, N_SENSORS + 1))
    cols = {k: [] for k in ('sensor', 'stamp', 'speed', 'target', 'lane', 'length')}
    for lane in (0, 1):
        last = -np.inf
        for k in range(40):
            t0 = 2.5 * k + 1.2 * lane + rng.uniform(0, 0.3)
            v = 25.0 + rng.normal(0, 0.3)
            late = max(20.0 + rng.normal(0, 2.5), last - t0 + 1.5)
            last = t0 + late
            for s, x in enumerate(layout.positions):
                cols['sensor'].append(s)
                cols['stamp'].append(t0 + x / v + (late if s >= 6 else 0.0))
                cols['speed'].append(v + rng.normal(0, 0.1))
                cols['target'].append(40 * lane + k)
                cols['lane'].append(lane)
                cols['length'].append(4.5)
    return layout, cols


def test_order_within_a_lane_makes_far_jumps_in_a_queue_expensive():
    layout, cols = queue(10)
    d = detections(cols, lane=True, length=False)
    # learnt from the true tracks: the queue gap is recognised in both lanes
    order = LaneOrder(layout, d, d.target)
    assert {(5, 0), (5, 1)} <= set(order.table)
    at5 = np.array([np.flatnonzero((d.sensor_index == 5) & (d.target == k))[0] for k in range(80)])
    at6 = np.array([np.flatnonzero((d.sensor_index == 6) & (d.target == k))[0] for k in range(80)])
    lane0 = np.arange(0, 36)
    true_cost = order.cost(at5[lane0], at6[lane0])
    three_ahead = order.cost(at5[lane0], at6[lane0 + 3])
    assert np.all(true_cost <= -1.0)
    assert np.all(three_ahead > true_cost + 3.0)
    # no term across lanes or outside the queue gap
    assert np.all(order.cost(at5[:5], at6[40:45]) == 0)
    at3 = np.array([np.flatnonzero((d.sensor_index == 3) & (d.target == k))[0] for k in range(5)])
    at4 = np.array([np.flatnonzero((d.sensor_index == 4) & (d.target == k))[0] for k in range(5)])
    assert np.all(order.cost(at3, at4) == 0)


def scattered_gap(seed: int, spread: float):
    """Free-flow vehicles (``background``, no lane or length) held up 10 s, give or take
    N(0, spread^2), between sensors 5 and 6, which the speeds at the sensors do not show."""
    layout, cols = background(80, seed)
    late = 10.0 + np.random.default_rng(seed + 100).normal(0, spread, 80)
    sensor, target = np.array(cols['sensor']), np.array(cols['target'])
    cols['stamp'] = (np.array(cols['stamp']) + np.where(sensor >= 6, late[target], 0.0)).tolist()
    return layout, detections(cols, lane=False, length=False)


def test_a_gap_whose_travel_times_scatter_gets_their_spread():
    layout, d = scattered_gap(3, 2.0)
    p = MotionParams(sigma=0.5, length=2000.0, stamp_noise=0.05, velocity_noise=0.2)
    got = estimate_gap_spread(layout, d, d.target, p).delay
    assert got.gap_time[5] == pytest.approx(10.0, abs=0.8)
    assert math.sqrt(got.gap_var[5]) == pytest.approx(2.0, rel=0.3)
    assert np.all(np.delete(got.gap_time, 5) == 0)
    assert np.all(np.delete(got.gap_var, 5) == 0)
    # from the detections alone, through the self-calibration: the first pass links only
    # what its gate lets through, so it sees part of the spread, but in that gap alone
    est = estimate_params(layout, d).delay
    assert est is not None and est.gap_var[5] > 0.5**2
    assert np.all(np.delete(est.gap_var, 5) == 0)


def test_the_spread_of_a_gap_keeps_its_tracks_together(monkeypatch):
    """Five draws of the scattered gap: with its spread the tracks hold together (98.4 % on
    average); without it the gap breaks them (91.3 %), even though the pairwise model's own
    fit then takes up part of the scatter."""

    def mean_accuracy() -> float:
        got = []
        for seed in range(1, 6):
            layout, d = scattered_gap(seed, 2.0)
            labels = make_associator('assignment').associate(layout, d, 80)
            got.append(accuracy(labels, d.target).accuracy)
        return float(np.mean(got))

    with_spread = mean_accuracy()
    monkeypatch.setattr(calibration, 'estimate_gap_spread', lambda layout, d, labels, p: p)
    without = mean_accuracy()
    assert with_spread > 0.975
    assert without < 0.93


@pytest.mark.parametrize('clutter', [False, True])
def test_no_gap_gets_a_spread_of_its_own_on_the_simulators_traffic(clutter):
    noise = dict(miss_probability=0.05, false_alarm_rate=0.05, stamp_noise=0.2, velocity_noise=0.5)
    for seed in range(3):
        ds = simulate(SimConfig(n_targets=50, n_sensors=20, **(noise if clutter else {})), seed)
        delay = estimate_params(ds.layout, ds.detections).delay
        assert delay is None or not delay.gap_var.any()


def queue_params(layout: Layout, d) -> MotionParams:
    """The model of ``queue``'s traffic, lane and length fitted on its true tracks, the order
    within lanes learnt from them."""
    delay = np.zeros(N_SENSORS - 1)
    delay[5] = 20.0
    spread = np.zeros(N_SENSORS - 1)
    spread[5] = 2.5**2
    cues = bind_cues(
        layout,
        d,
        {
            'lane': lane_cue.fit(layout, d, d.target),
            'length': length_cue.fit(layout, d, d.target),
            'lane_order': LaneOrder(layout, d, d.target),
        },
    )
    return MotionParams(
        sigma=0.3,
        length=2000.0,
        stamp_noise=0.01,
        velocity_noise=0.1,
        delay=GapDelays.per_gap(layout.positions, delay, spread),
        cues=cues,
    )


def test_neighbours_crossed_in_a_queue_get_their_order_back():
    layout, cols = queue(10)
    d = detections(cols, lane=True, length=True)
    p = queue_params(layout, d)
    assert {(5, 0), (5, 1)} <= set(p.cues.get('lane_order').order.table)
    # cars 10 and 11 (lane 0, one behind the other) with their continuations after the queue
    # gap exchanged: the links cross
    after = d.sensor_index >= 6
    crossed = d.target.copy()
    crossed[after & (d.target == 10)] = 11
    crossed[after & (d.target == 11)] = 10
    np.testing.assert_array_equal(restore_order(layout, d, crossed, p), d.target)
    assert np.all(crossed[after & (d.target == 10)] == 11)  # the input is left as it is


def test_a_crossing_that_the_lengths_confirm_is_kept():
    layout, cols = queue(10)
    # car 11 is a 12 m truck that passes station 6 and on ahead of car 10
    sensor, target = np.array(cols['sensor']), np.array(cols['target'])
    stamp, length = np.array(cols['stamp']), np.array(cols['length'])
    length[target == 11] = 12.0
    for s in range(6, N_SENSORS):
        i, j = (
            np.flatnonzero((sensor == s) & (target == 10)),
            np.flatnonzero((sensor == s) & (target == 11)),
        )
        stamp[i], stamp[j] = stamp[j], stamp[i]
    cols['stamp'], cols['length'] = stamp.tolist(), length.tolist()
    d = detections(cols, lane=True, length=True)
    p = queue_params(layout, d)
    assert (5, 0) in p.cues.get('lane_order').order.table
    np.testing.assert_array_equal(restore_order(layout, d, d.target, p), d.target)
    # the same crossing between two cars of the same length is undone
    length[target == 11] = 4.5
    cols['length'] = length.tolist()
    d = detections(cols, lane=True, length=True)
    swapped = restore_order(layout, d, d.target, queue_params(layout, d))
    assert np.all(swapped[(sensor >= 6) & (target == 10)] == 11)


def merge(
    seed: int,
    late: float = 2.5,
    spread: float = 0.6,
    spread_closing: float = 0.4,
    yield_late: float = 0.0,
):
    """A lane drop between sensors 5 and 6: 60 cars of the same length, one every ~1.5 s,
    every third in lane 1, which ends before sensor 6. A car of lane 1 is held up ``late`` s,
    give or take N(0, spread_closing^2), where it merges; a car of lane 0 is held up
    N(0, spread^2) by the waves the merging cars send through the queue, and ``yield_late`` s
    more if it reaches sensor 6 right behind a car of lane 1. After the gap every car is in
    lane 0."""
    rng = np.random.default_rng(seed)
    layout = Layout(SPACING * (N_SENSORS + 1), SPACING * np.arange(1, N_SENSORS + 1))
    lane = (np.arange(60) % 3 == 2).astype(int)
    t0, v, held = np.zeros(60), np.zeros(60), np.zeros(60)
    speed = np.zeros((60, N_SENSORS))
    for k in range(60):
        t0[k] = 1.5 * k + rng.uniform(0, 0.3)
        v[k] = rng.uniform(24, 26)
        held[k] = rng.normal(late, spread_closing) if lane[k] else rng.normal(0.0, spread)
        speed[k] = v[k] + rng.normal(0, 0.1, N_SENSORS)
    # the cars of lane 0 right behind a car of lane 1 at sensor 6, their extra delay included
    base = held.copy()
    for _ in range(20 if yield_late else 0):
        order = np.argsort(t0 + layout.positions[6] / v + held)
        behind = np.zeros(60, bool)
        behind[order[1:]] = (lane[order[:-1]] == 1) & (lane[order[1:]] == 0)
        if np.array_equal(base + yield_late * behind, held):
            break
        held = base + yield_late * behind
    cols = {k: [] for k in ('sensor', 'stamp', 'speed', 'target', 'lane', 'length')}
    for k in range(60):
        for s, x in enumerate(layout.positions):
            cols['sensor'].append(s)
            cols['stamp'].append(t0[k] + x / v[k] + (held[k] if s >= 6 else 0.0))
            cols['speed'].append(speed[k, s])
            cols['target'].append(k)
            cols['lane'].append(int(lane[k]) if s <= 5 else 0)
            cols['length'].append(4.5)
    return layout, detections(cols, lane=True, length=True)


MERGE_MODEL = MotionParams(sigma=0.5, length=2000.0, stamp_noise=0.05, velocity_noise=0.2)


@pytest.mark.parametrize('seed', range(3))
def test_the_lane_that_ends_at_a_merge_gets_its_own_delay(seed):
    layout, d = merge(seed)
    pooled = estimate_gap_spread(layout, d, d.target, MERGE_MODEL)
    assert pooled.delay.gap_var[5] > 0 and np.all(np.delete(pooled.delay.gap_var, 5) == 0)
    lanes = estimate_lane_delays(layout, d, d.target, pooled).delay.lanes
    assert [(g, lane) for g, lane, _, _ in lanes] == [(5, 0), (5, 1)]
    # each lane's median delay and its spread beyond the model's own (N(0, 0.6^2) for lane 0,
    # N(2.5, 0.4^2) for lane 1, from 40 and 20 cars)
    (_, _, t0, v0), (_, _, t1, v1) = lanes
    assert t0 == pytest.approx(0.0, abs=0.25)
    assert t1 == pytest.approx(2.5, abs=0.3)
    assert 0.0 < v0 < 0.6 and 0.0 < v1 < 0.4
    # the gap's own estimate is left as it is, for links that leave no lane behind
    np.testing.assert_array_equal(
        estimate_lane_delays(layout, d, d.target, pooled).delay.gap_time, pooled.delay.gap_time
    )


def test_lanes_held_up_alike_share_the_gap_delay():
    layout, d = merge(0, late=0.3, spread=0.6, spread_closing=0.6)
    pooled = estimate_gap_spread(layout, d, d.target, MERGE_MODEL)
    assert pooled.delay.gap_var[5] > 0
    assert estimate_lane_delays(layout, d, d.target, pooled).delay.lanes == ()


def test_relinking_with_the_lanes_delays_mends_the_merge():
    raw_acc, relinked_acc = [], []
    for seed in range(3):
        layout, d = merge(seed)
        pooled = estimate_gap_spread(layout, d, d.target, MERGE_MODEL)
        own = estimate_lane_delays(layout, d, d.target, pooled)
        raw = link(layout, d, pooled)
        kept = raw.copy()
        relinked = relink_lane_delays(layout, d, raw, own)
        np.testing.assert_array_equal(raw, kept)  # the input is left as it is
        # without lanes' own delays nothing is re-decided
        np.testing.assert_array_equal(relink_lane_delays(layout, d, raw, pooled), raw)
        # only links across the merge gap change: before it, the tracks are the same
        before = d.sensor_index <= 5
        assert (
            accuracy(relabel(relinked)[before], d.target[before]).accuracy
            == accuracy(relabel(raw)[before], d.target[before]).accuracy
        )
        raw_acc.append(accuracy(relabel(raw), d.target).accuracy)
        relinked_acc.append(accuracy(relabel(relinked), d.target).accuracy)
    # seeds 0-2: 0.88, 0.88, 0.83 -> 0.97, 0.98, 0.93
    assert np.mean(raw_acc) < 0.9
    assert np.mean(relinked_acc) > 0.95
    assert min(b - a for a, b in zip(raw_acc, relinked_acc, strict=True)) > 0.05


def merging_pair(stamps: list[float]):
    """Stations 200 m apart with a lane drop between the last two: car A (target 0, lane 0)
    and car B (target 1, lane 1, then lane 0) at 25 m/s; ``stamps`` are (A, B) at each
    station in turn."""
    layout = Layout(500.0, np.array([50.0, 250.0, 450.0]))
    return layout, Detections(
        np.array([0, 0, 1, 1, 2, 2]),
        np.array(stamps),
        np.full(6, 25.0),
        np.array([0, 1, 0, 1, 0, 1]),
        np.array([0, 1, 0, 1, 0, 0]),
    )


def test_a_merging_car_held_up_behind_the_one_it_passed_keeps_its_track():
    # stations 200 m apart, the lane drop between the last two; both cars at 25 m/s.
    # Car B (lane 1) passes station 1 a second before car A (lane 0) and merges behind it:
    # A is 0.3 s late at station 2, B 2.5 s. Expected late time and variance in that gap: 0.8 s
    # and 1.5 s^2 for the gap as a whole, 0 and 0.04 for lane 0, 2.5 and 0.04 for lane 1.
    layout, d = merging_pair([92.0, 91.0, 100.0, 99.0, 108.3, 109.5])
    pooled = replace(
        MERGE_MODEL, delay=GapDelays.per_gap(layout.positions, [0.0, 0.8], [0.0, 1.5])
    )
    lanes = ((1, 0, 0.0, 0.04), (1, 1, 2.5, 0.04))
    own = replace(pooled, delay=replace(pooled.delay, lanes=lanes))
    # residuals beyond the gap's 0.8 s: -0.5 and 1.7 s as they drove, 0.7 and 0.5 s with the
    # continuations exchanged, so the gap's law alone exchanges them ...
    raw = link(layout, d, pooled)
    assert raw[4] == raw[1] and raw[5] == raw[0]
    # ... and each lane's own law (0.3 s for A: 1.5 sigma; 0 s for B) gives them back
    relinked = relink_lane_delays(layout, d, raw, own)
    assert accuracy(relabel(relinked), d.target).accuracy == 1.0


@pytest.mark.parametrize('seed', range(4))
def test_the_car_that_lets_a_merging_car_in_gets_its_own_delay(seed):
    layout, d = merge(seed, spread=0.3, yield_late=1.0)
    p = estimate_gap_spread(layout, d, d.target, MERGE_MODEL)
    p = estimate_lane_delays(layout, d, d.target, p)
    ((g, time, var),) = estimate_yields(layout, d, d.target, p).delay.yields
    # N(0, 0.3^2) for a car of lane 0, 1 s more right behind a car of lane 1 (14-18 cars)
    assert g == 5
    assert time == pytest.approx(1.0, abs=0.4)
    assert 0.0 <= var < 0.5
    # without the extra delay, the cars behind a merging car are held up like the others
    layout, d = merge(seed, spread=0.3)
    p = estimate_gap_spread(layout, d, d.target, MERGE_MODEL)
    p = estimate_lane_delays(layout, d, d.target, p)
    assert p.delay.lanes and estimate_yields(layout, d, d.target, p).delay.yields == ()


def test_a_car_held_up_by_the_car_it_let_in_passes_after_it():
    # stations 200 m apart, the lane drop between the last two; both cars at 25 m/s. Car B
    # (lane 1) passes station 1 half a second before car A (lane 0); after the merge B passes
    # station 2 at 109.0 s, A at 109.4 s. Lane 0 is expected on time (0 s, variance 0.04 s^2),
    # lane 1 2.5 s late (variance 0.25), and a car of lane 0 right behind a merging one 1 s late
    # (variance 0.09).
    layout, d = merging_pair([92.0, 91.5, 100.0, 99.5, 109.4, 109.0])
    lanes = ((1, 0, 0.0, 0.04), (1, 1, 2.5, 0.25))
    delay = GapDelays.per_gap(layout.positions, [0.0, 0.8], [0.0, 1.5])
    p = replace(MERGE_MODEL, delay=replace(delay, lanes=lanes, yields=((1, 1.0, 0.09),)))
    # A first (1.0 s late: 5 sigma of lane 0), B 1.9 s late (1.2 sigma of lane 1) is what the
    # lanes alone prefer over A 1.4 s late (7 sigma) behind B 1.5 s late (2 sigma) ...
    swapped = np.array([0, 1, 0, 1, 1, 0])
    no_yield = replace(p, delay=replace(p.delay, yields=()))
    np.testing.assert_array_equal(exchange_merge_order(layout, d, swapped, no_yield), swapped)
    assert relink_lane_delays(layout, d, swapped, no_yield)[4] == 1
    # ... but A let B in: 0.4 s off its yield delay (1.3 sigma), and B leads
    np.testing.assert_array_equal(exchange_merge_order(layout, d, swapped, p), d.target)
    np.testing.assert_array_equal(exchange_merge_order(layout, d, d.target, p), d.target)
