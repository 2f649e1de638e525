"""The tracking associators (``assignment``, ``mlkm_robust``, ``multiframe``) and their machinery.

Hand-made cases with a known answer; dummy handling (a miss, a false alarm); batch equals
incremental; the multi-sensor evidence at work. ROS-free, fast.
"""

from __future__ import annotations

import numpy as np
import pytest

from mlkm_core.associators import available_methods, make_associator
from mlkm_core.associators.likelihood import sequence_nll
from mlkm_core.associators.linking import match_sparse, relabel
from mlkm_core.metrics import accuracy
from mlkm_core.model.motion import MotionParams
from mlkm_core.simulator import SimConfig, simulate
from mlkm_core.types import Detections, Layout

NEW = ('assignment', 'mlkm_robust', 'multiframe')
CLUTTER = dict(miss_probability=0.05, false_alarm_rate=0.05, stamp_noise=0.2, velocity_noise=0.5)

# Three constant-speed targets on four sensors; D (80 m/s) overtakes A (50 m/s) between the
# first and the second sensor, so the order of passage differs between sensors.
POS = np.array([100.0, 200.0, 300.0, 350.0])
TARGETS = {0: (50.0, 0.0), 1: (40.0, 1.0), 2: (80.0, 1.0)}  # id: (speed, entry time)


def hand_made(
    drop: tuple[int, int] | None = None, false_alarm: tuple[int, float] | None = None
) -> tuple[Layout, Detections]:
    si, st, sv, tg = [], [], [], []
    for s, x in enumerate(POS):
        for k, (v, t0) in TARGETS.items():
            if drop == (k, s):
                continue
            si.append(s)
            st.append(t0 + x / v)
            sv.append(v)
            tg.append(k)
        if false_alarm is not None and false_alarm[0] == s:
            si.append(s)
            st.append(false_alarm[1])
            sv.append(45.0)
            tg.append(-1)
    order = np.argsort(st, kind='stable')  # scrambled: by time, not by sensor
    d = Detections(
        np.array(si)[order], np.array(st)[order], np.array(sv)[order], np.array(tg)[order]
    )
    return Layout(400.0, POS), d


def same_partition(labels: np.ndarray, target: np.ndarray) -> bool:
    """Labels equal the truth up to renaming, false alarms (-1) unassigned."""
    if np.any(labels[target < 0] >= 0):
        return False
    t, lab = target[target >= 0], labels[target >= 0]
    if np.any(lab < 0):
        return False
    pairs = set(zip(t.tolist(), lab.tolist(), strict=True))
    return len(pairs) == len(set(t.tolist())) == len(set(lab.tolist()))


def test_registered_everywhere_by_name():
    assert set(NEW) <= set(available_methods())
    for name in NEW:
        assert make_associator(name).name == name


@pytest.mark.parametrize('method', NEW)
def test_hand_made_overtaking_is_associated_exactly(method):
    layout, d = hand_made()
    labels = make_associator(method).associate(layout, d, 3)
    assert same_partition(labels, d.target)
    # the overtaking happened: D passes sensor 0 after A and sensor 1 before A
    a0, d0 = (d.stamp[(d.target == k) & (d.sensor_index == 0)][0] for k in (0, 2))
    a1, d1 = (d.stamp[(d.target == k) & (d.sensor_index == 1)][0] for k in (0, 2))
    assert a0 < d0 and d1 < a1


@pytest.mark.parametrize('method', NEW)
def test_missed_detection_track_skips_the_sensor(method):
    layout, d = hand_made(drop=(1, 1))  # target 1 not reported at sensor 1
    labels = make_associator(method).associate(layout, d, 3)
    b = labels[d.target == 1]
    assert b.size == 3 and np.all(b == b[0]) and b[0] >= 0
    assert not np.isin(b[0], labels[d.target != 1])
    assert same_partition(labels, d.target)


