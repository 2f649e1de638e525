"""``mlkm_robust``: MLKM with its two greedy steps made optimal and clutter-tolerant.

Same three layers and the same segments as the paper's MLKM (``mlkm``); it reuses its Layer 1
(K-means++ on raw (v, t) per segment) and its Layer 2 error detection (the three rules). What
changes, and why:

* **Layer 2 correction by optimal assignment** instead of greedy nearest neighbour. The paper
  lets every detection of a flagged sensor take the cluster of the detection with the nearest
  predicted stamp at the neighbouring sensor, so two detections can take the same cluster and
  an error at one sensor propagates. Here the flagged sensor's detections are matched
  one-to-one to the reference sensor's (the next trusted or already corrected sensor, in the
  paper's order) with ``linear_sum_assignment`` on the pairwise travel-time and speed cost of
  ``assignment``, gated, with dummies: a detection left unmatched (its target was missed at
  the reference sensor, or it is a false alarm) opens a cluster of its own instead of being
  forced into a wrong one.
* **Layer 3 matched one-to-one** instead of K-means++ over projected centroids. K-means++ may
  put two clusters of one segment into one track and leave a track without a cluster in a
  segment; a constant-speed back-projection over the whole road is also wrong by the speed
  fluctuation. Here the clusters of consecutive segments are matched by a gated Hungarian
  assignment from the last detection of a track to the first detection of a cluster (same
  pairwise cost, dummies for a track missing a segment or a cluster starting a new track).
* **Counts that differ from N_A** (misses, false alarms) need no special case: dummies absorb
  them, and a track of a single detection is labelled UNASSIGNED (a false alarm).

Parameters: the variances of the pairwise cost are estimated from the data exactly as for
``assignment`` (``calibration.estimate_params``). The tracks then get the same corrections as
``assignment``'s: in queues, two consecutive vehicles of a lane whose links cross get their
order back (``laneorder.restore_order``), a lane change's two reports share a track
(``linking.merge_double_reports``), and a track that ends where no target can leave is joined
to one that starts downstream where none can enter when the whole-track cost favours it
(``linking.join_fragments``, with ``AssociatorConfig.entries`` / ``exits``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mlkm_core.associators.base import register
from mlkm_core.associators.kmeans import kmeans_labels
from mlkm_core.associators.linking import match_sparse
from mlkm_core.associators.mlkm import detect_errors
from mlkm_core.associators.repair import repaired
from mlkm_core.associators.tracking import TrackingAssociator
from mlkm_core.model.link import LinkModel
from mlkm_core.model.motion import MotionParams, PairwiseModel
from mlkm_core.progress import advance
from mlkm_core.types import Detections, Layout, segments


def _pair_weights(
    p: MotionParams,
    x1: np.ndarray,
    t1: np.ndarray,
    u1: np.ndarray,
    x2: float,
    t2: np.ndarray,
    u2: np.ndarray,
    skipped: np.ndarray | None = None,
    det1: np.ndarray | None = None,
    det2: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense gated weights between n1 'ends' and n2 detections at position x2 (or x2 < x1).

    ``det1``, ``det2``: the detections' indices in the data ``p.cues`` were bound to, to add
    the cues' costs (lane, length, ...) when both are given."""
    n1, n2 = t1.size, t2.size
    r = np.repeat(np.arange(n1), n2)
    c = np.tile(np.arange(n2), n1)
    rows = np.arange(n1)
    if np.all(x2 >= x1):
        m = LinkModel(p)
        m.grow(n1)
        m.start(rows, x1, t1, u1, det1)
        nll, d2 = m.motion_cost(m.predict(r, x2), t2[c], u2[c])
    else:  # backward: mirror the road (time and position change sign), extra times too
        m = LinkModel(p if p.delay is None else replace(p, delay=p.delay.mirrored()))
        m.grow(n1)
        m.start(rows, -x1, -t1, u1, det1)
        nll, d2 = m.motion_cost(m.predict(r, -x2), -t2[c], u2[c])
    extra = 0.0 if skipped is None else skipped[r] * p.miss_cost
    if det1 is not None and det2 is not None:
        extra = extra + m.cue_cost(r, det2[c])
    w = nll + extra - p.miss_cost - p.new_cost
    return r, c, np.where(d2 <= p.gate, w, 0.0)


