"""Shared machinery of the assignment-based associators (issue 4).

* ``match_sparse``: optimal one-to-one matching of rows (tracks) to columns (detections) with
  dummies for "row unmatched" (a miss) and "column unmatched" (a false alarm or a new track).
  Only gated candidate pairs are given. A pair is worth linking when its cost is below the sum
  of the two dummy costs, so the problem is a min-weight bipartite matching with weights
  ``w = cost - row_dummy - col_dummy < 0``. The candidate graph is split into connected
  components (time gating makes them small) and each component is solved exactly with
  ``scipy.optimize.linear_sum_assignment`` on a dense block in which non-edges weigh 0, which
  is the standard "dummy rows and columns" augmentation without building the (n+m)^2 matrix.
* ``gate_pairs``: candidate pairs from sorted 1-D windows (predicted passage time +- k sigma),
  O(n log n + pairs) instead of a dense n x m matrix.
* ``by_sensor``: detections grouped per sensor, sorted by stamp.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from mlkm_core.types import Detections


def by_sensor(detections: Detections, n_sensors: int) -> list[np.ndarray]:
    """Indices of the detections of each sensor, sorted by (stamp, velocity)."""
    order = np.lexsort((detections.velocity, detections.stamp, detections.sensor_index))
    bounds = np.searchsorted(detections.sensor_index[order], np.arange(n_sensors + 1))
    return [order[bounds[s] : bounds[s + 1]] for s in range(n_sensors)]


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
    counts = np.maximum(hi - lo, 0)
    total = int(counts.sum())
    rows = np.repeat(np.arange(centre.size), counts)
    starts = np.repeat(lo - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
    cols = order[starts + np.arange(total)]
    return rows, cols


def match_sparse(
    rows: np.ndarray, cols: np.ndarray, weight: np.ndarray, n_rows: int, n_cols: int
) -> tuple[np.ndarray, np.ndarray]:
    """Min-weight one-to-one matching over candidate edges with ``weight`` (< 0 to be useful).

    Returns matched (rows, cols). Edges with weight >= 0 never improve on leaving both ends
    unmatched (the dummies), so they are dropped first.
    """
    keep = weight < 0
    rows, cols, weight = rows[keep], cols[keep], weight[keep]
    if rows.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # keep the best edge per (row, col) pair
    graph = coo_matrix(
        (np.ones(rows.size), (rows, n_rows + cols)), shape=(n_rows + n_cols, n_rows + n_cols)
    )
    n_comp, comp = connected_components(graph, directed=False)
    edge_comp = comp[rows]
    order = np.argsort(edge_comp, kind='stable')
    rows, cols, weight, edge_comp = rows[order], cols[order], weight[order], edge_comp[order]
    bounds = np.flatnonzero(np.diff(edge_comp)) + 1
    starts = np.concatenate([[0], bounds])
    ends = np.concatenate([bounds, [rows.size]])
    sizes = ends - starts
    single = sizes == 1
    out_r = [rows[starts[single]]]
    out_c = [cols[starts[single]]]
    for s, e in zip(starts[~single], ends[~single], strict=True):
        r, c, w = rows[s:e], cols[s:e], weight[s:e]
        ur, ri = np.unique(r, return_inverse=True)
        uc, ci = np.unique(c, return_inverse=True)
        block = np.zeros((ur.size, uc.size))
        np.minimum.at(block, (ri, ci), w)
        a, b = linear_sum_assignment(block)
        useful = block[a, b] < 0
        out_r.append(ur[a[useful]])
        out_c.append(uc[b[useful]])
    return np.concatenate(out_r).astype(np.int64), np.concatenate(out_c).astype(np.int64)


def relabel(labels: np.ndarray, min_size: int = 2) -> np.ndarray:
    """Tracks with fewer than ``min_size`` detections become UNASSIGNED; ids made 0..k-1."""
    out = np.full(labels.size, -1, dtype=np.int64)
    valid = labels >= 0
    if not valid.any():
        return out
    ids, inverse, counts = np.unique(labels[valid], return_inverse=True, return_counts=True)
    big = counts[inverse] >= min_size
    new_ids = np.cumsum(counts >= min_size) - 1
    tmp = np.full(valid.sum(), -1, dtype=np.int64)
    tmp[big] = new_ids[inverse[big]]
    out[valid] = tmp
    return out
