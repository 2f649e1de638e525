"""Order of passage within a lane: the cue that survives a queue.

In a queue the travel time between two sensors is not predictable from the speeds measured at
them (vehicles stop and go in between), but vehicles that stay in their lane keep their order.
For every gap between consecutive sensors and every lane, :class:`LaneOrder` keeps the
same-lane links of a first pass; a candidate link a -> b in that lane is scored by its
inversions, the number of those links it crosses (a' before a but b' after b, or the
reverse): a link that jumps several places in the lane's order crosses many, so the wild
links a queue otherwise produces (matched by length and lane alone, tens of seconds off)
become expensive; an exchange of two neighbours crosses none and is left to the other
terms. Vehicles that join or leave the lane within the gap are not in the set, so they do
not disturb it. The distribution of the inversions of the first pass's own links (each
against the others), P(0) and a geometric tail for 1, 2, ..., gives the bounded
log-likelihood ratio -log(max(P(inversions), floor) W) against a uniform position among W
neighbours. It is used only where travel times cannot always tell neighbours in the lane
apart (one residual in ten exceeds half the lane's headway: a queue's stop-and-go waves hold
up some vehicles and not the next, while most pass on time; or they left most of the lane
unlinked); elsewhere (free flow) the term is off, so it does not count the travel time twice.

The exchange of two neighbours, which the inversions leave alone, is what a queue's waves
produce most: :func:`restore_order` undoes it after the pairwise pass, since a vehicle in a
queue does not overtake the one ahead of it in its lane.
"""

from __future__ import annotations

import numpy as np

from mlkm_core.associators.base import link_pairs
from mlkm_core.associators.motion import MotionParams, make_model
from mlkm_core.types import Detections, Layout

#: same-lane links needed in a gap and lane to judge it
MIN_LINKS = 20
#: below this fraction of a lane's detections linked across a gap, the gap is a queue too
#: (the travel times left most of them unlinked)
LINKED = 0.8
#: neighbours among which a wrong link would place the detection
NEIGHBOURS = 9
#: smallest probability of an inversion count (overtakes, first-pass errors)
FLOOR = 1e-5
#: share of a gap's travel-time residuals that must stay within half the lane's headway for
#: the gap to count as free-flowing
ON_TIME = 0.9
#: probability that two consecutive vehicles of a lane pass the next station of a queue in the
#: other order (in SUMO's queues, 0 to 2 of about 200 pairs per gap)
SWAP_PROB = 0.01


class LaneOrder:
    """Per (gap, lane): the first pass's same-lane links and their inversion law."""

    def __init__(self, layout: Layout, d: Detections, labels: np.ndarray) -> None:
        self.sensor, self.stamp = d.sensor_index, d.stamp
        self.lane = np.full(len(d), -1, np.int64) if d.lane is None else d.lane
        self.table: dict[tuple[int, int], tuple[np.ndarray, ...]] = {}
        a, b = link_pairs(d, labels)
        keep = (self.sensor[b] == self.sensor[a] + 1) & (self.lane[a] >= 0)
        keep &= self.lane[a] == self.lane[b]
        a, b = a[keep], b[keep]
        pos = layout.positions
        u = 1.0 / d.velocity
        for g, lane in {(int(self.sensor[x]), int(self.lane[x])) for x in a}:
            k = np.flatnonzero((self.sensor[a] == g) & (self.lane[a] == lane))
            if k.size < MIN_LINKS:
                continue
            at_b = np.sort(d.stamp[(self.sensor == g + 1) & (self.lane == lane)])
            headway = float(np.median(np.diff(at_b))) if at_b.size > 2 else 0.0
            dx = pos[g + 1] - pos[g]
            e_t = d.stamp[b[k]] - d.stamp[a[k]] - dx * (u[a[k]] + u[b[k]]) / 2
            spread = float(np.quantile(np.abs(e_t - np.median(e_t)), ON_TIME))
            at_a = int(((self.sensor == g) & (self.lane == lane)).sum())
            linked = k.size / max(min(at_a, at_b.size), 1)
            if not (spread > 0.5 * headway or linked < LINKED):
                continue
            links = (a[k], b[k])
            inv = self._inversions(links, a[k], b[k])
            p0 = float(np.clip(np.mean(inv == 0), 0.05, 0.99))
            more = inv[inv > 0]
            q = 1 - 1 / max(float(more.mean()) if more.size else 1.0, 1.0 + 1e-6)
            self.table[(g, lane)] = (a[k], b[k], np.array([p0, q]))

    def _inversions(
        self, links: tuple[np.ndarray, np.ndarray], qa: np.ndarray, qb: np.ndarray
    ) -> np.ndarray:
        """Links (other than those sharing an end with the query) that query i crosses.

        Exchanging the successors of two neighbours crosses no third link; the count grows
        with how far the query jumps in the lane's order."""
        la, lb = links
        ta, tb = self.stamp[la][None, :], self.stamp[lb][None, :]
        qa_t, qb_t = self.stamp[qa][:, None], self.stamp[qb][:, None]
        other = (la[None, :] != qa[:, None]) & (lb[None, :] != qb[:, None])
        cross = ((ta < qa_t) & (tb > qb_t)) | ((ta > qa_t) & (tb < qb_t))
        return (cross & other).sum(axis=1)

    @property
    def active(self) -> bool:
        return bool(self.table)

    def cost(self, det_a: np.ndarray, det_b: np.ndarray) -> np.ndarray:
        """NLL ratio of linking det_a to det_b (neighbouring sensors, either direction)."""
        out = np.zeros(det_a.size)
        back = self.sensor[det_a] == self.sensor[det_b] + 1
        up = np.where(back, det_b, det_a)
        down = np.where(back, det_a, det_b)
        ok = (self.sensor[down] == self.sensor[up] + 1) & (self.lane[up] >= 0)
        ok &= self.lane[up] == self.lane[down]
        if not ok.any():
            return out
        g, lane = self.sensor[up], self.lane[up]
        for key in {(int(x), int(y)) for x, y in zip(g[ok], lane[ok], strict=True)}:
            if key not in self.table:
                continue
            la, lb, (p0, q) = self.table[key]
            k = np.flatnonzero(ok & (g == key[0]) & (lane == key[1]))
            inv = self._inversions((la, lb), up[k], down[k])
            # P(0) = p0, then geometric: P(n) = (1 - p0) (1 - q) q^(n - 1)
            with np.errstate(divide='ignore'):
                log_p = np.where(
                    inv == 0,
                    np.log(p0),
                    np.log1p(-p0) + np.log1p(-q) + (inv - 1) * np.log(max(q, 1e-12)),
                )
            out[k] = -(np.maximum(log_p, np.log(FLOOR)) + np.log(NEIGHBOURS))
        return out


