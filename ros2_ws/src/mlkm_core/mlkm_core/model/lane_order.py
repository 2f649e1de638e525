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
produce most: ``associators.laneorder.restore_order`` undoes it after the pairwise pass.
``fit`` learns the order from the tracks of a pass, and link passes with the cue refine it
(``KIND.rounds``); what it learns is tied to the detections it was learnt on.
"""

from __future__ import annotations

import numpy as np

from mlkm_core.model.cues import Cue, CueKind, CueTracks
from mlkm_core.types import Detections, Layout, link_pairs

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


class LaneOrderCue(Cue):
    name = 'lane_order'

    def __init__(self, order: LaneOrder) -> None:
        self.order = order

    def tracks(self, accumulate: bool) -> LaneOrderTracks:
        return LaneOrderTracks(self, accumulate)


class LaneOrderTracks(CueTracks):
    """Per track: its last detection."""

    FIELDS = {'det': (0, np.int64)}

    def __init__(self, cue: LaneOrderCue, accumulate: bool) -> None:
        super().__init__(accumulate)
        self.order = cue.order

    def start(self, tracks: np.ndarray, det: np.ndarray) -> None:
        self.state['det'][tracks] = det

    def cost(self, tracks: np.ndarray, det: np.ndarray) -> np.ndarray:
        return self.order.cost(self.state['det'][tracks], det)

    def update(self, tracks: np.ndarray, det: np.ndarray) -> None:
        self.state['det'][tracks] = det


def fit(layout: Layout, d: Detections, labels: np.ndarray) -> LaneOrder | None:
    """The in-lane order of ``d`` learnt from the tracks ``labels``; None where travel times
    separate neighbours anyway, or without lanes."""
    if d.lane is None or not np.any(d.lane >= 0):
        return None
    order = LaneOrder(layout, d, labels)
    return order if order.active else None


def bind(layout: Layout, d: Detections, order: LaneOrder | None) -> LaneOrderCue | None:
    """The cue on ``d`` (the detections ``order`` was learnt on); None without an order."""
    return None if order is None else LaneOrderCue(order)


#: link passes that refine the in-lane order from their own tracks
ROUNDS = 3

KIND = CueKind(
    'lane_order',
    needs='queue in a lane (travel times that cannot tell neighbours apart)',
    bind=bind,
    fit=fit,
    rounds=ROUNDS,
    reusable=False,
)
