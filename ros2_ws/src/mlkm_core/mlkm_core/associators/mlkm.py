"""Multi-Layer K-means (MLKM), faithful to the paper, with and without error correction.

Layer 1 (segmentation and clustering): the sensors are split into E = ceil(N_S / K)
consecutive segments of K sensors (the last one shorter when K does not divide N_S); each
segment's detections are clustered with K-means++ into N_A clusters on raw (v, t).

Layer 2 (error detection and correction): three rules flag sensors whose measurements are
wrongly clustered; the flagged sensors' measurements are re-associated by nearest neighbour on
the predicted arrival time at the neighbouring sensor; centroids are recomputed.

Layer 3 (cluster matching): every segment centroid (v, t) is projected to the reference of the
first segment with the paper's preprocessing and the projected centroids are grouped with
K-means++ into N_A groups; a group is a track.

Registered methods: ``mlkm`` (with error correction) and ``mlkm_no_ec`` (Layer 2 skipped).

Readings of the paper
---------------------
Every place where the paper is ambiguous, and the reading implemented here:

1. Layer 1 features. "K-means++ is applied to each X_e without using pre-processing": raw
   (v, t) in their own units (m/s, s), no scaling, ``KMeans(init='k-means++', n_init=1,
   random_state=seed)``, k = N_A (capped by the segment's detection count).
2. Rule 1, "|Y_m^e| != m". Read as: a cluster of segment e must hold exactly one detection
   from each sensor of the segment (the segment's sensors are those with at least one
   detection in it). In a cluster of any other size, every sensor that appears in it a number
   of times other than once (zero, two or more) is flagged.
3. Rule 2, "p_i = p_j for i != j": a sensor with two or more detections in one cluster is
   flagged.
4. Rule 3, "for i >= j, t_i > t_j" is the law a cluster must obey (later sensor, later time).
   A detection at a sensor whose stamp is not later than the stamp of some detection of an
   upstream sensor in the same cluster violates it; the *downstream* sensor (the subject X_i of
   the rule) is flagged.
5. "The entire measurements from the same sensor" are then re-associated: flagging works per
   sensor of the segment, never per detection.
6. Error correction, argmin_k t_{l+1} - (t_l + |R_{l+1} - R_l| / v_l): read with an absolute
   value (the signed form would always choose the earliest stamp). Each detection of a flagged
   sensor takes the cluster of the detection of the neighbouring sensor whose stamp is
   closest to the predicted one (greedy nearest neighbour; two detections may choose the same
   neighbour, as in the paper). The neighbour is the next sensor downstream, as in the paper,
   and must itself be trusted: flagged sensors upstream of the last unflagged sensor are
   corrected from downstream to upstream, each against the next sensor (unflagged or already
   corrected); flagged sensors downstream of the last unflagged sensor have no trusted next
   sensor in the segment and are corrected against the previous sensor with the backward
   prediction t_{l-1} ~ t_l - |R_l - R_{l-1}| / v_l. If every sensor of a segment is flagged,
   the sensor whose Layer 1 labels span the most clusters (the upstream-most on ties) is
   trusted as the anchor. Correction stays inside the segment (the paper's Y^{e*} is a subset
   of X_e), which also keeps it incremental.
7. Centroids are recomputed as the mean (v, t) of each corrected cluster; a cluster left empty
   by the correction is dropped. Each centroid also carries the mean position of its
   detections, which is the position used to project it.
8. Layer 3 projection: t' = t_c - (R_c - R_ref) / v_c with R_c the centroid's mean sensor
   position and R_ref the position of the road's first sensor (the reference of the first
   segment, the paper's S_1); exact for a constant-speed target.
9. Layer 3 grouping, "referring the cluster centroids of all segments to the cluster centroid
   of the first segment and grouping them based on K-means++": the projected centroids of all
   segments are clustered on raw (v, t') by scikit-learn ``KMeans`` whose seeds are the first
   segment's projected centroids (``init`` = those centroids, ``n_init=1``). K-means++ seeding
   would pick one seed per cluster; the first segment already supplies exactly one centroid
   per target, so it is the reference the paper refers to and no random seeding is left.
   Track j is the group seeded by the first segment's cluster j (clusters are numbered by
   centroid time), so track ids are 0..c-1 and never change meaning when segments are added.
   As in the paper, this is not a one-to-one matching: two clusters of one segment may land
   in one track and a track may miss a segment. We keep that (``mlkm_robust`` matches
   one-to-one instead).
10. Incremental use (the live node): a new completed segment runs Layers 1 and 2 on its own
    detections only (cached) and Layer 3 is re-run on the centroids of that segment and of all
    the segments before it. Batch ``associate`` splits the detections into the same segments
    and runs Layer 3 once on all of them, so it equals the incremental result after the last
    segment exactly. Partial tracks may still be regrouped by a later Layer 3 run (the paper's
    Layer 3 is a joint clustering); their ids keep their meaning (reading 9).
11. Clutter (not in the paper): with misses or false alarms per-sensor counts differ from
    N_A; the rules and the correction still apply unchanged, and every detection (including
    false alarms) gets a track.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlkm_core.associators.base import Associator, Session, canonical_order, register
from mlkm_core.associators.kmeans import kmeans_labels
from mlkm_core.preprocess import back_project
from mlkm_core.types import Detections, Layout, segments


@dataclass(frozen=True)
class ErrorReport:
    """Sensors (layout indices) flagged by each Layer 2 rule in one segment."""

    size: frozenset[int]  # rule 1: cluster size differs from the segment's sensor count
    duplicate: frozenset[int]  # rule 2: two or more detections of one sensor in a cluster
    order: frozenset[int]  # rule 3: time not increasing along the road inside a cluster

    @property
    def flagged(self) -> frozenset[int]:
        return self.size | self.duplicate | self.order


def detect_errors(sensor_index: np.ndarray, stamp: np.ndarray, labels: np.ndarray) -> ErrorReport:
    """Apply the paper's three error-detection rules to one segment's clustering."""
    sensor_index = np.asarray(sensor_index, np.int64)
    if sensor_index.size == 0:
        return ErrorReport(frozenset(), frozenset(), frozenset())
    sensors, col = np.unique(sensor_index, return_inverse=True)
    clusters, row = np.unique(np.asarray(labels), return_inverse=True)
    shape = (clusters.size, sensors.size)
    count = np.zeros(shape, np.int64)
    np.add.at(count, (row, col), 1)
    tmin = np.full(shape, np.inf)
    tmax = np.full(shape, -np.inf)
    np.minimum.at(tmin, (row, col), stamp)
    np.maximum.at(tmax, (row, col), stamp)
    bad_size = count.sum(axis=1) != sensors.size
    rule1 = np.any((count[bad_size] != 1), axis=0)
    rule2 = np.any(count >= 2, axis=0)
    upstream_max = np.maximum.accumulate(tmax, axis=1)
    prev_max = np.concatenate([np.full((shape[0], 1), -np.inf), upstream_max[:, :-1]], axis=1)
    rule3 = np.any((count > 0) & (tmin <= prev_max), axis=0)

    def pick(mask: np.ndarray) -> frozenset[int]:
        return frozenset(int(s) for s in sensors[mask])

    return ErrorReport(pick(rule1), pick(rule2), pick(rule3))


def _nearest(reference: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Index into ``reference`` of the value nearest to each ``query`` value."""
    order = np.argsort(reference, kind='stable')
    ref = reference[order]
    pos = (
        np.clip(np.searchsorted(ref, query), 1, ref.size - 1)
        if ref.size > 1
        else (np.zeros(query.size, np.int64))
    )
    if ref.size > 1:
        left = ref[pos - 1]
        pos = np.where(np.abs(query - left) <= np.abs(ref[pos] - query), pos - 1, pos)
    return order[pos]


