"""Fragments of one track joined under the whole-track cost (``linking.join_fragments``)."""

from dataclasses import replace

import numpy as np
import pytest

from mlkm_core.associators import AssociatorConfig, make_associator
from mlkm_core.associators.base import canonical_order
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.associators.linking import (
    finish_tracks,
    join_fragments,
    link,
    merge_double_reports,
    relabel,
)
from mlkm_core.metrics import score
from mlkm_core.model.motion import MotionParams, PairwiseModel
from mlkm_core.simulator import SimConfig, simulate
from mlkm_core.types import Detections, Layout

POSITIONS = 200.0 * np.arange(1, 11)
LAYOUT = Layout(2200.0, POSITIONS)
#: a model whose per-sensor break (one miss and one new track) costs 4.6 nats
PARAMS = MotionParams(
    sigma=1.0,
    length=500.0,
    stamp_noise=0.1,
    velocity_noise=0.2,
    p_miss=0.1,
    clutter_density=0.1,
)


def car(speeds: list[float]) -> Detections:
    """One car past the ten sensors at the given speeds [m/s], with exact travel times (the
    speed changes linearly in slowness between two sensors)."""
    v = np.asarray(speeds, float)
    t = POSITIONS[0] / v[0] + np.concatenate(
        [[0.0], np.cumsum(200.0 * (1 / v[:-1] + 1 / v[1:]) / 2)]
    )
    return Detections(np.arange(10), t, v, np.zeros(10, np.int64))


def link_cost(d: Detections, a: int, b: int, p: MotionParams) -> tuple[float, float]:
    """NLL and squared Mahalanobis distance of the pairwise link from detection a to b."""
    m = PairwiseModel(p)
    m.grow(1)
    m.start(np.array([0]), POSITIONS[a], d.stamp[a : a + 1], 1 / d.velocity[a : a + 1])
    nll, d2 = m.cost(
        m.predict(np.array([0]), POSITIONS[b]), d.stamp[b : b + 1], 1 / d.velocity[b : b + 1]
    )
    return float(nll[0]), float(d2[0])


def break_costs(p: MotionParams, end: int, start: int) -> tuple[float, float]:
    """What the forward pass charges for a break, and what the whole-track model charges."""
    per_sensor = p.miss_cost + p.new_cost
    whole = p.misses_after(np.array([end]), 10)[0] + p.new_cost
    return per_sensor, float(whole + p.misses_before(np.array([start]))[0])


def test_a_car_accelerating_between_two_sensors_is_one_track():
    # 20 m/s up to sensor 4, 24.5 m/s from sensor 5 on: a link the pass finds too dear
    d = car([20.0] * 5 + [24.5] * 5)
    nll, d2 = link_cost(d, 4, 5, PARAMS)
    per_sensor, whole = break_costs(PARAMS, 4, 5)
    # within the gate, dearer than one miss and one new track (4.6 nats), much cheaper than
    # five sensors missed after the end, a new track and four missed before the start (23.0)
    assert d2 <= PARAMS.gate
    assert per_sensor == pytest.approx(4.605, abs=1e-3)
    assert whole == pytest.approx(23.026, abs=1e-3)
    assert per_sensor < nll < whole
    raw = link(LAYOUT, d, PARAMS)
    np.testing.assert_array_equal(raw, [0] * 5 + [1] * 5)
    np.testing.assert_array_equal(join_fragments(LAYOUT, d, raw, PARAMS), [0] * 10)
    for method in ('assignment', 'multiframe', 'mlkm_robust'):
        labels = make_associator(method).associate(LAYOUT, d, 1, motion=PARAMS)
        assert len(set(labels.tolist())) == 1, method


