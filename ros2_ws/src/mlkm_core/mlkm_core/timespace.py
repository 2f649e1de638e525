"""The time-space diagram's data: what ``mlkm plot`` draws, computed without drawing anything.

The picture traffic engineers read: time on x, the position along the road on y. Each
track is a polyline through its detections in the order of the road (by position, then
stamp, as :mod:`mlkm_core.metrics` orders a sequence); each of its pieces is a *link* of
two consecutive detections of one track. Detections no track took (label -1) are crosses.

Where ground truth is known, a link is *wrong* when its two detections do not belong to the
same true target: two different targets, or a false alarm (target -1, no target at all) on
either end. Every other link joins two detections of one vehicle. A detection whose truth
is missing (target :data:`NO_TRUTH`, e.g. a bag that lost the message) makes no link wrong.

Plain numpy, so that the figure's content can be checked (counts, which links are red)
without matplotlib; the drawing is ``mlkm_assoc.timespace_plot``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlkm_core.types import FALSE_ALARM, UNASSIGNED

#: ``target`` of a detection whose ground truth is not known: its links are never wrong.
NO_TRUTH = -2


@dataclass(frozen=True)
class TimeSpace:
    """The figure's content. Times in the unit of the stamps given [s], positions [m]."""

    #: Links as line segments, shape (L, 2, 2): ``[[t_a, y_a], [t_b, y_b]]``, the earlier
    #: detection along the road first; ordered by track, then along the road, so that the
    #: links of one track follow each other end to start.
    links: np.ndarray
    #: Track label of each link, shape (L,).
    link_track: np.ndarray
    #: Each link joins detections of two different true targets (or a false alarm), shape
    #: (L,); all False without ground truth.
    wrong: np.ndarray
    #: (t, y) of every assigned detection, shape (A, 2), and its track label, shape (A,).
    points: np.ndarray
    point_track: np.ndarray
    #: (t, y) of every unassigned detection, shape (U, 2).
    crosses: np.ndarray
    #: Distinct track labels (>= 0), sorted.
    tracks: np.ndarray
    #: Ground truth was given.
    has_truth: bool

    @property
    def n_wrong(self) -> int:
        return int(np.count_nonzero(self.wrong))


def time_space(
    position: np.ndarray,
    stamp: np.ndarray,
    labels: np.ndarray,
    target: np.ndarray | None = None,
) -> TimeSpace:
    """The diagram of detections at ``position`` [m], ``stamp`` [s] with track ``labels``
    (-1 = unassigned) and, when known, true ``target`` ids (-1 = false alarm, -2 = not known).

    Raises ValueError when the arrays are not 1-D of one length or hold a non-finite value.
    """
    position = np.asarray(position, dtype=float)
    stamp = np.asarray(stamp, dtype=float)
    labels = np.asarray(labels, dtype=np.int64)
    n = position.size
    arrays = [('position', position), ('stamp', stamp), ('labels', labels)]
    if target is not None:
        target = np.asarray(target, dtype=np.int64)
        arrays.append(('target', target))
    for name, values in arrays:
        if values.shape != (n,):
            raise ValueError(f'{name} must be 1-D with one entry per detection ({n})')
    if not (np.all(np.isfinite(position)) and np.all(np.isfinite(stamp))):
        raise ValueError('positions and stamps must be finite')
    assigned = np.flatnonzero(labels != UNASSIGNED)
    if np.any(labels[assigned] < 0):
        raise ValueError(f'track labels must be >= 0, or {UNASSIGNED} for unassigned')
    order = assigned[np.lexsort((stamp[assigned], position[assigned], labels[assigned]))]
    same = labels[order[1:]] == labels[order[:-1]]
    a, b = order[:-1][same], order[1:][same]
    tp = np.column_stack([stamp, position])
    links = np.stack([tp[a], tp[b]], axis=1) if a.size else np.zeros((0, 2, 2))
    if target is None:
        wrong = np.zeros(a.size, dtype=bool)
    else:
        wrong = ((target[a] != target[b]) | (target[a] == FALSE_ALARM)) & (
            (target[a] != NO_TRUTH) & (target[b] != NO_TRUTH)
        )
    unassigned = labels == UNASSIGNED
    return TimeSpace(
        links=links,
        link_track=labels[a],
        wrong=wrong,
        points=tp[assigned],
        point_track=labels[assigned],
        crosses=tp[unassigned],
        tracks=np.unique(labels[assigned]),
        has_truth=target is not None,
    )
