"""Extra travel time between stations: what the speeds measured at a gap's two ends do not show.

Two estimates from the tracks of a first pass, both kept in ``MotionParams.delay``
(``motion.GapDelays``):

* ``estimate_delay``: the mean extra time of a gap that the first pass could hardly link at all
  (road works, a standing queue: every vehicle is held up by about the same time, far beyond
  the gate);
* ``estimate_gap_spread``: the extra variance (and the shift) of a gap whose travel times
  scatter far more widely than the calibrated model allows (a queue with stop-and-go waves: a
  vehicle that meets a wave inside the gap stops, the next one may not, and the speeds at the
  two stations do not tell). Without it, the model's few-hundredths-of-a-second spread, fitted
  on the free-flowing rest of the road, makes any swap of two neighbours whose residuals
  happen to fit better look certain.

Where a lane ends inside such a gap, its cars' own delays are estimated by ``merges``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mlkm_core.model.gap_delays import GapDelays
from mlkm_core.model.motion import MotionParams, trapezoid_residual
from mlkm_core.types import Detections, Layout, link_pairs

#: a gap whose first-pass links join fewer than this fraction of its detections is searched
#: for an extra travel time
LINKED_FRACTION = 0.6
#: bin [s] of the histogram of travel-time residuals in which the extra time is the mode
DELAY_BIN = 1.0


def gap_links(layout: Layout, d: Detections, labels: np.ndarray) -> np.ndarray:
    """Links of ``labels`` across each gap between consecutive sensors."""
    a, b = link_pairs(d, labels)
    one = d.sensor_index[b] == d.sensor_index[a] + 1
    return np.bincount(d.sensor_index[a[one]], minlength=layout.n_sensors)[:-1]


def link_residuals(
    layout: Layout, d: Detections, a: np.ndarray, b: np.ndarray, p: MotionParams
) -> tuple[np.ndarray, np.ndarray]:
    """``motion.trapezoid_residual`` of the links from detections ``a`` to ``b``."""
    pos = layout.positions
    return trapezoid_residual(
        p,
        pos[d.sensor_index[a]],
        pos[d.sensor_index[b]],
        d.stamp[a],
        d.stamp[b],
        1.0 / d.velocity[a],
        1.0 / d.velocity[b],
    )


def robust_location(e: np.ndarray) -> tuple[float, float]:
    """Median and squared robust spread (1.4826 median absolute deviation) of ``e``: the few
    wrong links of a first pass do not count."""
    med = float(np.median(e))
    return med, (1.4826 * float(np.median(np.abs(e - med)))) ** 2


def estimate_delay(layout: Layout, d: Detections, labels: np.ndarray) -> GapDelays | None:
    """Extra travel time of the gaps the first pass could not link (``MotionParams.delay``).

    Where the speeds at both ends of a gap do not show a slowdown between them (road works, a
    queue), the predicted travel times are short by about the same amount for every vehicle
    and the gate breaks nearly every track there. For such a gap, the residuals of the
    predicted travel time over all pairs of detections at its two ends pile up at the true
    extra time (the right pairs) over a flat background (the wrong ones): their mode, refined
    by the median of the residuals within two bins of it.
    """
    n_s = layout.n_sensors
    if n_s < 2 or len(d) == 0:
        return None
    pos = layout.positions
    links = gap_links(layout, d, labels)
    count = np.bincount(d.sensor_index, minlength=n_s)
    extra = np.zeros(n_s - 1)
    u = 1.0 / d.velocity
    for g in range(n_s - 1):
        n = min(count[g], count[g + 1])
        if n < 10 or links[g] >= LINKED_FRACTION * n:
            continue
        ia = np.flatnonzero(d.sensor_index == g)
        ib = np.flatnonzero(d.sensor_index == g + 1)
        dx = pos[g + 1] - pos[g]
        r = (d.stamp[ib][None, :] - d.stamp[ia][:, None]) - dx * (
            u[ia][:, None] + u[ib][None, :]
        ) / 2
        base = dx * np.median(u[ia])
        r = r[(r > -0.5 * base) & (r < min(3 * base, 600.0))]
        if r.size < 10:
            continue
        edges = np.arange(r.min(), r.max() + DELAY_BIN, DELAY_BIN)
        if edges.size < 3:
            continue
        hist, _ = np.histogram(r, edges)
        smooth = np.convolve(hist, np.ones(3), mode='same')
        peak = edges[int(np.argmax(smooth))] + DELAY_BIN / 2
        near = r[np.abs(r - peak) <= 2 * DELAY_BIN]
        extra[g] = float(np.median(near))
    if not np.any(extra):
        return None
    return GapDelays.per_gap(pos, extra, np.zeros_like(extra))


#: a gap gets a variance of its own where the robust spread of its travel-time residuals is
#: this many times the model's (the product's own simulator and free-flowing SUMO traffic stay
#: well within it; in stop-and-go traffic the gaps of the queue are 3 to 30 times wider)
SPREAD_RATIO = 2.0
#: ... and wider than this [s] (a gap of a few metres leaves the model nearly no spread)
MIN_SPREAD = 0.05
#: links across a gap needed to judge its spread
MIN_GAP_LINKS = 20


def estimate_gap_spread(
    layout: Layout, d: Detections, labels: np.ndarray, p: MotionParams
) -> MotionParams:
    """``p`` with the extra variance and shift of the gaps whose travel times scatter widely.

    For each gap between consecutive sensors, the residuals of the links of ``labels`` across
    it (the trapezoid travel time and the delays of ``p`` taken off) give a robust location
    (median) and spread (1.4826 median absolute deviation, so that the few wrong links of the
    first pass do not count); where the spread exceeds ``SPREAD_RATIO`` times the model's own
    (the median of the pairwise model's travel-time variance over those links) and
    ``MIN_SPREAD``, the gap gets the excess variance and its median as an extra time. Other gaps
    are left as they are.
    """
    n_s = layout.n_sensors
    if n_s < 2 or len(d) == 0:
        return p
    a, b = link_pairs(d, labels)
    one = d.sensor_index[b] == d.sensor_index[a] + 1
    a, b = a[one], b[one]
    if a.size == 0:
        return p
    e_t, model = link_residuals(layout, d, a, b, p)
    gap = d.sensor_index[a]
    shift, var = np.zeros(n_s - 1), np.zeros(n_s - 1)
    for g in np.unique(gap):
        k = gap == g
        if k.sum() < MIN_GAP_LINKS:
            continue
        med, spread2 = robust_location(e_t[k])
        own = float(np.median(model[k]))
        if spread2 > SPREAD_RATIO**2 * own and spread2 > MIN_SPREAD**2:
            shift[g], var[g] = med, spread2 - own
    if not var.any():
        return p
    old = p.delay
    profiles = ()
    if old is not None:
        shift, var, profiles = shift + old.gap_time, var + old.gap_var, old.profiles
    return replace(p, delay=GapDelays.per_gap(layout.positions, shift, var, profiles))
