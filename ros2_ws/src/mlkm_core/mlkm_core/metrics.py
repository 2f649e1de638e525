"""Association metrics. ``accuracy`` is the contract's one accuracy function.

Accuracy (the paper's M_cr / M_t): the output tracks are mapped one-to-one onto the true
targets by the Hungarian assignment that maximises the number of shared detections on the
track x target contingency table; a true detection is correct when its track is mapped to
its target. False alarms (target -1) are not true detections and are left out of M_t; an
unassigned true detection (label -1) is never correct.

Beside it (issue 4), over the same detections:

- links: the consecutive detection pairs of a sequence ordered by sensor (then stamp). The
  true links come from each target's sequence, the output links from each track's.
  ``link_recall`` = shared links / true links, ``link_precision`` = shared / output links.
- ``identity_switches``: along each target's sequence, the number of times the track label
  changes between consecutive assigned detections (unassigned ones are skipped).
- ``adjusted_rand_index``: ``sklearn.metrics.adjusted_rand_score`` over all detections,
  where every false alarm and every unassigned detection is a singleton of its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from sklearn.metrics import adjusted_rand_score

from mlkm_core.types import Detections


@dataclass(frozen=True)
class AccuracyResult:
    accuracy: float  # correct / total, in [0, 1]; 1.0 when there is no true detection
    correct: int
    total: int


@dataclass(frozen=True)
class Score:
    accuracy: float
    correct: int
    total: int
    link_precision: float
    link_recall: float
    identity_switches: int
    adjusted_rand_index: float


def _dense_codes(values: np.ndarray) -> np.ndarray:
    return np.unique(values, return_inverse=True)[1].reshape(-1)


def accuracy(labels: np.ndarray, target: np.ndarray) -> AccuracyResult:
    """Fraction of true detections whose track maps to their target (best 1:1 mapping)."""
    labels = np.asarray(labels, dtype=np.int64)
    target = np.asarray(target, dtype=np.int64)
    if labels.shape != target.shape:
        raise ValueError('labels and target must have the same shape')
    true = target >= 0
    total = int(true.sum())
    if total == 0:
        return AccuracyResult(1.0, 0, 0)
    keep = true & (labels >= 0)
    if not keep.any():
        return AccuracyResult(0.0, 0, total)
    rows = _dense_codes(labels[keep])
    cols = _dense_codes(target[keep])
    table = coo_matrix((np.ones(rows.size), (rows, cols))).toarray()
    r, c = linear_sum_assignment(table, maximize=True)
    correct = int(table[r, c].sum())
    return AccuracyResult(correct / total, correct, total)


def _links(group: np.ndarray, order: np.ndarray) -> set[tuple[int, int]]:
    """Consecutive (detection, detection) pairs within each group, walking ``order``."""
    g = group[order]
    same = g[1:] == g[:-1]
    return set(zip(order[:-1][same].tolist(), order[1:][same].tolist(), strict=True))


def _sequence_order(detections: Detections, mask: np.ndarray, group: np.ndarray) -> np.ndarray:
    idx = np.flatnonzero(mask)
    return idx[np.lexsort((detections.stamp[idx], detections.sensor_index[idx], group[idx]))]


def score(detections: Detections, labels: np.ndarray) -> Score:
    """All metrics of ``labels`` against ``detections.target`` (which must be present)."""
    if detections.target is None:
        raise ValueError('scoring needs ground truth (detections.target)')
    labels = np.asarray(labels, dtype=np.int64)
    target = detections.target
    if labels.shape != target.shape:
        raise ValueError('one label per detection is required')
    acc = accuracy(labels, target)

    true = target >= 0
    assigned = labels >= 0
    true_links = _links(target, _sequence_order(detections, true, target))
    out_links = _links(labels, _sequence_order(detections, assigned, labels))
    shared = len(true_links & out_links)
    link_recall = shared / len(true_links) if true_links else 1.0
    link_precision = shared / len(out_links) if out_links else 1.0

    order = _sequence_order(detections, true & assigned, target)
    t, lab = target[order], labels[order]
    switches = int(np.count_nonzero((t[1:] == t[:-1]) & (lab[1:] != lab[:-1])))

    n = len(detections)
    singletons = np.arange(n, dtype=np.int64) + int(max(target.max(initial=0), 0)) + 1
    truth_classes = np.where(true, target, singletons)
    label_classes = np.where(assigned, labels, singletons + int(labels.max(initial=0)) + 1)
    ari = float(adjusted_rand_score(truth_classes, label_classes)) if n else 1.0

    return Score(
        accuracy=acc.accuracy,
        correct=acc.correct,
        total=acc.total,
        link_precision=link_precision,
        link_recall=link_recall,
        identity_switches=switches,
        adjusted_rand_index=ari,
    )
