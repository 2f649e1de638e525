"""Accuracy of every method on seeded data, pinned to the exact count of correct detections.

Every method is deterministic for a given dataset and seed, so a change of any figure here is a
change of results, to be explained (an improvement or a deliberate change of method), never a
side effect of restructuring code. Datasets: the simulator's paper mode and clutter mode at
50 targets x 20 sensors (seed 1), and clutter at 200 x 50 (seed 0) for the tracking methods.
"""

from __future__ import annotations

import pytest

from mlkm_core.associators import make_associator
from mlkm_core.metrics import accuracy
from mlkm_core.simulator import SimConfig, simulate

CLUTTER = dict(miss_probability=0.05, false_alarm_rate=0.05, stamp_noise=0.2, velocity_noise=0.5)
DATASETS = {
    'paper_50x20': (SimConfig(n_targets=50, n_sensors=20), 1),
    'clutter_50x20': (SimConfig(n_targets=50, n_sensors=20, **CLUTTER), 1),
    'clutter_200x50': (SimConfig(n_targets=200, n_sensors=50, **CLUTTER), 0),
}
# (dataset, method): (correct, total) of mlkm_core.metrics.accuracy
PINNED = {
    ('paper_50x20', 'assignment'): (1000, 1000),
    ('paper_50x20', 'kmeans_p'): (656, 1000),
    ('paper_50x20', 'kmeans_pp'): (845, 1000),
    ('paper_50x20', 'kmeans_pp_up'): (722, 1000),
    ('paper_50x20', 'kmeans_up'): (627, 1000),
    ('paper_50x20', 'mlkm'): (935, 1000),
    ('paper_50x20', 'mlkm_no_ec'): (857, 1000),
    ('paper_50x20', 'mlkm_robust'): (1000, 1000),
    ('paper_50x20', 'multiframe'): (1000, 1000),
    ('clutter_50x20', 'assignment'): (949, 952),
    ('clutter_50x20', 'kmeans_p'): (634, 952),
    ('clutter_50x20', 'kmeans_pp'): (764, 952),
    ('clutter_50x20', 'kmeans_pp_up'): (680, 952),
    ('clutter_50x20', 'kmeans_up'): (551, 952),
    ('clutter_50x20', 'mlkm'): (775, 952),
    ('clutter_50x20', 'mlkm_no_ec'): (778, 952),
    ('clutter_50x20', 'mlkm_robust'): (949, 952),
    ('clutter_50x20', 'multiframe'): (952, 952),
    ('clutter_200x50', 'assignment'): (9287, 9503),
    ('clutter_200x50', 'mlkm'): (7444, 9503),
    ('clutter_200x50', 'mlkm_robust'): (9273, 9503),
    ('clutter_200x50', 'multiframe'): (9420, 9503),
}
_CACHE: dict = {}


def dataset(name: str):
    if name not in _CACHE:
        config, seed = DATASETS[name]
        _CACHE[name] = simulate(config, seed)
    return _CACHE[name]


@pytest.mark.parametrize(('name', 'method'), sorted(PINNED))
def test_accuracy_is_pinned(name, method):
    ds = dataset(name)
    labels = make_associator(method).associate(ds.layout, ds.detections, ds.n_targets)
    result = accuracy(labels, ds.detections.target)
    assert (result.correct, result.total) == PINNED[(name, method)]
