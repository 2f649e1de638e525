"""The contract's accuracy and issue 4's metrics on hand-computed cases."""

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
