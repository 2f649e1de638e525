"""Every registered method: batch equals incremental; the paper baselines on seeded data."""

import numpy as np
import pytest

from mlkm_core.associators import AssociatorConfig, available_methods, make_associator
from mlkm_core.associators.dnn import dnn_split
from mlkm_core.metrics import accuracy
from mlkm_core.simulator import SimConfig, simulate

CASES = [
    (SimConfig(n_targets=20, n_sensors=12), 5),
    (
        SimConfig(
            n_targets=15,
            n_sensors=11,
            miss_probability=0.1,
            false_alarm_rate=0.05,
            stamp_noise=0.2,
            velocity_noise=0.5,
        ),
        4,
    ),
]


def test_paper_methods_are_registered():
    assert {'kmeans_up', 'kmeans_p', 'kmeans_pp_up', 'kmeans_pp', 'mlkm', 'mlkm_no_ec'} <= set(
        available_methods()
    )


@pytest.mark.parametrize('method', available_methods())
@pytest.mark.parametrize('case', range(len(CASES)))
def test_batch_equals_incremental(method, case):
    cfg, k = CASES[case]
    ds = simulate(cfg, 3 + case)
    assoc = make_associator(method, AssociatorConfig(segment_size=k, seed=1))
    batch = assoc.associate(ds.layout, ds.detections, ds.n_targets)
    inc = assoc.associate_incrementally(ds.layout, ds.detections, ds.n_targets)
    assert batch.shape == (len(ds.detections),)
    assert np.array_equal(batch, inc)


@pytest.mark.parametrize('method', ['kmeans_up', 'kmeans_p', 'kmeans_pp_up', 'kmeans_pp'])
def test_kmeans_result_does_not_depend_on_input_order(method):
    ds = simulate(SimConfig(n_targets=20, n_sensors=10), 8)
    perm = np.random.default_rng(0).permutation(len(ds.detections))
    assoc = make_associator(method, AssociatorConfig(seed=3))
    a = assoc.associate(ds.layout, ds.detections, ds.n_targets)
    b = assoc.associate(ds.layout, ds.detections.subset(perm), ds.n_targets)
    assert np.array_equal(a[perm], b)


def test_preprocessing_helps_kmeans_pp_on_seeded_data():
    up, p = [], []
    for seed in range(8):
        ds = simulate(SimConfig(n_targets=10, n_sensors=10), seed)
        for name, out in (('kmeans_pp_up', up), ('kmeans_pp', p)):
            lab = make_associator(name, AssociatorConfig(seed=seed)).associate(
                ds.layout, ds.detections, ds.n_targets
            )
            out.append(accuracy(lab, ds.detections.target).accuracy)
    assert np.mean(p) > np.mean(up)


def test_dnn_split_trains_on_labelled_sensors():
    ds = simulate(SimConfig(n_targets=8, n_sensors=12), 0)
    r = dnn_split(ds, 9, seed=0, max_iter=300)
    assert (r.n_train_sensors, r.n_test_sensors) == (9, 3)
    assert 0.5 < r.train_accuracy <= 1.0
    assert 0.4 < r.test_accuracy <= 1.0
    with pytest.raises(ValueError):
        dnn_split(ds, 12)
