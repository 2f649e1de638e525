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
* ``estimate_lane_delays``: in such a gap, an extra time and variance per lane where the lanes
  differ by more than their spread (a lane that ends before the next station: its vehicles pass
  the station before the merge at speed, then wait seconds for a gap in the queue, while the
  others roll on). ``relink_lane_delays`` re-decides the links across those gaps with them.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mlkm_core.associators.base import link_pairs
from mlkm_core.associators.linking import gate_pairs, match_sparse
from mlkm_core.associators.motion import (
    GapDelays,
    MotionParams,
    PairwiseModel,
    trapezoid_residual,
)
from mlkm_core.types import Detections, Layout

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
    pos = layout.positions
    e_t, model = trapezoid_residual(
        p,
        pos[d.sensor_index[a]],
        pos[d.sensor_index[b]],
        d.stamp[a],
        d.stamp[b],
        1.0 / d.velocity[a],
        1.0 / d.velocity[b],
    )
    gap = d.sensor_index[a]
    shift, var = np.zeros(n_s - 1), np.zeros(n_s - 1)
    for g in np.unique(gap):
        k = gap == g
        if k.sum() < MIN_GAP_LINKS:
            continue
        med = float(np.median(e_t[k]))
        spread2 = (1.4826 * float(np.median(np.abs(e_t[k] - med)))) ** 2
        own = float(np.median(model[k]))
        if spread2 > SPREAD_RATIO**2 * own and spread2 > MIN_SPREAD**2:
            shift[g], var[g] = med, spread2 - own
    if not var.any():
        return p
    old = p.delay
    if old is not None:
        shift, var = shift + old.gap_time, var + old.gap_var
    return replace(p, delay=GapDelays.per_gap(pos, shift, var))


#: a queue gap gets an extra time per lane where the medians of the lanes' travel-time
#: residuals lie further apart than this many times the widest lane's spread (SUMO's lane drops:
#: the closing lane is held up 2-4 s more than the lane it merges into, with spreads of 0.4-1 s;
#: where waves scatter every lane by seconds, the lanes' medians do not separate them)
LANE_SEPARATION = 1.0
#: links out of a lane needed to judge its extra time
MIN_LANE_LINKS = 10


def estimate_lane_delays(
    layout: Layout, d: Detections, labels: np.ndarray, p: MotionParams
) -> MotionParams:
    """``p`` with an extra time and variance per lane in the queue gaps where lanes differ.

    Only gaps that already carry a spread of their own (``estimate_gap_spread``) are judged.
    For each lane at the gap's first sensor with enough links in ``labels``, the residuals of
    those links (the trapezoid and the gap's own extra time taken off) give a robust location
    and spread, as for the whole gap. Where the lanes' locations lie further apart than
    ``LANE_SEPARATION`` times the widest spread, every such lane gets its own extra time (the
    gap's plus its location) and variance (its spread beyond the model's own) in
    ``GapDelays.lanes``; a lane with too few links keeps the gap's. Replaces any earlier
    per-lane estimate.
    """
    delay = p.delay
    if delay is None or d.lane is None or len(d) == 0:
        return p
    spread_gaps = np.flatnonzero(delay.gap_var > 0)
    lanes: list[tuple[int, int, float, float]] = []
    a, b = link_pairs(d, labels)
    one = (d.sensor_index[b] == d.sensor_index[a] + 1) & (d.lane[a] >= 0)
    a, b = a[one], b[one]
    pos = layout.positions
    e_t, model = trapezoid_residual(
        p,
        pos[d.sensor_index[a]],
        pos[d.sensor_index[b]],
        d.stamp[a],
        d.stamp[b],
        1.0 / d.velocity[a],
        1.0 / d.velocity[b],
    )
    for g in spread_gaps:
        rows = []
        in_gap = d.sensor_index[a] == g
        for lane in np.unique(d.lane[a[in_gap]]):
            k = in_gap & (d.lane[a] == lane)
            if k.sum() < MIN_LANE_LINKS:
                continue
            med = float(np.median(e_t[k]))
            spread2 = (1.4826 * float(np.median(np.abs(e_t[k] - med)))) ** 2
            own = float(np.median(model[k])) - delay.gap_var[g]
            rows.append((int(lane), med, spread2, own))
        if len(rows) < 2:
            continue
        med = np.array([r[1] for r in rows])
        widest = float(np.sqrt(max(r[2] for r in rows)))
        if med.max() - med.min() <= LANE_SEPARATION * widest:
            continue
        for lane, m, spread2, own in rows:
            lanes.append((int(g), lane, float(delay.gap_time[g] + m), max(spread2 - own, 0.0)))
    return replace(p, delay=replace(delay, lanes=tuple(lanes)))