def test_a_car_that_leaves_and_one_that_enters_stay_apart():
    # the same detections with an exit and an entry between sensors 4 and 5: the first
    # track leaves the road, the second enters it, and neither break costs anything more
    d = car([20.0] * 5 + [24.5] * 5)
    config = AssociatorConfig(entries=(1100.0,), exits=(1100.0,))
    openings = MotionParams.road_openings(POSITIONS, config.entries, config.exits)
    opened = replace(PARAMS, open_road=openings)
    raw = link(LAYOUT, d, opened)
    np.testing.assert_array_equal(join_fragments(LAYOUT, d, raw, opened), [0] * 5 + [1] * 5)
    labels = make_associator('assignment', config).associate(LAYOUT, d, 2, motion=PARAMS)
    assert labels[0] != labels[9]
    # an exit alone: a track that ends before an exit is complete, so it is not joined
    exit_only = replace(PARAMS, open_road=MotionParams.road_openings(POSITIONS, (), (1100.0,)))
    joined = join_fragments(LAYOUT, d, link(LAYOUT, d, exit_only), exit_only)
    np.testing.assert_array_equal(joined, [0] * 5 + [1] * 5)


def test_no_link_beyond_the_gate_however_dear_the_break():
    # 20 -> 27 m/s: outside the pass's gate; with misses rarer (p_miss 0.01) the break costs
    # 43.7 nats, more than the link's NLL, and the fragments still stay apart
    dear = replace(PARAMS, p_miss=0.01)
    d = car([20.0] * 5 + [27.0] * 5)
    nll, d2 = link_cost(d, 4, 5, dear)
    assert d2 > dear.gate
    assert nll < break_costs(dear, 4, 5)[1]
    raw = link(LAYOUT, d, dear)
    np.testing.assert_array_equal(join_fragments(LAYOUT, d, raw, dear), raw)


def test_a_car_unseen_over_more_sensors_than_the_pass_carries_is_one_track():
    # constant speed, unseen at sensors 3 to 6: four sensors in a row, one more than the
    # forward pass carries a track (max_skip 3), so the pass leaves two tracks
    whole = car([20.0] * 10)
    seen = np.r_[0:3, 7:10]
    d = Detections(
        whole.sensor_index[seen], whole.stamp[seen], whole.velocity[seen], whole.target[seen]
    )
    assert PARAMS.max_skip == 3
    raw = link(LAYOUT, d, PARAMS)
    np.testing.assert_array_equal(raw, [0] * 3 + [1] * 3)
    # joined: a perfect link plus four misses (9.2 nats) against seven missed after the end
    # (16.1), a new track and four missed before the start (9.2 + 2.3)
    nll, _ = link_cost(whole, 2, 7, PARAMS)
    broken = break_costs(PARAMS, 2, 7)[1]
    assert nll + 4 * PARAMS.miss_cost < broken
    np.testing.assert_array_equal(join_fragments(LAYOUT, d, raw, PARAMS), [0] * 6)
    for method in ('assignment', 'multiframe', 'mlkm_robust'):
        labels = make_associator(method).associate(LAYOUT, d, 1, motion=PARAMS)
        assert len(set(labels.tolist())) == 1, method


def test_three_fragments_take_the_label_of_the_first():
    # speeds up after sensor 2 and slows down again after sensor 6
    d = car([20.0] * 3 + [24.5] * 4 + [20.0] * 3)
    raw = link(LAYOUT, d, PARAMS)
    np.testing.assert_array_equal(raw, [0] * 3 + [1] * 4 + [2] * 3)
    np.testing.assert_array_equal(join_fragments(LAYOUT, d, raw, PARAMS), [0] * 10)


def test_joining_raises_accuracy_in_clutter():
    # the simulator with 5 % misses, false alarms, 0.2 s stamp noise: tracks the pass breaks
    # after misses are joined again; no seed loses, and the mean gains half a point
    gains = []
    for seed in range(8):
        ds = simulate(
            SimConfig(
                n_targets=50,
                n_sensors=20,
                miss_probability=0.05,
                false_alarm_rate=0.05,
                stamp_noise=0.2,
                velocity_noise=0.5,
            ),
            seed,
        )
        d = ds.detections.subset(canonical_order(ds.detections))
        p = estimate_params(ds.layout, d)
        raw = link(ds.layout, d, p)
        before = score(d, relabel(merge_double_reports(d, raw, p))).accuracy
        after = score(d, finish_tracks(ds.layout, d, raw, p)).accuracy
        assert after >= before, seed
        gains.append(after - before)
    assert np.mean(gains) > 0.004