def estimate_lane_order(layout: Layout, d: Detections, labels: np.ndarray) -> LaneOrder | None:
    """The in-lane order of ``d`` learnt from the tracks ``labels``; None where travel times
    separate neighbours anyway, or without lanes."""
    if d.lane is None or not np.any(d.lane >= 0):
        return None
    order = LaneOrder(layout, d, labels)
    return order if order.active else None


def restore_order(
    layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams
) -> np.ndarray:
    """Undo the crossing of two consecutive vehicles of a lane across the gaps of a queue.

    In a queue (the gaps of ``params.attributes.order``) a vehicle does not overtake the one
    ahead of it in its lane: two vehicles that pass station s in one lane in the order (a1, a2)
    pass s + 1 in that order, whatever lane they are in by then. The pairwise pass scores each
    link on its own, and where a wave holds up the first of two similar vehicles it can cross
    their links. For every queue gap and every lane at its upstream station, the links of
    ``labels`` out of that lane are sorted by their upstream stamp, and two neighbours that
    arrive downstream in the other order exchange their continuations when the exchange costs
    less than -log(``SWAP_PROB``) more under the pairwise model (motion, lane and length);
    passes repeat until nothing is exchanged. Returns new labels (the detections after the gap
    follow the exchanged continuations); ``labels`` is left as it is.
    """
    att = params.attributes
    out = labels.copy()
    if att is None or att.order is None or d.lane is None:
        return out
    u = 1.0 / d.velocity
    limit = -np.log(SWAP_PROB)
    for g in sorted({g for g, _ in att.order.table}):
        a, b = link_pairs(d, out)
        across = (d.sensor_index[a] == g) & (d.sensor_index[b] == g + 1) & (d.lane[a] >= 0)
        a, b = a[across], b[across]
        for lane in np.unique(d.lane[a]):
            k = np.flatnonzero(d.lane[a] == lane)
            k = k[np.argsort(d.stamp[a[k]], kind='stable')]
            if k.size < 2:
                continue
            up, down = a[k], b[k].copy()
            cost = _pair_cost(layout, d, params, up, g, u)
            for _ in range(k.size):
                changed = False
                for i in range(k.size - 1):
                    j = i + 1
                    if d.stamp[down[i]] <= d.stamp[down[j]]:
                        continue
                    crossed = cost(i, down[i]) + cost(j, down[j])
                    if cost(i, down[j]) + cost(j, down[i]) - crossed < limit:
                        down[i], down[j] = down[j], down[i]
                        changed = True
                if not changed:
                    break
            moved = np.flatnonzero(down != b[k])
            if moved.size == 0:
                continue
            # the continuation that now follows up[i] takes its label
            tails = [np.flatnonzero((out == out[down[i]]) & (d.sensor_index > g)) for i in moved]
            for i, tail in zip(moved, tails, strict=True):
                out[tail] = out[up[i]]
    return out


def _pair_cost(layout: Layout, d: Detections, params: MotionParams, up: np.ndarray, g: int, u):
    """cost(i, det): the pairwise link cost (motion, lane, length) from up[i] at sensor g to
    det at sensor g + 1, as ``linking.link`` scores it."""
    pos = layout.positions
    model = make_model('pairwise', params)
    model.grow(up.size)
    rows = np.arange(up.size)
    model.start(rows, pos[g], d.stamp[up], u[up])
    tracker = params.attributes.tracker(accumulate=False)
    tracker.grow(up.size)
    tracker.start(rows, up)

    def cost(i: int, det: int) -> float:
        r, c = np.array([i]), np.array([det])
        nll, _ = model.cost(model.predict(r, pos[g + 1]), d.stamp[c], u[c])
        return float(nll[0] + tracker.cost(r, c)[0])

    return cost
