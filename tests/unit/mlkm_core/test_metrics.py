"""The contract's accuracy and the link metrics: hand-computed cases, a dense reference, scale."""

import numpy as np
import pytest

from mlkm_core.metrics import accuracy, score
from mlkm_core.types import Detections


def _dets(sensor, target, stamp=None):
    sensor = np.asarray(sensor)
    stamp = np.arange(sensor.size, dtype=float) if stamp is None else stamp
    return Detections(sensor, stamp, np.full(sensor.size, 50.0), np.asarray(target))


def test_accuracy_perfect_under_permuted_labels():
    target = np.array([0, 0, 1, 1, 2, 2])
    labels = np.array([7, 7, 3, 3, 5, 5])  # any renaming of the tracks is still perfect
    res = accuracy(labels, target)
    assert (res.accuracy, res.correct, res.total) == (1.0, 6, 6)


def test_accuracy_hand_computed_with_swap_and_unassigned():
    # Targets 0,1,2 with three detections each. Track 1 took one detection of target 1,
    # track 0 one of target 0 swapped the other way, and one detection is unassigned.
    target = np.array([0, 0, 0, 1, 1, 1, 2, 2, 2])
    labels = np.array([0, 0, 1, 1, 1, 0, 2, 2, -1])
    # Contingency: track0 -> t0:2, t1:1; track1 -> t0:1, t1:2; track2 -> t2:2.
    # Best one-to-one mapping: 0->0, 1->1, 2->2 = 2 + 2 + 2 = 6 of 9.
    res = accuracy(labels, target)
    assert (res.correct, res.total) == (6, 9)
    assert res.accuracy == pytest.approx(6 / 9)


def test_accuracy_is_one_to_one_not_majority():
    # One track swallowing two targets can only be credited with one of them.
    target = np.array([0, 0, 1, 1])
    labels = np.array([4, 4, 4, 4])
    assert accuracy(labels, target).correct == 2


def test_accuracy_leaves_false_alarms_out_of_the_total():
    target = np.array([0, 0, -1, 1, 1, -1])
    labels = np.array([0, 0, 0, 1, 1, -1])
    res = accuracy(labels, target)
    assert (res.correct, res.total, res.accuracy) == (4, 4, 1.0)


def test_link_metrics_and_identity_switches_hand_computed():
    # Two targets over three sensors. The tracks swap identities after sensor 1.
    sensor = np.array([0, 1, 2, 0, 1, 2])
    target = np.array([0, 0, 0, 1, 1, 1])
    labels = np.array([0, 0, 1, 1, 1, 0])
    s = score(_dets(sensor, target), labels)
    # True links: (0,1) (1,2) (3,4) (4,5). Output links: track0 = dets 0,1,5 -> (0,1) (1,5);
    # track1 = dets 2,3,4 sorted by sensor 3,4,2 -> (3,4) (4,2). Shared: (0,1) and (3,4).
    assert s.link_recall == pytest.approx(2 / 4)
    assert s.link_precision == pytest.approx(2 / 4)
    assert s.identity_switches == 2
    assert (s.correct, s.total) == (4, 6)


def test_score_perfect_and_ari_treats_false_alarms_as_singletons():
    sensor = np.array([0, 1, 0, 1, 1])
    target = np.array([0, 0, 1, 1, -1])
    labels = np.array([3, 3, 9, 9, -1])
    s = score(_dets(sensor, target), labels)
    assert s.accuracy == 1.0
    assert s.link_precision == s.link_recall == 1.0
    assert s.identity_switches == 0
    assert s.adjusted_rand_index == pytest.approx(1.0)
    # Putting the false alarm into a track costs precision and ARI, not accuracy.
    s2 = score(_dets(sensor, target), np.array([3, 3, 9, 9, 9]))
    assert s2.accuracy == 1.0
    assert s2.link_precision < 1.0
    assert s2.adjusted_rand_index < 1.0


def test_score_requires_truth():
    with pytest.raises(ValueError, match='ground truth'):
        score(Detections([0], [0.0], [1.0]), np.array([0]))


def _dense_reference(labels, target):
    """The textbook definition: Hungarian on the dense track x target table."""
    from scipy.optimize import linear_sum_assignment

    keep = (target >= 0) & (labels >= 0)
    if not keep.any():
        return 0
    rows = np.unique(labels[keep], return_inverse=True)[1]
    cols = np.unique(target[keep], return_inverse=True)[1]
    table = np.zeros((rows.max() + 1, cols.max() + 1))
    np.add.at(table, (rows, cols), 1)
    r, c = linear_sum_assignment(table, maximize=True)
    return int(table[r, c].sum())


@pytest.mark.parametrize('seed', range(40))
def test_sparse_accuracy_equals_the_dense_hungarian(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 120))
    n_targets = int(rng.integers(1, 15))
    n_tracks = int(rng.integers(1, 15))
    target = rng.integers(-1, n_targets, n)  # -1: false alarms
    labels = np.where(
        rng.random(n) < 0.6,
        target * 3 + 1,  # mostly follow the target under a renaming
        rng.integers(-1, n_tracks, n),  # the rest anywhere, unassigned included
    )
    labels[labels < -1] = -1
    res = accuracy(labels, target)
    assert res.correct == _dense_reference(labels, target)
    assert res.total == int((target >= 0).sum())


def test_accuracy_with_a_hundred_thousand_targets_stays_sparse():
    # 100,000 targets x 120,000 tracks: the dense table alone would need 96 GB.
    rng = np.random.default_rng(7)
    n_targets = 100_000
    target = np.repeat(np.arange(n_targets), 3)
    labels = rng.permutation(n_targets)[target]
    # One detection of 20,000 targets goes to a singleton track of its own: the best
    # mapping keeps every target on its main track (2 or 3 shared detections beat 1).
    moved = rng.choice(n_targets, 20_000, replace=False) * 3 + rng.integers(0, 3, 20_000)
    labels[moved] = n_targets + np.arange(moved.size)
    res = accuracy(labels, target)
    assert (res.correct, res.total) == (300_000 - 20_000, 300_000)


def test_score_of_many_targets_counts_links_exactly():
    # 50,000 targets over 4 sensors; every target's last detection is left unassigned.
    n_targets, n_sensors = 50_000, 4
    target = np.repeat(np.arange(n_targets), n_sensors)
    sensor = np.tile(np.arange(n_sensors), n_targets)
    labels = np.where(sensor == n_sensors - 1, -1, target + 5)
    s = score(_dets(sensor, target), labels)
    # true links: 3 per target; output links: 2 per track, all true.
    assert s.link_precision == 1.0
    assert s.link_recall == pytest.approx(2 / 3)
    assert (s.correct, s.total, s.identity_switches) == (3 * n_targets, 4 * n_targets, 0)