@pytest.mark.parametrize('method', NEW)
def test_false_alarm_is_unassigned(method):
    layout, d = hand_made(false_alarm=(1, 30.0))  # far from every track at sensor 1
    labels = make_associator(method).associate(layout, d, 3)
    assert labels[d.target == -1].tolist() == [-1]
    assert same_partition(labels, d.target)


@pytest.mark.parametrize('method', NEW)
def test_miss_and_false_alarm_together(method):
    layout, d = hand_made(drop=(2, 1), false_alarm=(2, 0.5))
    labels = make_associator(method).associate(layout, d, 3)
    assert labels[d.target == -1].tolist() == [-1]
    assert same_partition(labels, d.target)


@pytest.mark.parametrize('method', NEW)
def test_batch_equals_incremental_and_input_order_free(method):
    ds = simulate(SimConfig(n_targets=20, n_sensors=12, **CLUTTER), 5)
    a = make_associator(method)
    batch = a.associate(ds.layout, ds.detections, ds.n_targets)
    incr = a.associate_incrementally(ds.layout, ds.detections, ds.n_targets)
    assert np.array_equal(batch, incr)
    perm = np.random.default_rng(1).permutation(len(ds.detections))
    shuffled = np.empty_like(batch)
    shuffled[perm] = a.associate(ds.layout, ds.detections.subset(perm), ds.n_targets)
    assert np.array_equal(batch, shuffled)
    assert accuracy(batch, ds.detections.target).accuracy > 0.9


def test_seeded_accuracy_ordering_in_clutter():
    """Multi-sensor evidence beats pairwise assignment, which beats the paper's MLKM."""
    res = {m: [] for m in ('mlkm', 'mlkm_robust', 'assignment', 'multiframe')}
    for seed in range(3):
        ds = simulate(SimConfig(n_targets=50, n_sensors=20, **CLUTTER), seed)
        for m in res:
            lab = make_associator(m).associate(ds.layout, ds.detections, ds.n_targets)
            res[m].append(accuracy(lab, ds.detections.target).accuracy)
    mean = {m: float(np.mean(v)) for m, v in res.items()}
    assert mean['multiframe'] > mean['assignment'] > mean['mlkm']
    assert mean['mlkm_robust'] >= mean['mlkm'] + 0.10
    assert mean['multiframe'] > 0.98


def test_match_sparse_with_dummies_hand_computed():
    # rows = tracks, cols = detections; weights are cost - dummy costs (< 0 worth linking)
    rows = np.array([0, 0, 1, 1, 2])
    cols = np.array([0, 1, 0, 1, 2])
    w = np.array([-5.0, -4.0, -4.5, -1.0, 3.0])
    r, c = match_sparse(rows, cols, w, 3, 4)
    got = dict(zip(r.tolist(), c.tolist(), strict=True))
    # greedy would take (0,0) and then (1,1): -6; optimal is (0,1) + (1,0): -8.5;
    # (2,2) costs more than its dummies (w > 0): track 2 missed, detections 2, 3 unmatched
    assert got == {0: 1, 1: 0}


def test_relabel_prunes_single_detection_tracks():
    assert relabel(np.array([7, 7, 3, 9, -1, 9])).tolist() == [0, 0, -1, 1, -1, 1]


def test_kalman_likelihood_prefers_the_true_tracks():
    layout, d = hand_made()
    p = MotionParams(stamp_noise=0.01, velocity_noise=0.01)

    def track(k):
        idx = np.flatnonzero(d.target == k)
        row = np.full(4, -1)
        row[d.sensor_index[idx]] = idx
        return row

    a, b = track(0), track(2)
    swapped_a = np.concatenate([a[:2], b[2:]])
    swapped_b = np.concatenate([b[:2], a[2:]])
    nll = sequence_nll(layout, d, np.array([a, b, swapped_a, swapped_b]), p)
    assert nll[0] + nll[1] < nll[2] + nll[3] - 10
