"""Time gates: the candidate pairs of a link model, without a dense n x m matrix.

* ``gate_pairs``: every (track, detection) pair whose value (a passage time) lies in the
  track's window (predicted passage time +- k sigma), from one sort of the values:
  O(n log n + pairs).
* ``gate_pairs_grouped``: the same within groups (a network's hops: a track's window is
  searched among its hop's detections only), from one sort of the values and the windows'
  ends together, however many groups.
"""

from __future__ import annotations

import numpy as np


def gate_pairs(
    centre: np.ndarray, half_width: np.ndarray, values: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """All (i, j) with |values[j] - centre[i]| <= half_width[i]; ``values`` need not be sorted."""
    if centre.size == 0 or values.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    order = np.argsort(values, kind='stable')
    sv = values[order]
    lo = np.searchsorted(sv, centre - half_width, side='left')
    hi = np.searchsorted(sv, centre + half_width, side='right')
    return runs(lo, hi, order)


def gate_pairs_grouped(
    row_group: np.ndarray,
    centre: np.ndarray,
    half_width: np.ndarray,
    value_group: np.ndarray,
    values: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``gate_pairs`` within groups: all (i, j) with ``row_group[i] == value_group[j]`` and
    |values[j] - centre[i]| <= half_width[i], by i, then by value (ties in the order of j).

    One stable sort of the values and both ends of every gate by (group, value) finds each
    gate's run of its group's values, however many groups (a network's hundreds of hops)."""
    n_v, n_r = values.size, centre.size
    if n_r == 0 or n_v == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    group = np.concatenate([value_group, row_group, row_group])
    value = np.concatenate([values, centre - half_width, centre + half_width])
    # ties: a gate's low end sorts before an equal value, its high end after
    end = np.concatenate([np.ones(n_v), np.zeros(n_r), np.full(n_r, 2.0)])
    events = np.lexsort((end, value, group))
    is_value = events < n_v
    before = np.empty(events.size, np.int64)
    before[events] = np.cumsum(is_value) - is_value  # values sorted before each event
    return runs(before[n_v : n_v + n_r], before[n_v + n_r :], events[is_value])


def runs(lo: np.ndarray, hi: np.ndarray, order: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(i, order[k]) for every k in [lo[i], hi[i]) of each row i, row after row: the pairs of
    the gates whose runs in the sorted values ``order`` are [lo, hi), or the members of
    groups stored as runs of ``order``."""
    counts = np.maximum(hi - lo, 0)
    rows = np.repeat(np.arange(lo.size), counts)
    starts = np.repeat(lo - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
    return rows, order[starts + np.arange(rows.size)]