def implausible_links(
    positions: np.ndarray, d: Detections, labels: np.ndarray, p: MotionParams
) -> frozenset[int]:
    """Rule 4 (added): a sensor whose detection is not a plausible successor of the previous
    detection of its cluster (pairwise travel-time and speed cost beyond the 6-sigma gate)."""
    order = np.lexsort((d.sensor_index, labels))
    lab, det = labels[order], order
    same = lab[1:] == lab[:-1]
    a, b = det[:-1][same], det[1:][same]
    if a.size == 0:
        return frozenset()
    m = PairwiseModel(p)
    m.grow(a.size)
    u = 1.0 / d.velocity
    m.start(np.arange(a.size), positions[d.sensor_index[a]], d.stamp[a], u[a])
    bad = np.zeros(a.size, bool)
    for s in np.unique(d.sensor_index[b]):
        k = np.flatnonzero(d.sensor_index[b] == s)
        _, d2 = m.cost(m.predict(k, float(positions[s])), d.stamp[b[k]], u[b[k]])
        bad[k] = d2 > p.gate
    return frozenset(int(s) for s in np.unique(d.sensor_index[b[bad]]))


def correct_by_assignment(
    positions: np.ndarray,
    d: Detections,
    labels: np.ndarray,
    flagged: frozenset[int],
    p: MotionParams,
    glob: np.ndarray | None = None,
) -> np.ndarray:
    """Layer 2 correction of the flagged sensors, one-to-one with dummies (module doc).

    ``glob`` maps the indices of ``d`` to those of the data ``p.cues`` were bound to."""
    labels = labels.copy()
    if not flagged or labels.size == 0:
        return labels
    sensors = np.unique(d.sensor_index)
    members = [np.flatnonzero(d.sensor_index == s) for s in sensors]
    trusted = np.array([int(s) not in flagged for s in sensors])
    if not trusted.any():
        spans = [np.unique(labels[m]).size for m in members]
        anchor = int(np.argmax(spans))
        trusted[anchor] = True
        # the anchor defines the clusters: one per detection (no shared cluster)
        labels[members[anchor]] = int(labels.max()) + 1 + np.arange(members[anchor].size)
    last = int(np.flatnonzero(trusted)[-1])
    next_label = int(labels.max()) + 1
    u = 1.0 / d.velocity

    def take(j: int, processed: np.ndarray, backward: bool) -> None:
        """Match sensor j's detections one-to-one to the cluster ends nearest to j among the
        processed sensors (a cluster missed at the neighbouring sensor is still reachable)."""
        nonlocal next_label
        mj = members[j]
        pool = (
            np.concatenate([members[k] for k in processed])
            if processed.size
            else (np.zeros(0, np.int64))
        )
        if pool.size:
            key = d.sensor_index[pool] if backward else -d.sensor_index[pool]
            pool = pool[np.argsort(key, kind='stable')]
            _, first = np.unique(labels[pool], return_index=True)
            ends = pool[first]
            skipped = np.abs(d.sensor_index[ends] - sensors[j]) - 1
            x_end = positions[d.sensor_index[ends]]
            r, c, w = _pair_weights(
                p,
                x_end,
                d.stamp[ends],
                u[ends],
                float(positions[sensors[j]]),
                d.stamp[mj],
                u[mj],
                skipped,
                None if glob is None else glob[ends],
                None if glob is None else glob[mj],
            )
            mr_i, mc_i = match_sparse(r, c, w, ends.size, mj.size)
        else:
            mr_i = mc_i = np.zeros(0, np.int64)
        new = np.full(mj.size, -1, dtype=np.int64)
        if mr_i.size:
            new[mc_i] = labels[ends[mr_i]]
        free = new < 0
        new[free] = np.arange(next_label, next_label + int(free.sum()))
        next_label += int(free.sum())
        labels[mj] = new

    for j in range(last - 1, -1, -1):
        if not trusted[j]:
            take(j, np.arange(j + 1, last + 1), backward=True)
    for j in range(last + 1, sensors.size):
        take(j, np.arange(0, j), backward=False)
    return labels


