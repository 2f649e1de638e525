"""The streaming tracker's cheap paths: the scalar link cost and the calibration carried
from one window solve to the next (no ROS)."""

import math
from dataclasses import replace

import numpy as np
import pytest

import mlkm_core.streaming.solve as solve_module
from mlkm_core.metrics import accuracy
from mlkm_core.model.motion import GapDelays, MotionParams, PairwiseModel
from mlkm_core.simulator import SimConfig, simulate
from mlkm_core.streaming import StreamConfig, StreamTracker
from mlkm_core.streaming.motion import LinkCost, overdue_at
from mlkm_core.streaming.solve import CarriedModel, WindowProblem, solve
from mlkm_core.types import Layout

CLUTTER = dict(miss_probability=0.05, false_alarm_rate=0.05, stamp_noise=0.2, velocity_noise=0.5)


def pairwise_weight(p, layout, a, t1, v1, b, t2, v2, birth):
    """The link weight through the vectorised pairwise model (the batch methods' cost)."""
    m = PairwiseModel(p)
    m.grow(1)
    m.start(np.arange(1), layout.positions[[a]], np.array([t1]), np.array([1 / v1]))
    pred = m.predict(np.arange(1), float(layout.positions[b]))
    with np.errstate(all='ignore'):
        nll, d2 = m.cost(pred, np.array([t2]), np.array([1 / v2]))
    w = nll + (b - 1 - a) * p.miss_cost - p.miss_cost - birth
    return float(np.where((d2 <= p.gate) & np.isfinite(w), w, np.inf)[0])


def test_link_cost_equals_the_pairwise_model():
    rng = np.random.default_rng(0)
    layout = Layout(2000.0, np.sort(rng.uniform(0, 2000, 12)))
    # gaps with an extra time and a spread of their own
    delay = GapDelays.per_gap(layout.positions, rng.uniform(0, 3, 11), rng.uniform(0, 4, 11))
    for p in (
        MotionParams(),
        replace(MotionParams(), jump_rate=0.002, stamp_noise=0.3),
        replace(MotionParams(), delay=delay),
    ):
        cost = LinkCost(p, layout)
        gated = 0
        for _ in range(500):
            a = int(rng.integers(0, 10))
            b = a + int(rng.integers(1, 3))
            t1, v1, v2 = rng.uniform(0, 100), rng.uniform(10, 35), rng.uniform(10, 35)
            t2 = t1 + (layout.positions[b] - layout.positions[a]) / v1 + rng.normal(0, 2)
            want = pairwise_weight(p, layout, a, t1, v1, b, t2, v2, 3.0)
            got = cost.weight((a, t1, v1), b, t2, v2, 3.0)
            if math.isinf(want):
                assert math.isinf(got)
                gated += 1
            else:
                assert abs(got - want) <= 1e-9 * max(1.0, abs(want))
        assert 0 < gated < 500  # both sides of the gate were exercised


def test_link_due_equals_the_overdue_gate_of_the_pairwise_model():
    rng = np.random.default_rng(1)
    layout = Layout(2000.0, np.sort(rng.uniform(0, 2000, 12)))
    delay = GapDelays.per_gap(layout.positions, rng.uniform(0, 3, 11), rng.uniform(0, 4, 11))
    for p in (
        MotionParams(),
        replace(MotionParams(), jump_rate=0.002, sigma=3.0),
        replace(MotionParams(), delay=delay),
    ):
        cost = LinkCost(p, layout)
        for _ in range(200):
            a = int(rng.integers(0, 10))
            to = a + int(rng.integers(1, 3))
            t, v = rng.uniform(0, 100), rng.uniform(5, 35)
            want = overdue_at(p, layout, a, t, v, to)
            assert abs(cost.due((a, t, v), to) - want) <= 1e-9 * max(1.0, abs(want))


def test_a_carried_model_gives_the_calibrating_solve_its_own_result():
    ds = simulate(SimConfig(n_targets=30, n_sensors=10, **CLUTTER), 3)
    problem = WindowProblem(
        'multiframe', StreamConfig().associator_config(), ds.layout, ds.detections, None
    )
    first = solve(problem)
    assert first.model is not None and first.model.reusable
    again = solve(replace(problem, model=first.model))
    assert again.model is None  # a carried model is not recalibrated
    np.testing.assert_array_equal(again.labels, first.labels)
    assert accuracy(first.labels, ds.detections.target).accuracy > 0.95


