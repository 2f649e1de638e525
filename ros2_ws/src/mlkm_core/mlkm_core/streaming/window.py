"""One window solve: a batch associator on a window of detections plus anchors.

``solve_window`` runs the method's own ``associate`` (every registered method: the
associators calibrate their model on what they are given, use lane and length where known,
and ``multiframe`` runs its Kalman pass and multi-frame local search inside the window) with
the number of targets taken from the window (its largest per-station count).

``owners`` maps the clusters back onto tracks through the anchors (module doc of
``mlkm_core.streaming``).
"""

from __future__ import annotations

import bisect
import warnings

import numpy as np

from mlkm_core.associators.base import Associator, DegradedResultWarning, canonical_order
from mlkm_core.associators.linking import link
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Detections, Layout


def solve_window(
    associator: Associator, layout: Layout, d: Detections, motion: MotionParams | None = None
) -> tuple[np.ndarray, int, bool]:
    """(cluster of each detection of ``d``, -1 = alone; degraded-result warnings; failed).

    ``motion``: the model a calibrating associator uses instead of calibrating on ``d``
    (bound to ``d`` in canonical order). A method that cannot associate the window
    (ValueError) is replaced by the sequential assignment with generic parameters for that
    window (``failed`` True).
    """
    extra = {} if motion is None else {'motion': motion}
    n_targets = int(np.bincount(d.sensor_index).max()) if len(d) else 1
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always', DegradedResultWarning)
        try:
            return (
                np.asarray(associator.associate(layout, d, n_targets, **extra), np.int64),
                sum(issubclass(w.category, DegradedResultWarning) for w in caught),
                False,
            )
        except ValueError:
            pass
    order = canonical_order(d)
    labels = np.empty(len(d), np.int64)
    labels[order] = link(layout, d.subset(order), MotionParams())
    return labels, 0, True


def owners(
    labels: np.ndarray,
    sensor: np.ndarray,
    stamp: np.ndarray,
    anchor_track: np.ndarray,
    last_anchor: np.ndarray,
    occupied: dict[int, set[int]],
    slack: float,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Map window clusters onto tracks.

    Rows are the solve's detections; ``anchor_track`` is the track of an anchor (-1 for a
    window detection), ``last_anchor`` marks each track's most downstream committed
    detection, ``occupied`` holds the stations of each track's committed detections. A
    cluster holding the last anchors of tracks at stations s_1 < s_2 < ... gives a window
    detection at station s to the track of the largest s_j <= s, unless that track has a
    committed detection at s (two window detections of a cluster at one station both join:
    a double report the method merged). A window detection upstream of every last anchor
    (s < s_1) joins the first track only if its stamp is at most ``slack`` [s] after that
    anchor's (stamps out of road order under noise). The other window detections of the
    cluster form a new group (as do clusters without a last anchor).

    Returns (track of each window row or -1, groups of window rows without a track).
    """
    n = labels.size
    owner = np.full(n, -1, np.int64)
    clusters: dict[int, list[int]] = {}
    groups: list[np.ndarray] = []
    for i in range(n):
        if labels[i] >= 0:
            clusters.setdefault(int(labels[i]), []).append(i)
        elif anchor_track[i] == -1:
            groups.append(np.array([i], np.int64))
    for members in clusters.values():
        heads = sorted(
            (int(sensor[i]), i, int(anchor_track[i])) for i in members if last_anchor[i]
        )
        starts = [h[0] for h in heads]
        rest = []
        for i in sorted(members, key=lambda i: sensor[i]):
            if anchor_track[i] != -1:
                continue
            s = int(sensor[i])
            if heads:
                j = bisect.bisect_right(starts, s) - 1
                _, head, track = heads[max(j, 0)]
                fits = j >= 0 or stamp[i] <= stamp[head] + slack
                if fits and s not in occupied.get(track, ()):
                    owner[i] = track
                    continue
            rest.append(i)
        if rest:
            groups.append(np.array(rest, np.int64))
    return owner, groups
