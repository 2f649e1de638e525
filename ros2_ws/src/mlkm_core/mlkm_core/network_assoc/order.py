"""Order of passage along a one-lane link: vehicles that cannot overtake keep their order.

On a hop that runs along one link of a single lane, with no junction, entry, exit or unseen
station on the way (``hops.Hops.in_order``), the vehicles pass the second station in the
order they passed the first. The matching prices each link on its own, and where travel
times scatter (a queue that backs up over both stations, a platoon held at the red light
downstream) it crosses the links of two vehicles, which no vehicle on one lane can do.

``keep_order`` undoes that after the matching: of the hop's links sorted by the stamp at
their first station, two neighbours that reach the second station in the other order
exchange their continuations, unless the exchange costs more than -log(``SWAP_PROB``) under
the link model (``associators.laneorder.SWAP_PROB``, the one-road prior of two consecutive
vehicles of a lane passing in the other order); the passes (odd-even transposition, so that
the neighbours exchanged at once are disjoint) repeat until nothing is exchanged. The
exchange keeps both detections' links on the hop and every other link as it is; a pair the
gate did not offer is never made.
"""

from __future__ import annotations

import numpy as np

from mlkm_core.associators.laneorder import SWAP_PROB
from mlkm_core.types import Detections


def pair_costs(n: int, keys: np.ndarray, costs: np.ndarray):
    """A lookup ``(a, b) -> cost`` [nats] of the candidate pairs ``keys`` (a * ``n`` + b,
    sorted, unique) and their ``costs``; inf for a pair the gate did not offer."""

    def lookup(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        if keys.size == 0:
            return np.full(a.shape, np.inf)
        want = a.astype(np.int64) * n + b
        at = np.minimum(np.searchsorted(keys, want), keys.size - 1)
        return np.where(keys[at] == want, costs[at], np.inf)

    return lookup


def keep_order(
    in_order: np.ndarray,
    d: Detections,
    a: np.ndarray,
    b: np.ndarray,
    hop: np.ndarray,
    cost_of,
) -> np.ndarray:
    """The successors ``b`` of the links ``a`` -> ``b`` across ``hop`` with the crossed
    neighbours of every hop where ``in_order`` exchanged (module docstring); ``cost_of(a,
    b)``: the link model's cost of each pair [nats]. ``a`` and ``hop`` stay as they are."""
    b = b.copy()
    limit = -np.log(SWAP_PROB)
    # the links of those hops, by hop and then by the stamp at their first station
    kept = np.flatnonzero(in_order[hop])
    kept = kept[np.lexsort((d.stamp[a[kept]], hop[kept]))]
    for k in np.split(kept, np.flatnonzero(np.diff(hop[kept])) + 1):
        if k.size < 2:
            continue
        stale = 0
        parity = 0
        while stale < 2:
            p, q = k[parity:-1:2], k[parity + 1 :: 2]
            crossed = d.stamp[b[p]] > d.stamp[b[q]]
            p, q = p[crossed], q[crossed]
            now = cost_of(a[p], b[p]) + cost_of(a[q], b[q])
            swapped = cost_of(a[p], b[q]) + cost_of(a[q], b[p])
            go = swapped - now < limit
            p, q = p[go], q[go]
            b[p], b[q] = b[q], b[p]
            stale = 0 if p.size else stale + 1
            parity ^= 1
    return b