def relink_lane_delays(
    layout: Layout, d: Detections, labels: np.ndarray, p: MotionParams
) -> np.ndarray:
    """Re-decide the links across the gaps with per-lane delays (``GapDelays.lanes``).

    For such a gap g, the detections at g that continue at g + 1 or end their track there are
    matched anew to the detections at g + 1 that follow one at g or start a track, as the
    pairwise pass matches them (optimal assignment, gated, against a miss and a new track), but
    with each link scored under the extra time and variance of the lane it leaves from. The
    detections after the gap follow the new links. Returns new labels; ``labels`` is left as it
    is.
    """
    out = labels.copy()
    delay = p.delay
    if delay is None or not delay.lanes or len(d) == 0:
        return out
    free = out < 0
    out[free] = out.max(initial=-1) + 1 + np.arange(int(free.sum()))
    pos = layout.positions
    u = 1.0 / d.velocity
    lane = np.full(len(d), -1, np.int64) if d.lane is None else d.lane
    for g in sorted({x[0] for x in delay.lanes}):
        own = {x[1]: delay.with_gap(g, x[2], x[3]) for x in delay.lanes if x[0] == g}
        n_lab = int(out.max()) + 1
        first = np.full(n_lab, np.iinfo(np.int64).max)
        last = np.full(n_lab, -1)
        np.minimum.at(first, out, d.sensor_index)
        np.maximum.at(last, out, d.sensor_index)
        a, b = link_pairs(d, out)
        across = (d.sensor_index[a] == g) & (d.sensor_index[b] == g + 1)
        at_g = np.flatnonzero((d.sensor_index == g) & (last[out] == g))
        at_h = np.flatnonzero((d.sensor_index == g + 1) & (first[out] == g + 1))
        up = np.unique(np.concatenate([a[across], at_g]))
        down = np.unique(np.concatenate([b[across], at_h]))
        if up.size == 0 or down.size == 0:
            continue
        rows, cols, weight = [], [], []
        attrs = p.attributes.tracker(accumulate=False) if p.attributes is not None else None
        if attrs is not None and attrs.a.active:
            attrs.grow(up.size)
            attrs.start(np.arange(up.size), up)
        else:
            attrs = None
        for ln in np.unique(lane[up]):
            i = np.flatnonzero(lane[up] == ln)
            m = PairwiseModel(replace(p, delay=own.get(int(ln), delay)))
            m.grow(up.size)
            m.start(i, pos[g], d.stamp[up[i]], u[up[i]])
            pred = m.predict(i, pos[g + 1])
            r, c = gate_pairs(*m.gate_window(pred), d.stamp[down])
            if r.size == 0:
                continue
            nll, d2 = m.cost(pred.take(r), d.stamp[down[c]], u[down[c]])
            if attrs is not None:
                nll = nll + attrs.cost(i[r], down[c])
            w = nll - p.miss_cost - p.new_cost
            rows.append(i[r])
            cols.append(c)
            weight.append(np.where(d2 <= p.gate, w, 0.0))
        if not rows:
            continue
        mr, mc = match_sparse(
            np.concatenate(rows), np.concatenate(cols), np.concatenate(weight), up.size, down.size
        )
        tails = [np.flatnonzero((out == out[x]) & (d.sensor_index > g)) for x in down]
        fresh = int(out.max()) + 1
        follow = dict(zip(mc.tolist(), mr.tolist(), strict=True))
        for j, tail in enumerate(tails):
            if j in follow:
                out[tail] = out[up[follow[j]]]
            else:
                out[tail] = fresh
                fresh += 1
    return out
