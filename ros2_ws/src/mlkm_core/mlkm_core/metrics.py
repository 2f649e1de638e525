"""Association metrics. ``accuracy`` is the contract's one accuracy function.

Accuracy (the paper's M_cr / M_t): the output tracks are mapped one-to-one onto the true
targets by the assignment that maximises the number of shared detections on the track x
target contingency table (the Hungarian optimum, computed on the sparse table so that
millions of detections and targets fit in memory); a true detection is correct when its
track is mapped to its target. False alarms (target -1) are not true detections and are
left out of M_t; an unassigned true detection (label -1) is never correct.

Beside it, over the same detections:

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
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import min_weight_full_bipartite_matching

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


def contingency(labels: np.ndarray, target: np.ndarray) -> csr_matrix:
    """Sparse track x target counts of shared detections (rows and columns renumbered 0..)."""
    rows = _dense_codes(labels)
    cols = _dense_codes(target)
    shape = (int(rows.max(initial=-1)) + 1, int(cols.max(initial=-1)) + 1)
    table = coo_matrix((np.ones(rows.size, np.int64), (rows, cols)), shape=shape).tocsr()
    table.sum_duplicates()
    return table


def max_weight_matching(table: csr_matrix) -> int:
    """Largest total weight of a one-to-one row/column matching of a sparse >= 0 table.

    Only the nonzero cells are edges, so the cost grows with the detections, never with
    tracks x targets. Each row r and column c gets a dummy partner (edges of weight 0) so
    that a full matching always exists; the dummies pair up among themselves on the
    transposed pattern. With cost = big - weight on real edges and big on dummy edges, every
    full matching costs (rows + cols) * big - (matched weight), so the cheapest one is the
    heaviest matching of the table.
    """
    table = csr_matrix(table)
    table.eliminate_zeros()
    n_r, n_c = table.shape
    if table.nnz == 0:
        return 0
    big = float(table.data.max()) + 1.0
    real = coo_matrix(table)
    r_idx = np.arange(n_r)
    c_idx = np.arange(n_c)
    rows = np.concatenate([real.row, r_idx, n_r + c_idx, n_r + real.col])
    cols = np.concatenate([real.col, n_c + r_idx, c_idx, n_c + real.row])
    cost = np.concatenate(
        [big - real.data.astype(float), np.full(n_r + n_c, big), np.full(real.nnz, big)]
    )
    graph = csr_matrix((cost, (rows, cols)), shape=(n_r + n_c, n_c + n_r))
    left, right = min_weight_full_bipartite_matching(graph)
    real_pair = (left < n_r) & (right < n_c)
    return int(np.asarray(table[left[real_pair], right[real_pair]]).sum())


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
    correct = max_weight_matching(contingency(labels[keep], target[keep]))
    return AccuracyResult(correct / total, correct, total)


def _links(group: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Consecutive (detection, detection) pairs within each group, walking ``order``.

    Each pair (a, b) is encoded as one int64 ``a * n + b`` (n = number of detections), so
    millions of links compare as sorted arrays instead of Python sets.
    """
    n = np.int64(group.size)
    g = group[order]
    same = g[1:] == g[:-1]
    return np.unique(order[:-1][same].astype(np.int64) * n + order[1:][same])


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
    shared = np.intersect1d(true_links, out_links, assume_unique=True).size
    link_recall = shared / true_links.size if true_links.size else 1.0
    link_precision = shared / out_links.size if out_links.size else 1.0

    order = _sequence_order(detections, true & assigned, target)
    t, lab = target[order], labels[order]
    switches = int(np.count_nonzero((t[1:] == t[:-1]) & (lab[1:] != lab[:-1])))

    n = len(detections)
    singletons = np.arange(n, dtype=np.int64) + int(max(target.max(initial=0), 0)) + 1
    truth_classes = np.where(true, target, singletons)
    label_classes = np.where(assigned, labels, singletons + int(labels.max(initial=0)) + 1)
    from sklearn.metrics import adjusted_rand_score  # a second to import: on first use

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
