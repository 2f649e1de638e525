"""Lane and vehicle length in the link likelihood (loop detectors report both).

A vehicle's measured length is nearly constant from station to station (up to the sensor's
length noise sigma_l) and it keeps its lane between nearby stations unless it changes lane
(probability p_g for the gap g between stations g and g + 1). Neither is a hard constraint:
each enters the cost of a link as a bounded log-likelihood *ratio* against the population
(what a detection's lane and length would look like if it were not the track's), so a
detection that starts a track pays nothing extra, and a term with an unknown value (lane -1,
length NaN) vanishes.

* Length: the track's length estimate is the mean of its n known lengths (``accumulate``; the
  pairwise model keeps only the last one, n = 1); the predictive density of the new length is
  N(mean, sigma_l^2 (1 + 1/n)), mixed with a fraction ``length_outlier`` eps of the
  population density p_pop (a kernel density over the observed lengths with bandwidth
  sqrt(2) sigma_l, so that discrete lengths get their frequency). Cost
  -log((1 - eps) N / p_pop + eps) <= -log eps.
* Order within a lane (``laneorder``, in queues only): a same-lane link across a gap whose
  travel times cannot tell neighbours in the lane apart is scored by its rank in the lane.
* Lane: over the gaps from the track's last known lane (lane a, station s_a) to station s_b,
  stay = prod (1 - p_g). Same lane: ratio stay / P_pop(a at s_b); another lane (chosen like
  the population among the other lanes): ratio (1 - stay) / (1 - P_pop(a at s_b)). P_pop is
  the lane frequency per station (Laplace-smoothed).

``estimate_attributes`` fits sigma_l, eps and p_g from the links of a first pass (moments with
a robust scale; p_g shrunk to a distance-proportional rate fitted over all gaps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from mlkm_core.associators.base import link_pairs
from mlkm_core.associators.laneorder import LaneOrder
from mlkm_core.types import Detections, Layout

#: floor of the length noise [m] (lengths may be reported exactly)
FLOOR_LENGTH = 0.05
#: bounds of the fraction of length outliers and of a lane change probability per gap
OUTLIER_BOUNDS = (1e-3, 0.05)
CHANGE_BOUNDS = (1e-3, 0.95)
#: weight (in links) of the distance-proportional prior of a gap's lane-change probability
CHANGE_PRIOR_LINKS = 10.0
#: lengths used for the population density
POP_SAMPLE = 2000


@dataclass(frozen=True)
class AttributeParams:
    """Parameters of the lane and length terms."""

    length_noise: float = 0.3  # sigma_l [m]
    length_outlier: float = 0.01  # eps, fraction of unrelated length measurements
    change_rate: float = 1e-4  # lane changes per metre (prior of every gap)
    change: np.ndarray | None = None  # p_g per gap (n_sensors - 1,), None = from the rate


class Attributes:
    """Lane and length evidence of one set of detections under ``AttributeParams``."""

    def __init__(
        self,
        layout: Layout,
        d: Detections,
        params: AttributeParams,
        order: LaneOrder | None = None,
    ) -> None:
        self.params = params
        self.order = order
        n = len(d)
        self.lane = np.full(n, -1, np.int64) if d.lane is None else d.lane.copy()
        self.length = np.full(n, np.nan) if d.length is None else d.length.astype(float)
        self.sensor = d.sensor_index
        n_s = layout.n_sensors
        gaps = np.diff(layout.positions)
        p = params.change
        if p is None or p.shape != gaps.shape:
            p = 1 - np.exp(-params.change_rate * gaps)
        p = np.clip(p, *CHANGE_BOUNDS)
        self.log_stay = np.concatenate([[0.0], np.cumsum(np.log1p(-p))])
        # lane frequency per station
        known = self.lane >= 0
        n_lanes = int(self.lane[known].max()) + 1 if known.any() else 1
        counts = np.zeros((n_s, n_lanes))
        np.add.at(counts, (self.sensor[known], self.lane[known]), 1.0)
        width = np.zeros(n_s, np.int64)
        np.maximum.at(width, self.sensor[known], self.lane[known] + 1)
        present = np.arange(n_lanes)[None, :] < width[:, None]
        counts = counts + present
        self.pop_lane = counts / np.maximum(counts.sum(axis=1, keepdims=True), 1.0)
        # population density of the length, per detection
        self.log_pop_len = np.zeros(n)
        lk = np.flatnonzero(np.isfinite(self.length))
        if lk.size:
            ref = self.length[lk]
            if ref.size > POP_SAMPLE:
                ref = np.sort(np.random.default_rng(0).choice(ref, POP_SAMPLE, replace=False))
            bw = math.sqrt(2.0) * max(params.length_noise, FLOOR_LENGTH)
            dens = np.empty(lk.size)
            for i in range(0, lk.size, 2000):
                z = (self.length[lk[i : i + 2000], None] - ref[None, :]) / bw
                dens[i : i + 2000] = np.exp(-0.5 * z * z).mean(axis=1)
            self.log_pop_len[lk] = np.log(dens / (bw * math.sqrt(2 * math.pi)) + 1e-300)
        self.active = bool(known.any() or lk.size or order is not None)

    def tracker(self, accumulate: bool) -> TrackAttributes:
        return TrackAttributes(self, accumulate)


@dataclass
class AttributeState:
    """Per track: last known lane and its station, sum and count of known lengths."""

    lane: np.ndarray
    sensor: np.ndarray
    lsum: np.ndarray
    lcnt: np.ndarray
    det: np.ndarray  # last detection

    @staticmethod
    def empty(n: int) -> AttributeState:
        return AttributeState(
            np.full(n, -1, np.int64),
            np.zeros(n, np.int64),
            np.zeros(n),
            np.zeros(n),
            np.zeros(n, np.int64),
        )

    def take(self, rows: np.ndarray) -> AttributeState:
        return AttributeState(*(getattr(self, f.name)[rows] for f in fields(self)))

    def copy(self) -> AttributeState:
        return AttributeState(*(getattr(self, f.name).copy() for f in fields(self)))


class TrackAttributes:
    """Lane and length state of many tracks (ids 0..n-1), parallel to a motion model."""

    def __init__(self, attrs: Attributes, accumulate: bool) -> None:
        self.a = attrs
        self.accumulate = accumulate
        self.state = AttributeState.empty(0)

    def grow(self, n: int) -> None:
        e = AttributeState.empty(n)
        s = self.state
        self.state = AttributeState(
            *(np.concatenate([getattr(s, f.name), getattr(e, f.name)]) for f in fields(s))
        )

    def load(self, state: AttributeState) -> None:
        self.state = state.copy()

    def start(self, tracks: np.ndarray, det: np.ndarray) -> None:
        s, a = self.state, self.a
        s.lane[tracks] = a.lane[det]
        s.sensor[tracks] = a.sensor[det]
        ln = a.length[det]
        known = np.isfinite(ln)
        s.lsum[tracks] = np.where(known, ln, 0.0)
        s.lcnt[tracks] = known.astype(float)
        s.det[tracks] = det

    def cost(self, tracks: np.ndarray, det: np.ndarray) -> np.ndarray:
        """NLL ratio of detection det[i] joining track tracks[i] (0 when unknown)."""
        s, a, p = self.state, self.a, self.a.params
        out = np.zeros(det.size)
        if a.order is not None:
            out += a.order.cost(s.det[tracks], det)
        # length
        cnt = s.lcnt[tracks]
        ln = a.length[det]
        ok = (cnt > 0) & np.isfinite(ln)
        if ok.any():
            sl = max(p.length_noise, FLOOR_LENGTH)
            var = sl * sl * (1 + 1 / cnt[ok])
            e = ln[ok] - s.lsum[tracks[ok]] / cnt[ok]
            log_n = -0.5 * (e * e / var + np.log(2 * math.pi * var))
            eps = p.length_outlier
            out[ok] -= np.logaddexp(
                math.log1p(-eps) + log_n - a.log_pop_len[det[ok]], math.log(eps)
            )
        # lane
        la, lb = s.lane[tracks], a.lane[det]
        ok = (la >= 0) & (lb >= 0)
        if ok.any():
            sb = a.sensor[det[ok]]
            # either direction along the road (mlkm_robust also matches backwards)
            stay = np.exp(-np.abs(a.log_stay[sb] - a.log_stay[s.sensor[tracks[ok]]]))
            lane_a = la[ok]
            inside = lane_a < a.pop_lane.shape[1]
            pop_a = np.where(
                inside, a.pop_lane[sb, np.minimum(lane_a, a.pop_lane.shape[1] - 1)], 0
            )
            pop_a = np.clip(pop_a, 1e-6, 1 - 1e-6)
            ratio = np.where(lane_a == lb[ok], stay / pop_a, (1 - stay) / (1 - pop_a))
            out[ok] -= np.log(np.maximum(ratio, 1e-300))
        return out

    def update(self, tracks: np.ndarray, det: np.ndarray) -> None:
        s, a = self.state, self.a
        s.det[tracks] = det
        lb = a.lane[det]
        known = lb >= 0
        s.lane[tracks[known]] = lb[known]
        s.sensor[tracks[known]] = a.sensor[det[known]]
        ln = a.length[det]
        known = np.isfinite(ln)
        tk = tracks[known]
        if self.accumulate:
            s.lsum[tk] += ln[known]
            s.lcnt[tk] += 1.0
        else:
            s.lsum[tk] = ln[known]
            s.lcnt[tk] = 1.0


def has_attributes(d: Detections) -> bool:
    lane = d.lane is not None and bool(np.any(d.lane >= 0))
    length = d.length is not None and bool(np.any(np.isfinite(d.length)))
    return lane or length


def estimate_attributes(
    layout: Layout, d: Detections, labels: np.ndarray, base: AttributeParams | None = None
) -> AttributeParams:
    """Length noise, length outlier fraction and lane-change probabilities from the links of
    the tracks ``labels`` (a first pass; robust to a few wrong links)."""
    base = base or AttributeParams()
    a, b = link_pairs(d, labels)
    noise, outlier, rate, change = base.length_noise, base.length_outlier, base.change_rate, None
    if d.length is not None:
        ok = np.isfinite(d.length[a]) & np.isfinite(d.length[b])
        dl = (d.length[b] - d.length[a])[ok]
        if dl.size >= 10:
            # robust scale of the difference of two measurements: MAD / 0.6745 / sqrt(2)
            mad = float(np.median(np.abs(dl - np.median(dl))))
            noise = max(mad / 0.6745 / math.sqrt(2), FLOOR_LENGTH)
            far = np.abs(dl) > 5 * math.sqrt(2) * noise
            outlier = float(np.clip(far.mean(), *OUTLIER_BOUNDS))
    if d.lane is not None:
        ok = (d.lane[a] >= 0) & (d.lane[b] >= 0)
        a2, b2 = a[ok], b[ok]
        if a2.size >= 10:
            pos = layout.positions
            changed = d.lane[a2] != d.lane[b2]
            dx = pos[d.sensor_index[b2]] - pos[d.sensor_index[a2]]
            rate = max(float(changed.sum()) / max(float(dx.sum()), 1.0), 1e-7)
            gaps = np.diff(pos)
            prior = 1 - np.exp(-rate * gaps)
            one = d.sensor_index[b2] - d.sensor_index[a2] == 1
            g = d.sensor_index[a2[one]]
            n_g = np.bincount(g, minlength=gaps.size).astype(float)
            c_g = np.bincount(g, changed[one], minlength=gaps.size)
            k = CHANGE_PRIOR_LINKS
            change = np.clip((c_g + k * prior) / (n_g + k), *CHANGE_BOUNDS)
    return AttributeParams(noise, outlier, rate, change)
