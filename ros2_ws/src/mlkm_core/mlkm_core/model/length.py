"""The vehicle-length cue: a vehicle's measured length is nearly constant between stations.

The track's length estimate is the mean of its n known lengths (a track of a filtering motion
model; one of the pairwise model keeps only the last one, n = 1). The predictive density of
the new length is N(mean, sigma_l^2 (1 + 1/n)), mixed with a fraction ``length_outlier`` eps
of the population density p_pop (a kernel density over the observed lengths with bandwidth
sqrt(2) sigma_l, so that discrete lengths get their frequency). Cost
-log((1 - eps) N / p_pop + eps) <= -log eps; an unknown length (NaN) costs nothing.

``fit`` estimates sigma_l and eps from the links of a pass (a robust scale of the length
differences; eps from those beyond 5 standard deviations). Where most links join equal lengths
(the MAD is 0: lengths reported exactly, to their resolution, as trajectories and simulators
give them), sigma_l is the Gaussian noise whose differences reach half a resolution step as
often as the links' lengths differ by about one step (``exact_noise``): one step apart is then
a different vehicle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from mlkm_core.model.cues import Cue, CueKind, CueTracks
from mlkm_core.types import Detections, Layout, link_pairs

#: floor of the length noise [m] (lengths may be reported exactly)
FLOOR_LENGTH = 0.001
#: bounds of the fraction of length outliers
OUTLIER_BOUNDS = (1e-3, 0.05)
#: lengths used for the population density
POP_SAMPLE = 2000


@dataclass(frozen=True)
class LengthParams:
    length_noise: float = 0.3  # sigma_l [m]
    length_outlier: float = 0.01  # eps, fraction of unrelated length measurements


class LengthCue(Cue):
    name = 'length'

    def __init__(self, d: Detections, params: LengthParams) -> None:
        self.params = params
        self.length = d.length.astype(float)
        n = len(d)
        # population density of the length, per detection
        self.log_pop_len = np.zeros(n)
        lk = np.flatnonzero(np.isfinite(self.length))
        ref = self.length[lk]
        if ref.size > POP_SAMPLE:
            ref = np.sort(np.random.default_rng(0).choice(ref, POP_SAMPLE, replace=False))
        bw = math.sqrt(2.0) * max(params.length_noise, FLOOR_LENGTH)
        dens = np.empty(lk.size)
        for i in range(0, lk.size, 2000):
            z = (self.length[lk[i : i + 2000], None] - ref[None, :]) / bw
            dens[i : i + 2000] = np.exp(-0.5 * z * z).mean(axis=1)
        self.log_pop_len[lk] = np.log(dens / (bw * math.sqrt(2 * math.pi)) + 1e-300)

    def tracks(self, accumulate: bool) -> LengthTracks:
        return LengthTracks(self, accumulate)


class LengthTracks(CueTracks):
    """Per track: the sum and the count of its known lengths."""

    FIELDS = {'lsum': (0.0, float), 'lcnt': (0.0, float)}

    def __init__(self, cue: LengthCue, accumulate: bool) -> None:
        super().__init__(accumulate)
        self.cue = cue

    def start(self, tracks: np.ndarray, det: np.ndarray) -> None:
        ln = self.cue.length[det]
        known = np.isfinite(ln)
        self.state['lsum'][tracks] = np.where(known, ln, 0.0)
        self.state['lcnt'][tracks] = known.astype(float)

    def cost(self, tracks: np.ndarray, det: np.ndarray) -> np.ndarray:
        c, p = self.cue, self.cue.params
        out = np.zeros(det.size)
        cnt = self.state['lcnt'][tracks]
        ln = c.length[det]
        ok = (cnt > 0) & np.isfinite(ln)
        if ok.any():
            sl = max(p.length_noise, FLOOR_LENGTH)
            var = sl * sl * (1 + 1 / cnt[ok])
            e = ln[ok] - self.state['lsum'][tracks[ok]] / cnt[ok]
            log_n = -0.5 * (e * e / var + np.log(2 * math.pi * var))
            eps = p.length_outlier
            out[ok] = -np.logaddexp(
                math.log1p(-eps) + log_n - c.log_pop_len[det[ok]], math.log(eps)
            )
        return out

    def update(self, tracks: np.ndarray, det: np.ndarray) -> None:
        ln = self.cue.length[det]
        known = np.isfinite(ln)
        tk = tracks[known]
        if self.accumulate:
            self.state['lsum'][tk] += ln[known]
            self.state['lcnt'][tk] += 1.0
        else:
            self.state['lsum'][tk] = ln[known]
            self.state['lcnt'][tk] = 1.0


def bind(layout: Layout, d: Detections, params: LengthParams) -> LengthCue | None:
    """The cue on ``d``; None when no length is known, or when the known lengths vary no more
    than their measurement noise (every car 4.8 m long): then they tell no vehicle from another,
    and a cue that carries no information must not weigh in the links (a constant cost per
    link would still shift every choice between a link and a new track)."""
    return bind_detections(d, params)


def bind_detections(d: Detections, params: LengthParams) -> LengthCue | None:
    """``bind`` on any detections: the cue needs no road (a road network's links too)."""
    if d.length is None:
        return None
    known = d.length[np.isfinite(d.length)]
    if known.size == 0 or float(np.std(known)) <= max(params.length_noise, FLOOR_LENGTH):
        return None
    return LengthCue(d, params)


def fit(
    layout: Layout, d: Detections, labels: np.ndarray, base: LengthParams | None = None
) -> LengthParams:
    """Length noise and outlier fraction from the links of the tracks ``labels`` (robust to a
    few wrong links); ``base`` (the generic values) where there are too few links."""
    if d.length is None:
        return base or LengthParams()
    a, b = link_pairs(d, labels)
    return fit_links(d, a, b, base)


def fit_links(
    d: Detections, a: np.ndarray, b: np.ndarray, base: LengthParams | None = None
) -> LengthParams:
    """``fit`` on the links ``a[k]`` -> ``b[k]`` (detection indexes), wherever they come from
    (a road network's links too)."""
    base = base or LengthParams()
    noise, outlier = base.length_noise, base.length_outlier
    if d.length is not None:
        ok = np.isfinite(d.length[a]) & np.isfinite(d.length[b])
        dl = (d.length[b] - d.length[a])[ok]
        if dl.size >= 10:
            # robust scale of the difference of two measurements: MAD / 0.6745 / sqrt(2)
            mad = float(np.median(np.abs(dl - np.median(dl))))
            if mad > 0:
                noise = max(mad / 0.6745 / math.sqrt(2), FLOOR_LENGTH)
            else:
                noise = exact_noise(d.length, dl)
            far = np.abs(dl) > 5 * math.sqrt(2) * noise
            outlier = float(np.clip(far.mean(), *OUTLIER_BOUNDS))
    return LengthParams(noise, outlier)


def resolution(length: np.ndarray) -> float:
    """The smallest step between the distinct known lengths [m] (at least ``FLOOR_LENGTH``):
    the reporting resolution, or the spacing of the length classes where there are few."""
    v = np.unique(length[np.isfinite(length)])
    steps = np.diff(v)
    return max(float(steps.min()) if steps.size else 0.0, FLOOR_LENGTH)


def exact_noise(length: np.ndarray, dl: np.ndarray) -> float:
    """sigma_l [m] where the links' length differences ``dl`` are mostly exactly 0: the noise
    whose difference of two measurements exceeds half the resolution step with the frequency f
    of the differences of about one step (0 < |dl| < 1.5 steps; at least one link's worth),
    sigma_l = step / (2 sqrt(2) z), z the standard normal quantile of 1 - f / 2. Larger
    differences are not noise but the links' outliers."""
    step = resolution(length)
    near = int(np.count_nonzero((dl != 0) & (np.abs(dl) < 1.5 * step)))
    f = max(near, 1) / dl.size
    z = float(NormalDist().inv_cdf(1.0 - f / 2.0))
    return max(step / (2.0 * math.sqrt(2.0) * z), FLOOR_LENGTH)


KIND = CueKind(
    'length',
    needs='known vehicle lengths that vary more than their noise',
    bind=bind,
    fit=fit,
    generic=LengthParams(),
)