@register
class RobustMLKM(TrackingAssociator):
    name = 'mlkm_robust'
    progress_shares = (0.1, 0.99)  # the segments' K-means take the time (10^4 detections)

    def solve_segment(
        self,
        layout: Layout,
        d: Detections,
        n_targets: int,
        p: MotionParams,
        glob: np.ndarray | None = None,
    ) -> np.ndarray:
        """Layers 1 and 2 on one segment (``d`` in canonical order): local cluster labels;
        ``glob`` maps ``d``'s indices to those ``p.cues`` were bound to."""
        labels, _ = kmeans_labels(
            np.column_stack([d.velocity, d.stamp]), n_targets, 'k-means++', self.config.seed
        )
        errors = detect_errors(d.sensor_index, d.stamp, labels)
        flagged = errors.flagged | implausible_links(layout.positions, d, labels, p)
        labels = correct_by_assignment(layout.positions, d, labels, flagged, p, glob)
        return np.unique(labels, return_inverse=True)[1].reshape(-1)

    def track(
        self, layout: Layout, d: Detections, n_targets: int, p: MotionParams, given: bool
    ) -> np.ndarray:
        pos = layout.positions
        u = 1.0 / d.velocity
        track = np.full(len(d), -1, dtype=np.int64)
        # per track: last detection index, last segment
        end_det: list[int] = []
        end_seg: list[int] = []
        segs = list(segments(layout.n_sensors, self.config.segment_size))
        for e, seg in enumerate(segs):
            advance(e, len(segs))
            idx = np.flatnonzero(np.isin(d.sensor_index, seg))
            if idx.size == 0:
                continue
            local = self.solve_segment(layout, d.subset(idx), n_targets, p, idx)
            n_c = int(local.max()) + 1
            # first and last detection of each cluster (canonical order is by sensor, stamp)
            first = np.full(n_c, -1, dtype=np.int64)
            last = np.full(n_c, -1, dtype=np.int64)
            first[local[::-1]] = idx[::-1]
            last[local] = idx
            ids = np.full(n_c, -1, dtype=np.int64)
            ends = np.array(end_det, dtype=np.int64)
            active = np.flatnonzero(np.array(end_seg, dtype=np.int64) >= e - 2)
            if active.size:
                a_det = ends[active]
                # one Hungarian per first-sensor group keeps the pairwise cost exact
                for s in np.unique(d.sensor_index[first]):
                    cl = np.flatnonzero(d.sensor_index[first] == s)
                    ahead = d.sensor_index[a_det] < s
                    if not ahead.any():
                        continue
                    a_sel = active[ahead]
                    a_d = ends[a_sel]
                    skipped = np.maximum(s - 1 - d.sensor_index[a_d], 0)
                    r, c, w = _pair_weights(
                        p,
                        pos[d.sensor_index[a_d]],
                        d.stamp[a_d],
                        u[a_d],
                        float(pos[s]),
                        d.stamp[first[cl]],
                        u[first[cl]],
                        skipped,
                        a_d,
                        first[cl],
                    )
                    taken = np.array([ids[x] for x in range(n_c) if ids[x] >= 0])
                    if taken.size:
                        w = np.where(np.isin(a_sel[r], taken), 0.0, w)
                    mr, mc = match_sparse(r, c, w, a_sel.size, cl.size)
                    ids[cl[mc]] = a_sel[mr]
            for k in range(n_c):
                if ids[k] < 0:
                    ids[k] = len(end_det)
                    end_det.append(-1)
                    end_seg.append(e)
                end_det[ids[k]] = int(last[k])
                end_seg[ids[k]] = e
            track[idx] = ids[local]
        return repaired(layout, d, track, p)