def correct_errors(
    positions: np.ndarray,
    sensor_index: np.ndarray,
    stamp: np.ndarray,
    velocity: np.ndarray,
    labels: np.ndarray,
    flagged: frozenset[int],
) -> np.ndarray:
    """Re-associate the flagged sensors' detections by nearest predicted arrival time.

    ``positions`` are the layout positions; returns new labels (see readings 6 in the module
    docstring).
    """
    labels = np.asarray(labels, np.int64).copy()
    if not flagged or labels.size == 0:
        return labels
    sensors = np.unique(sensor_index)
    members = [np.flatnonzero(sensor_index == s) for s in sensors]
    trusted = np.array([int(s) not in flagged for s in sensors])
    if not trusted.any():
        spans = [np.unique(labels[m]).size for m in members]
        anchor = int(np.argmax(spans))
        trusted[anchor] = True
        mem = members[anchor]
        first = np.zeros(mem.size, bool)
        first[np.unique(labels[mem], return_index=True)[1]] = True
        fresh = labels.max() + 1 + np.arange(int((~first).sum()))
        labels[mem[~first]] = fresh
    last = int(np.flatnonzero(trusted)[-1])

    def take(j: int, ref: int) -> None:
        dr = positions[sensors[j]] - positions[sensors[ref]]  # negative when ref is downstream
        predicted = stamp[members[j]] - dr / velocity[members[j]]
        near = _nearest(stamp[members[ref]], predicted)
        labels[members[j]] = labels[members[ref]][near]

    for j in range(last - 1, -1, -1):
        if not trusted[j]:
            take(j, j + 1)
    for j in range(last + 1, sensors.size):
        take(j, j - 1)
    return labels


@dataclass(frozen=True)
class SegmentClusters:
    """Result of Layers 1 and 2 on one segment, in the caller's detection order."""

    labels: np.ndarray  # local cluster 0..c-1 of each detection, numbered by centroid time
    centroids: np.ndarray  # (c, 3): mean velocity [m/s], mean stamp [s], mean position [m]
    errors: ErrorReport  # what Layer 2 detected (also filled when correction is off)


