"""One window solve: the batch associators run on a window of detections plus anchors.

``solve_window`` returns a cluster per detection (raw ids, -1 = left alone). ``assignment``
and ``multiframe`` run natively with the motion parameters the tracker calibrated on its
history (the sequential assignment, and for ``multiframe`` the Kalman pass, the pairwise
pass and the multi-frame local search, keeping the more likely result); every other method
runs its own ``associate`` with the number of targets taken from the window (its largest
per-station count). Without history (nothing committed yet) every method runs its own
``associate``, so a window holding the whole input gives exactly the batch labels.

``owners`` maps the clusters back onto tracks through the anchors (module doc of
``mlkm_core.streaming``).
"""

from __future__ import annotations

import bisect
import math
import warnings

import numpy as np

from mlkm_core.associators.base import Associator, DegradedResultWarning, canonical_order
from mlkm_core.associators.likelihood import total_nll
from mlkm_core.associators.linking import link
from mlkm_core.associators.motion import MotionParams
from mlkm_core.associators.multiframe import DUAL_START_MAX
from mlkm_core.associators.search import refine
from mlkm_core.types import Detections, Layout

#: methods the window solve runs natively with the tracker's calibrated motion model
NATIVE = ('assignment', 'multiframe')


def _multiframe(layout: Layout, d: Detections, params: MotionParams, budget: int) -> np.ndarray:
    """The ``multiframe`` search with given parameters on ``d`` (canonical order); raw ids."""
    best, best_nll, pairwise = None, math.inf, None
    starts = ('kalman', 'pairwise') if len(d) <= DUAL_START_MAX else ('kalman',)
    with np.errstate(all='ignore'):
        for model in starts:
            start = link(layout, d, params, model)
            if model == 'pairwise':
                pairwise = start
            result = refine(layout, d, start, params, budget=budget)
            nll = total_nll(layout, d, result.labels, params)
            if math.isfinite(nll) and nll < best_nll:
                best, best_nll = result.labels, nll
    if best is None:
        best = pairwise if pairwise is not None else link(layout, d, params, 'pairwise')
    return best


def solve_window(
    associator: Associator,
    layout: Layout,
    d: Detections,
    params: MotionParams | None,
) -> tuple[np.ndarray, int]:
    """(cluster of each detection of ``d``, -1 = alone; count of degraded-result warnings).

    ``params`` None: the method's own batch ``associate``. A method that cannot associate the
    window (ValueError) is replaced by the sequential assignment for that window.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always', DegradedResultWarning)
        if params is not None and associator.name in NATIVE:
            order = canonical_order(d)
            dd = d.subset(order)
            if associator.name == 'assignment':
                raw = link(layout, dd, params, 'pairwise')
            else:
                raw = _multiframe(layout, dd, params, associator.config.search_budget)
            labels = np.empty(len(d), np.int64)
            labels[order] = raw
        else:
            n_targets = int(np.bincount(d.sensor_index).max()) if len(d) else 1
            try:
                labels = associator.associate(layout, d, n_targets)
            except ValueError:
                labels = None
            if labels is None:
                order = canonical_order(d)
                labels = np.empty(len(d), np.int64)
                labels[order] = link(layout, d.subset(order), params or MotionParams())
                caught.append(None)
    degraded = sum(1 for w in caught if w is None or issubclass(w.category, DegradedResultWarning))
    return np.asarray(labels, np.int64), degraded


def owners(
    labels: np.ndarray,
    sensor: np.ndarray,
    anchor_track: np.ndarray,
    last_anchor: np.ndarray,
    occupied: dict[int, set[int]],
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Map window clusters onto tracks.

    Rows are the solve's detections; ``anchor_track`` is the track of an anchor (-1 for a
    window detection), ``last_anchor`` marks each track's most downstream committed
    detection, ``occupied`` holds the stations of each track's committed detections. A
    cluster holding the last anchors of tracks at stations s_1 < s_2 < ... gives a window
    detection at station s to the track of the largest s_j <= s (the first track for
    s < s_1), unless that track already has a detection at s; the other window detections
    of the cluster form a new group (as do clusters without a last anchor).

    Returns (track of each window row or -1, groups of window rows without a track).
    """
    n = labels.size
    owner = np.full(n, -1, np.int64)
    clusters: dict[int, list[int]] = {}
    groups: list[np.ndarray] = []
    for i in range(n):
        if labels[i] >= 0:
            clusters.setdefault(int(labels[i]), []).append(i)
        elif anchor_track[i] < 0:
            groups.append(np.array([i], np.int64))
    for members in clusters.values():
        heads = sorted((int(sensor[i]), int(anchor_track[i])) for i in members if last_anchor[i])
        starts = [h[0] for h in heads]
        used = {t: set(occupied.get(t, ())) for _, t in heads}
        rest = []
        for i in sorted(members, key=lambda i: sensor[i]):
            if anchor_track[i] >= 0:
                continue
            s = int(sensor[i])
            if heads:
                track = heads[max(bisect.bisect_right(starts, s) - 1, 0)][1]
                if s not in used[track]:
                    owner[i] = track
                    used[track].add(s)
                    continue
            rest.append(i)
        if rest:
            groups.append(np.array(rest, np.int64))
    return owner, groups