def _calibrations(monkeypatch, config: StreamConfig):
    """multiframe on a clutter stream (50 targets, 20 sensors): the sizes of the inputs its
    model was estimated on, the solves before the flush, the tracker and the labels."""
    calls = []
    estimate = solve_module.estimate_params

    def counting(layout, d, openings=None, whole_passages=True):
        assert not whole_passages  # a window cuts vehicles in transit: no count curves
        calls.append(len(d))
        return estimate(layout, d, openings, whole_passages)

    monkeypatch.setattr(solve_module, 'estimate_params', counting)
    ds = simulate(SimConfig(n_targets=50, n_sensors=20, **CLUTTER), 0)
    d = ds.detections
    tracker = StreamTracker(ds.layout, config)
    labels = np.full(len(d), -1)
    for k in np.lexsort((d.sensor_index, d.stamp)).tolist():
        u = tracker.push(k, int(d.sensor_index[k]), float(d.stamp[k]), float(d.velocity[k]))
        for key, track in u.committed.tolist():
            labels[key] = track
    solves = tracker.stats()['solves']
    for key, track in tracker.flush().committed.tolist():
        labels[key] = track
    return calls[:-1], solves, tracker, accuracy(labels, d.target).accuracy  # -1: the flush


@pytest.mark.slow
def test_the_stream_calibrates_once_every_calibration_every_windows(monkeypatch):
    """The method's model is estimated at every window until one was estimated on a full
    context (``context_size`` rows), then once every ``calibration_every`` windows; the
    windows in between get it carried over, without the context, and the commits stay as
    accurate as batch."""
    config = StreamConfig(calibration_every=3)
    calls, solves, tracker, acc = _calibrations(monkeypatch, config)
    full = next(i for i, n in enumerate(calls) if n >= config.context_size)
    assert solves >= 9 and full < solves - 3
    assert len(calls) - full <= math.ceil((solves - full) / 3) + 1
    assert isinstance(tracker._model, CarriedModel)
    assert tracker.params is tracker._model.params  # the immediate link uses it too
    assert acc >= 0.99


@pytest.mark.slow
def test_a_model_from_fewer_rows_than_a_full_context_is_not_carried(monkeypatch):
    """A road filling up: no model was estimated on ``context_size`` rows, so every window
    calibrates (a model from the first sparse windows carried over for a minute of a short
    stream cost 3 points on SUMO ramps)."""
    calls, solves, _, acc = _calibrations(
        monkeypatch, StreamConfig(calibration_every=3, context_size=100_000)
    )
    assert solves >= 9 and len(calls) == solves
    assert max(calls) < 100_000 and acc >= 0.99


def partition(labels: dict) -> list[list[int]]:
    tracks: dict = {}
    for key, track in labels.items():
        if track >= 0:
            tracks.setdefault(track, []).append(key)
    return sorted(sorted(g) for g in tracks.values())


@pytest.mark.slow
def test_deferred_solves_commit_the_same_later():
    """While ``deferring``, due windows wait (up to MAX_DEFERRED boundaries); once it is off
    they are solved in order and the committed association (which detections share a track,
    which are false alarms; ids follow the arrival of tracks) is that of a tracker that never
    deferred."""
    from mlkm_core.streaming.tracker import MAX_DEFERRED

    ds = simulate(SimConfig(n_targets=50, n_sensors=20, **CLUTTER), 1)
    d = ds.detections
    order = np.lexsort((d.sensor_index, d.stamp)).tolist()

    def run(defer_until: int) -> tuple[dict, list[int]]:
        tracker = StreamTracker(ds.layout, StreamConfig(solve_interval=5.0))
        labels, solves = {}, []
        for i, k in enumerate(order):
            tracker.deferring = i < defer_until
            u = tracker.push(k, int(d.sensor_index[k]), float(d.stamp[k]), float(d.velocity[k]))
            labels.update(u.committed.tolist())
            solves.append(tracker.stats()['solves'])
        labels.update(tracker.flush().committed.tolist())
        return labels, solves

    plain, plain_solves = run(0)
    half = len(order) // 2
    deferred, deferred_solves = run(half)
    assert partition(deferred) == partition(plain)
    assert sorted(k for k, t in deferred.items() if t < 0) == sorted(
        k for k, t in plain.items() if t < 0
    )
    due = plain_solves[half - 1]
    assert due >= 4  # windows were due while deferring...
    assert deferred_solves[half - 1] == max(0, due - MAX_DEFERRED)  # ...and waited
    assert deferred_solves[-1] == plain_solves[-1]
