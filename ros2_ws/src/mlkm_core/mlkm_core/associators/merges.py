"""A lane that ends between two stations: the merge, where a queue's cars are held up unevenly.

In a queue gap (``delays.estimate_gap_spread``) that holds a lane drop, the cars of the closing
lane pass the station before it at speed, then wait seconds for a gap to merge into, while the
lane they merge into rolls on; and the car that lets a merging car in right ahead of it is held
up too. One extra time and spread for the whole gap mixes these, and across such a gap the
pairwise pass exchanges the continuations of a merging car and its neighbour. Two laws, each
estimated from the tracks of a first pass and kept in ``MotionParams.delay``
(``motion.GapDelays``):

* ``estimate_lane_delays``: an extra time and variance per lane, where the lanes' medians lie
  further apart than their spreads; ``relink_lane_delays`` re-decides the links across those
  gaps with them;
* ``estimate_yields``: in those gaps, an extra time and variance for a car of a continuing lane
  that passes the next station right behind a car of the closing lane;
  ``exchange_merge_order`` re-decides, with it, which of two such neighbours passes first.

``mend_merges`` does both.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mlkm_core.associators.delays import link_residuals, robust_location
from mlkm_core.associators.gating import gate_pairs
from mlkm_core.associators.linking import match_sparse
from mlkm_core.model.link import LinkModel
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Detections, Layout, link_pairs

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
    e_t, model = link_residuals(layout, d, a, b, p)
    for g in spread_gaps:
        rows = []
        in_gap = d.sensor_index[a] == g
        for lane in np.unique(d.lane[a[in_gap]]):
            k = in_gap & (d.lane[a] == lane)
            if k.sum() < MIN_LANE_LINKS:
                continue
            med, spread2 = robust_location(e_t[k])
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
        for ln in np.unique(lane[up]):
            i = np.flatnonzero(lane[up] == ln)
            m = LinkModel(replace(p, delay=own.get(int(ln), delay)))
            m.grow(up.size)
            m.start(i, pos[g], d.stamp[up[i]], u[up[i]], up[i])
            pred = m.predict(i, pos[g + 1])
            r, c = gate_pairs(*m.gate_window(pred), d.stamp[down])
            if r.size == 0:
                continue
            nll, d2 = m.cost(pred.take(r), d.stamp[down[c]], u[down[c]], down[c])
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


#: a car that lets a merging car in gets a delay of its own where the median of such cars'
#: residuals lies further than this many times the wider spread from that of the other cars of
#: the continuing lanes (where they merge, such cars are seconds later or not at all, against
#: spreads from tenths of a second to seconds: docs/benchmarks.md#simulator-defaults) ...
YIELD_SEPARATION = 0.5
#: ... and further than this many standard errors of the difference of the two medians (a
#: merge passes only tens of cars: a difference of half a spread is often chance)
YIELD_SIGNIFICANCE = 2.5
#: links of each kind needed to judge it
MIN_YIELD_LINKS = 8


def closing_lanes(d: Detections, g: int) -> np.ndarray:
    """Lanes reported at sensor g and at no detection of sensor g + 1."""
    if d.lane is None:
        return np.zeros(0, np.int64)
    before = np.unique(d.lane[(d.sensor_index == g) & (d.lane >= 0)])
    after = np.unique(d.lane[(d.sensor_index == g + 1) & (d.lane >= 0)])
    return np.setdiff1d(before, after)


def _links_across(d: Detections, labels: np.ndarray, g: int) -> tuple[np.ndarray, np.ndarray]:
    """Links of ``labels`` from sensor g to g + 1, in the order of their stamps at g + 1."""
    a, b = link_pairs(d, labels)
    k = (d.sensor_index[a] == g) & (d.sensor_index[b] == g + 1)
    a, b = a[k], b[k]
    order = np.argsort(d.stamp[b], kind='stable')
    return a[order], b[order]


def estimate_yields(
    layout: Layout, d: Detections, labels: np.ndarray, p: MotionParams
) -> MotionParams:
    """``p`` with a delay of their own for the cars that let a merging car in.

    In each gap with lanes' own delays (``estimate_lane_delays``) where a lane closes, the links
    of ``labels`` across it are put in the order in which they reach the next station. A car
    of a continuing lane right behind a car of a closing lane there has let it in. Where the
    robust location of those cars' residuals (the trapezoid and the gap's own extra time taken
    off) lies further than ``YIELD_SEPARATION`` times the wider spread from that of the other
    cars of the continuing lanes, and further than ``YIELD_SIGNIFICANCE`` standard errors, the
    gap gets their extra time and variance (beyond the model's own) in ``GapDelays.yields``.
    Replaces any earlier estimate.
    """
    delay = p.delay
    if delay is None or not delay.lanes or d.lane is None:
        return p
    yields: list[tuple[int, float, float]] = []
    for g in sorted({x[0] for x in delay.lanes}):
        closing = closing_lanes(d, g)
        up, down = _links_across(d, labels, g)
        if closing.size == 0 or up.size == 0:
            continue
        merging = np.isin(d.lane[up], closing)
        behind = ~merging & np.concatenate([[False], merging[:-1]])
        others = ~merging & ~behind
        if behind.sum() < MIN_YIELD_LINKS or others.sum() < MIN_YIELD_LINKS:
            continue
        e_t, model = link_residuals(layout, d, up, down, p)
        med_y, spread_y = robust_location(e_t[behind])
        med_o, spread_o = robust_location(e_t[others])
        gap_medians = abs(med_y - med_o)
        # standard error of a median: sqrt(pi / 2) sigma / sqrt(n)
        error = np.sqrt(np.pi / 2 * (spread_y / behind.sum() + spread_o / others.sum()))
        if gap_medians <= max(
            YIELD_SEPARATION * np.sqrt(max(spread_y, spread_o)), YIELD_SIGNIFICANCE * error
        ):
            continue
        own = float(np.median(model[behind])) - delay.gap_var[g]
        yields.append((int(g), float(delay.gap_time[g] + med_y), max(spread_y - own, 0.0)))
    return replace(p, delay=replace(delay, yields=tuple(yields)))


class _MergeCosts:
    """Pairwise link costs (motion under a given law of the gap, lane and length) from the
    detections ``up`` at sensor g to ``down`` at g + 1, computed once per (law, link)."""

    def __init__(
        self,
        layout: Layout,
        d: Detections,
        p: MotionParams,
        g: int,
        up: np.ndarray,
        down: np.ndarray,
    ) -> None:
        self.d, self.p, self.g, self.up, self.down = d, p, g, up, down
        self.x = layout.positions
        self.u = 1.0 / d.velocity
        self.models: dict[tuple[float, float], LinkModel] = {}
        self.memo: dict[tuple[tuple[float, float], int, int], float] = {}

    def __call__(self, law: tuple[float, float], i: int, j: int) -> float:
        key = (law, i, j)
        if key not in self.memo:
            model = self.models.get(law)
            if model is None:
                model = LinkModel(replace(self.p, delay=self.p.delay.with_gap(self.g, *law)))
                model.grow(self.up.size)
                rows = np.arange(self.up.size)
                model.start(rows, self.x[self.g], self.d.stamp[self.up], self.u[self.up], self.up)
                self.models[law] = model
            r, c = np.array([i]), np.array([self.down[j]])
            pred = model.predict(r, self.x[self.g + 1])
            nll, d2 = model.cost(pred, self.d.stamp[c], self.u[c], c)
            cost = float(nll[0]) if d2[0] <= self.p.gate else np.inf
            self.memo[key] = cost
        return self.memo[key]


def exchange_merge_order(
    layout: Layout, d: Detections, labels: np.ndarray, p: MotionParams
) -> np.ndarray:
    """Re-decide which of two neighbours, one merging and one letting it in, passes first.

    For a gap with a yield (``GapDelays.yields``), the links of ``labels`` across it are put in
    the order in which they reach the next station. Each link is scored under its lane's law
    (``GapDelays.lanes``, or the gap's), except that a car of a continuing lane right behind a
    merging car is scored under the yield's. Where the cars of two consecutive links come from
    a closing and a continuing lane, their continuations are exchanged when that lowers the
    cost of the two links and of the one after them (whose predecessor changes); passes repeat
    until nothing is exchanged. Returns new labels; ``labels`` is left as it is.
    """
    out = labels.copy()
    delay = p.delay
    if delay is None or not delay.yields or d.lane is None:
        return out
    for g, y_time, y_var in delay.yields:
        up, down = _links_across(d, out, g)
        n = up.size
        if n < 2:
            continue
        pooled = (float(delay.gap_time[g]), float(delay.gap_var[g]))
        lane_law = {lane: (t, v) for gap, lane, t, v in delay.lanes if gap == g}
        merging = np.isin(d.lane[up], closing_lanes(d, g))
        own = [lane_law.get(int(x), pooled) for x in d.lane[up]]
        partner = _merge_order(
            _MergeCosts(layout, d, p, g, up, down), merging, own, (y_time, y_var)
        )
        moved = np.flatnonzero(partner != np.arange(n))
        tails = [np.flatnonzero((out == out[down[j]]) & (d.sensor_index > g)) for j in moved]
        for j, tail in zip(moved, tails, strict=True):
            out[tail] = out[up[partner[j]]]
    return out


def _merge_order(
    cost: _MergeCosts, merging: np.ndarray, own: list, yield_law: tuple[float, float]
) -> np.ndarray:
    """partner[j]: the link (index into ``cost.up``) that reaches ``cost.down[j]`` after the
    exchanges of ``exchange_merge_order``."""
    n = merging.size

    def nll(i: int, j: int, after_merging: bool) -> float:
        return cost(yield_law if after_merging and not merging[i] else own[i], i, j)

    partner = np.arange(n)
    for _ in range(n):
        changed = False
        for j in range(n - 1):
            i1, i2 = partner[j], partner[j + 1]
            if merging[i1] == merging[i2]:
                continue
            ahead = j > 0 and bool(merging[partner[j - 1]])
            kept = nll(i1, j, ahead) + nll(i2, j + 1, bool(merging[i1]))
            swapped = nll(i2, j, ahead) + nll(i1, j + 1, bool(merging[i2]))
            if j + 2 < n:
                kept += nll(partner[j + 2], j + 2, bool(merging[i2]))
                swapped += nll(partner[j + 2], j + 2, bool(merging[i1]))
            if swapped < kept:
                partner[j], partner[j + 1] = i2, i1
                changed = True
        if not changed:
            break
    return partner


def mend_merges(layout: Layout, d: Detections, labels: np.ndarray, p: MotionParams) -> np.ndarray:
    """``labels`` relinked across the merges with the lanes' own delays, then the order of
    merging cars and the cars that let them in re-decided (no change without them)."""
    return exchange_merge_order(layout, d, relink_lane_delays(layout, d, labels, p), p)
