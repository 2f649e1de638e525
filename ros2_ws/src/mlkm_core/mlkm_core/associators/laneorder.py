"""Order of passage within a lane in a queue: crossed neighbours get their order back.

A vehicle in a queue does not overtake the one ahead of it in its lane, but the pairwise pass
scores each link on its own and a stop-and-go wave can cross the links of two similar
neighbours; ``restore_order`` undoes that in the gaps where the ``lane_order`` cue
(``model.lane_order``) found a queue.
"""

from __future__ import annotations

import numpy as np

from mlkm_core.model.link import LinkModel
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Detections, Layout, link_pairs

#: probability that two consecutive vehicles of a lane pass the next station of a queue in the
#: other order (rare in SUMO's queues: docs/benchmarks.md#associator-design-figures)
SWAP_PROB = 0.01


def restore_order(
    layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams
) -> np.ndarray:
    """Undo the crossing of two consecutive vehicles of a lane across the gaps of a queue.

    In a queue (the gaps of the ``lane_order`` cue of ``params.cues``) a vehicle does not
    overtake the one ahead of it in its lane: two vehicles that pass station s in one lane in
    the order (a1, a2) pass s + 1 in that order, whatever lane they are in by then. The
    pairwise pass scores each link on its own, and where a wave holds up the first of two
    similar vehicles it can cross their links. For every queue gap and every lane at its
    upstream station, the links of ``labels`` out of that lane are sorted by their upstream
    stamp, and two neighbours that arrive downstream in the other order exchange their
    continuations when the exchange costs less than -log(``SWAP_PROB``) more under the pairwise
    model (motion, lane and length); passes repeat until nothing is exchanged. Returns new
    labels (the detections after the gap follow the exchanged continuations); ``labels`` is
    left as it is.
    """
    cue = None if params.cues is None else params.cues.get('lane_order')
    out = labels.copy()
    if cue is None or d.lane is None:
        return out
    u = 1.0 / d.velocity
    limit = -np.log(SWAP_PROB)
    for g in sorted({g for g, _ in cue.order.table}):
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
    model = LinkModel(params)
    model.grow(up.size)
    rows = np.arange(up.size)
    model.start(rows, pos[g], d.stamp[up], u[up], up)

    def cost(i: int, det: int) -> float:
        r, c = np.array([i]), np.array([det])
        nll, _ = model.cost(model.predict(r, pos[g + 1]), d.stamp[c], u[c], c)
        return float(nll[0])

    return cost
