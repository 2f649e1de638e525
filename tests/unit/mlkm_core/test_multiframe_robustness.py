"""``multiframe`` on inputs that defeat its model: it never crashes and its work is bounded.

* When no starting point of the local search can be scored (the likelihood is not finite),
  the result is the pairwise assignment's, with a ``DegradedResultWarning``; stop-and-go
  traffic, where the Kalman model does not fit, is searched under the pairwise model's Markov
  chain, without a warning.
* Congested, near-stationary traffic makes every passage-time gate span most of the episode,
  so the local search has candidates quadratic in the number of tracks; the search scores at
  most ``search_budget`` of them (counted, not timed) and stays deterministic.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mlkm_core.associators import (
    AssociatorConfig,
    DegradedResultWarning,
    canonical_order,
    make_associator,
)
from mlkm_core.associators import multiframe as multiframe_module
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.associators.likelihood import total_nll
from mlkm_core.associators.linking import link, relabel
from mlkm_core.associators.multiframe import kalman_fits
from mlkm_core.associators.repair import repaired
from mlkm_core.associators.search import refine
from mlkm_core.simulator import SimConfig, simulate

CLUTTER = dict(miss_probability=0.05, false_alarm_rate=0.05, stamp_noise=0.2, velocity_noise=0.5)
# stop-and-go: crawling speeds (3 m/s cruise, down to 0.05 m/s) and dense entries, so every
# target's detections overlap in time with those of most others
STOP_AND_GO = SimConfig(
    n_targets=30,
    n_sensors=12,
    velocity_mean=3.0,
    velocity_std=2.0,
    velocity_variation=2.5,
    min_speed=0.05,
    start_increment_min=0.0,
    start_increment_max=4.0,
    **CLUTTER,
)


@pytest.mark.parametrize('score', [np.inf, np.nan])
def test_falls_back_to_pairwise_when_no_start_has_a_finite_likelihood(monkeypatch, score):
    ds = simulate(SimConfig(n_targets=20, n_sensors=10, **CLUTTER), 2)
    # the calibrated model cannot score any labelling (log-likelihood -inf or undefined)
    monkeypatch.setattr(multiframe_module, 'total_nll', lambda *args: float(score))
    with pytest.warns(DegradedResultWarning, match='pairwise assignment'):
        labels = make_associator('multiframe').associate(ds.layout, ds.detections, 20)
    want = make_associator('assignment').associate(ds.layout, ds.detections, 20)
    np.testing.assert_array_equal(labels, want)
    assert (labels >= 0).sum() > 0.9 * len(ds.detections)


def test_local_search_stops_at_its_budget_on_stop_and_go_traffic():
    ds = simulate(STOP_AND_GO, 0)
    d = ds.detections.subset(canonical_order(ds.detections))
    with np.errstate(all='ignore'):
        params = estimate_params(ds.layout, d)
        start = link(ds.layout, d, params, 'kalman')
        budget = 5_000
        first = refine(ds.layout, d, start, params, budget=budget)
        again = refine(ds.layout, d, start, params, budget=budget)
        # a budget of nothing leaves the starting point as it is
        none = refine(ds.layout, d, start, params, budget=0)
    # more candidates than the budget in this traffic: the search stopped exactly at it
    assert first.exhausted and first.scored == budget
    assert first.rounds >= 1
    np.testing.assert_array_equal(first.labels, again.labels)
    assert none.scored == 0 and none.exhausted
    np.testing.assert_array_equal(none.labels, start)


def test_multiframe_with_a_budget_labels_every_detection_and_warns():
    ds = simulate(SimConfig(n_targets=50, n_sensors=20, **CLUTTER), 1)
    assoc = make_associator('multiframe', AssociatorConfig(search_budget=30))
    with pytest.warns(DegradedResultWarning, match='budget of 30 candidates'):
        labels = assoc.associate(ds.layout, ds.detections, ds.n_targets)
    assert labels.shape == (len(ds.detections),)
    assert labels.min() >= -1 and (labels >= 0).any()
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DegradedResultWarning)
        np.testing.assert_array_equal(
            labels, assoc.associate(ds.layout, ds.detections, ds.n_targets)
        )


def test_stop_and_go_traffic_is_searched_under_the_markov_chain():
    # near-zero speeds: the Kalman model (a cruise speed to revert to) predicts the tracks
    # clearly worse than the pairwise model; the search runs under the pairwise model's Markov
    # chain instead, lowers that model's NLL of the pairwise pass, and warns of nothing
    ds = simulate(STOP_AND_GO, 1)
    d = ds.detections.subset(canonical_order(ds.detections))
    with np.errstate(all='ignore'):
        params = estimate_params(ds.layout, d)
        start = repaired(ds.layout, d, link(ds.layout, d, params, 'pairwise'), params)
        assert not kalman_fits(ds.layout, d, relabel(start), params)
        searched = refine(ds.layout, d, start, params, model='pairwise').labels
        before = total_nll(ds.layout, d, start, params, 'pairwise')
        after = total_nll(ds.layout, d, searched, params, 'pairwise')
    assert after < before - 1.0
    with warnings.catch_warnings():
        warnings.simplefilter('error', DegradedResultWarning)
        labels = make_associator('multiframe').associate(ds.layout, ds.detections, 30)
    want = make_associator('assignment').associate(ds.layout, ds.detections, 30)
    assert not np.array_equal(labels, want)


def test_default_budget_does_not_limit_ordinary_traffic():
    ds = simulate(SimConfig(n_targets=50, n_sensors=20, **CLUTTER), 0)
    with warnings.catch_warnings():
        warnings.simplefilter('error', DegradedResultWarning)
        make_associator('multiframe').associate(ds.layout, ds.detections, ds.n_targets)


def test_negative_budget_is_refused():
    with pytest.raises(ValueError, match='search_budget'):
        AssociatorConfig(search_budget=-1)