def solve_segment(
    layout: Layout, detections: Detections, n_targets: int, seed: int, error_correction: bool
) -> SegmentClusters:
    """Layers 1 and 2 on the detections of one segment."""
    order = canonical_order(detections)
    d = detections.subset(order)
    labels, _ = kmeans_labels(np.column_stack([d.velocity, d.stamp]), n_targets, 'k-means++', seed)
    errors = detect_errors(d.sensor_index, d.stamp, labels)
    if error_correction:
        labels = correct_errors(
            layout.positions, d.sensor_index, d.stamp, d.velocity, labels, errors.flagged
        )
    used, labels = np.unique(labels, return_inverse=True)
    pos = layout.positions[d.sensor_index]
    cnt = np.bincount(labels, minlength=used.size).astype(float)
    cent = (
        np.column_stack(
            [np.bincount(labels, w, minlength=used.size) / cnt for w in (d.velocity, d.stamp, pos)]
        )
        if used.size
        else (np.zeros((0, 3)))
    )
    by_time = np.argsort(cent[:, 1], kind='stable')
    rank = np.empty_like(by_time)
    rank[by_time] = np.arange(by_time.size)
    out = np.empty(len(detections), np.int64)
    out[order] = rank[labels]
    return SegmentClusters(out, cent[by_time], errors)


def match_segments(parts: list[SegmentClusters], ref_position: float) -> list[np.ndarray]:
    """Layer 3: project all segment centroids to ``ref_position``; group them by K-means
    seeded with the first (non-empty) segment's projected centroids (reading 9).

    Returns, per segment, the track id of each of its local clusters.
    """
    sizes = [len(p.centroids) for p in parts]
    if sum(sizes) == 0:
        return [np.zeros(0, np.int64) for _ in parts]
    cent = np.concatenate([p.centroids for p in parts])
    tproj = back_project(cent[:, 1], cent[:, 0], cent[:, 2], ref_position)
    points = np.column_stack([cent[:, 0], tproj])
    n_seeds = next(n for n in sizes if n > 0)
    start = sum(sizes[: next(e for e, n in enumerate(sizes) if n > 0)])
    seeds = points[start : start + n_seeds]
    if n_seeds == points.shape[0]:
        tracks = np.arange(n_seeds, dtype=np.int64)
    else:
        from sklearn.cluster import KMeans  # a second to import: on first use

        km = KMeans(n_clusters=n_seeds, init=seeds, n_init=1).fit(points)
        tracks = km.labels_.astype(np.int64)
    return np.split(tracks, np.cumsum(sizes)[:-1])


class MLKMSession(Session):
    """Layers 1 + 2 once per fed segment, Layer 3 over every segment so far."""

    def __init__(self, associator: MLKM, layout: Layout, n_targets: int) -> None:
        super().__init__(associator, layout, n_targets)
        self._mlkm = associator
        self._solved: list[SegmentClusters] = []

    def add_segment(self, detections: Detections) -> np.ndarray:
        self._parts.append(detections)
        self._solved.append(self._mlkm.solve_segment(self._layout, detections, self._n_targets))
        return self.labels()

    def labels(self) -> np.ndarray:
        """Track id of every detection fed so far, in the order fed."""
        return self._mlkm.label_parts(self._layout, self._solved)


class MLKM(Associator):
    """The paper's MLKM with error correction (Layer 2)."""

    name = 'mlkm'
    error_correction = True

    def solve_segment(
        self, layout: Layout, detections: Detections, n_targets: int
    ) -> SegmentClusters:
        return solve_segment(
            layout, detections, n_targets, self.config.seed, self.error_correction
        )

    def label_parts(self, layout: Layout, solved: list[SegmentClusters]) -> np.ndarray:
        """Layer 3 over solved segments; track id of each detection in segment order."""
        if not solved:
            return np.zeros(0, np.int64)
        tracks = match_segments(solved, float(layout.positions[0]))
        return np.concatenate([t[p.labels] for t, p in zip(tracks, solved)]).astype(np.int64)

    def associate(self, layout: Layout, detections: Detections, n_targets: int) -> np.ndarray:
        idx = [
            np.flatnonzero(np.isin(detections.sensor_index, seg))
            for seg in segments(layout.n_sensors, self.config.segment_size)
        ]
        solved = [self.solve_segment(layout, detections.subset(i), n_targets) for i in idx]
        labels = self.label_parts(layout, solved)
        out = np.full(len(detections), -1, np.int64)
        out[np.concatenate(idx)] = labels
        return out

    def session(self, layout: Layout, n_targets: int) -> MLKMSession:
        return MLKMSession(self, layout, n_targets)


register(MLKM)


@register
class MLKMNoEC(MLKM):
    """MLKM with Layer 2's error correction switched off."""

    name = 'mlkm_no_ec'
    error_correction = False
