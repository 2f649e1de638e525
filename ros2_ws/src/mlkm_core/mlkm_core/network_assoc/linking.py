"""Tracks across a road network by one global matching of each detection to its successor.

On one road ``assignment`` links sensor after sensor. A network has no such order: a vehicle
seen at a station may next be seen on any link that can follow, and a station after a merge
sees vehicles from several roads. Every candidate link goes forward in time, so the tracks
are the paths of a min-cost matching between each detection (as a predecessor) and each
detection (as a successor), the classical successor formulation of multi-target data
association: a detection with no predecessor starts a track, one with no successor ends it.

A candidate link joins detection i at station s to detection j at a station of a hop from s
(``hops``), later in time and inside the gate of the pairwise motion model over the hop's
distance, widened by the time lost at its junctions. Its cost is the sum of parts:

* motion: the pairwise model's NLL of the travel time and speed change over the distance,
  with the mean and the variance of the time lost at the junctions on the way
  (``junctions``) added to the travel time's, and the link's wait at its signals
  (``signals``: the queue's release and the time to the green);
* the turn: -log of the shares of the connections crossed (``junctions``);
* misses: the stations the hop passes unseen, each -log p_miss;
* the vehicle length where the stations report it (``model.length``: the same cue as on one
  road);
* the lane where the stations report it, as the hop's links of a pass show it follows from
  one station to the next (``lanes``: a lane index means another place on another link).

A track's start costs the new-track cost plus the misses of the stations it must have passed
unseen since an entry; its end the misses of the stations it would pass before an exit
(``hops.Hops.before`` / ``after``). A link is made when it costs less than the start and the
end it saves; a track of one detection is left unassigned (a false alarm), as on one road.
On a hop along one lane, where no vehicle can overtake another, two links the matching
crossed are exchanged back into the order of passage unless the link model objects
(``order``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from mlkm_core.associators.gating import gate_pairs_grouped, runs
from mlkm_core.associators.linking import match_sparse, relabel
from mlkm_core.model.cues import Cue
from mlkm_core.model.motion import END_MISSES, FLOOR_T, MotionParams, PairwiseModel
from mlkm_core.network_assoc.hops import Hops
from mlkm_core.network_assoc.junctions import JunctionModel
from mlkm_core.network_assoc.lanes import HopLanes
from mlkm_core.network_assoc.order import keep_order, pair_costs
from mlkm_core.network_assoc.signals import Signals
from mlkm_core.types import Detections


@dataclass(frozen=True)
class Links:
    """The links of a labelling: detection ``a[k]`` -> ``b[k]`` across hop ``hop[k]``."""

    a: np.ndarray
    b: np.ndarray
    hop: np.ndarray


def hop_cost(
    p: MotionParams,
    distance: float | np.ndarray,
    ti: np.ndarray,
    ui: np.ndarray,
    tj: np.ndarray,
    uj: np.ndarray,
    spread: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """(NLL, squared Mahalanobis distance) of links over ``distance`` [m] (one, or one per
    link) from (stamp [s], slowness [s/m]) (ti, ui) to (tj, uj) (the time lost at junctions
    already taken off tj), with the variance [s^2] the junctions add to the travel time."""
    n = ti.size
    rows = np.arange(n)
    pw = p.for_pairwise()
    if spread > 0.0:  # the travel time's variance holds 2 sigma_t^2
        base = max(pw.stamp_noise, FLOOR_T) ** 2
        pw = replace(pw, stamp_noise=float(np.sqrt(base + spread / 2.0)))
    m = PairwiseModel(pw)
    m.grow(n)
    m.start(rows, 0.0, ti, ui)
    return m.cost(m.predict(rows, distance), tj, uj)


def candidates(
    hops: Hops,
    d: Detections,
    p: MotionParams,
    junctions: JunctionModel,
    cue: Cue | None = None,
    lanes: HopLanes | None = None,
    per_hop: dict[int, MotionParams] | None = None,
    only: list[int] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(i, j, cost, hop) of every gated candidate link (module docstring), by hop, then by
    ``i``, then by the stamp of ``j``; ``cue`` (bound to ``d``) and ``lanes`` add their
    costs to each; ``only``: these hops alone.

    The hops that share a motion model and a junction spread are gated and costed at once
    (a network has hundreds of hops, most with a few detections at either end)."""
    u = 1.0 / d.velocity
    n_st = hops.before.size
    by_station = np.argsort(d.sensor_index, kind='stable')
    count = np.bincount(d.sensor_index, minlength=n_st)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    chosen = np.arange(hops.size) if only is None else np.asarray(only, np.int64)
    chosen = chosen[(count[hops.src[chosen]] > 0) & (count[hops.dst[chosen]] > 0)]
    groups: dict[tuple[int, float], tuple[MotionParams, list[int]]] = {}
    shifts = np.zeros(hops.size)
    missed = np.zeros(hops.size)  # per hop [nats]
    turned = np.zeros(hops.size)  # per hop [nats]
    for h in chosen.tolist():
        ph = p if per_hop is None else per_hop.get(h, p)
        shifts[h], spread = junctions.lost(h, hops.turns[h])
        missed[h] = hops.skipped[h] * p.miss_cost
        turned[h] = junctions.turn_cost(hops.turns[h])
        groups.setdefault((id(ph), float(spread)), (ph, []))[1].append(h)
    signals = junctions.signals
    release = None if signals is None else signals.releases(d)
    parts = [
        _group_candidates(hops, d, u, ph, spread, np.asarray(hs, np.int64),
                          by_station, first, count, shifts, signals, release)
        for (_, spread), (ph, hs) in groups.items()
    ]  # fmt: skip
    if not parts:
        z = np.zeros(0, np.int64)
        return z, z, np.zeros(0), z
    i, j, cost, hop = (np.concatenate(c) for c in zip(*parts, strict=True))
    order = np.argsort(hop, kind='stable')  # each group is by hop already
    i, j, hop = i[order], j[order], hop[order]
    cost = cost[order] + missed[hop] + turned[hop]
    if cue is not None:
        state = cue.tracks(False)
        pairs = np.arange(i.size)
        state.grow(i.size)
        state.start(pairs, i)
        cost = cost + state.cost(pairs, j)
    if lanes is not None:
        for h in set(lanes.tables).intersection(np.unique(hop).tolist()):
            lo, hi = np.searchsorted(hop, [h, h + 1])
            cost[lo:hi] += lanes.cost(h, d.lane[i[lo:hi]], d.lane[j[lo:hi]])
    return i, j, cost, hop


def _group_candidates(
    hops: Hops,
    d: Detections,
    u: np.ndarray,
    ph: MotionParams,
    spread: float,
    hs: np.ndarray,
    by_station: np.ndarray,
    first: np.ndarray,
    count: np.ndarray,
    shifts: np.ndarray,
    signals: Signals | None = None,
    release: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(i, j, motion cost, hop) of the gated links across the hops ``hs``, which share the
    motion model ``ph`` and the junction spread ``spread`` [s^2]; by hop, ``i``, stamp of
    ``j``. ``signals``: each link's travel time also holds its wait for the green (from its
    queue's ``release`` where known)."""
    src, dst = hops.src[hs], hops.dst[hs]
    k, a = runs(first[src], first[src] + count[src], by_station)
    a_hop = hs[k]
    rows = np.arange(a.size)
    m = PairwiseModel(ph)
    m.grow(a.size)
    m.start(rows, 0.0, d.stamp[a], u[a])
    centre, half = m.gate_window(m.predict(rows, hops.distance[a_hop]))
    half = np.sqrt(half * half + ph.gate * spread)
    lost = shifts[a_hop]
    if signals is not None:
        lost = lost + signals.waits(a_hop, d.stamp[a], u[a], release[a])
    centre = centre + lost
    k, b = runs(first[dst], first[dst] + count[dst], by_station)
    r, c = gate_pairs_grouped(a_hop, centre, half, hs[k], d.stamp[b])
    i, j, hop, lost = a[r], b[c], a_hop[r], lost[r]
    keep = d.stamp[j] > d.stamp[i]
    i, j, hop, lost = i[keep], j[keep], hop[keep], lost[keep]
    nll, d2 = hop_cost(ph, hops.distance[hop], d.stamp[i], u[i], d.stamp[j] - lost, u[j], spread)
    ok = np.isfinite(nll) & (d2 <= ph.gate)
    return i[ok], j[ok], nll[ok], hop[ok]


def link_weights(
    hops: Hops, p: MotionParams, d: Detections, i: np.ndarray, j: np.ndarray, cost: np.ndarray
) -> np.ndarray:
    """What each candidate link ``i`` -> ``j`` saves: its ``cost`` minus starting a track at
    ``j`` (the new-track cost and the stations it passed unseen since an entry) and ending
    one at ``i`` (the stations it would pass unseen before an exit). A link is worth making
    where this is negative."""
    st = d.sensor_index
    start = p.new_cost + np.minimum(hops.before[st[j]], p.max_skip + 1) * p.miss_cost
    end = np.minimum(hops.after[st[i]], END_MISSES) * p.miss_cost
    return cost - start - end


def solve(
    hops: Hops,
    d: Detections,
    p: MotionParams,
    junctions: JunctionModel,
    cue: Cue | None = None,
    lanes: HopLanes | None = None,
    per_hop: dict[int, MotionParams] | None = None,
) -> tuple[np.ndarray, Links]:
    """Track ids (-1: a detection left alone) and the links made."""
    n = len(d)
    i, j, cost, hop = candidates(hops, d, p, junctions, cue, lanes, per_hop)
    rows, cols = match_sparse(i, j, link_weights(hops, p, d, i, j, cost), n, n)
    # the hop of each link made (the cheapest candidate between the two detections)
    key = i.astype(np.int64) * n + j
    order = np.lexsort((cost, key))
    keys = key[order]
    first = np.concatenate([[True], keys[1:] != keys[:-1]]) if keys.size else keys.astype(bool)
    best_key, best_hop = keys[first], hop[order][first]
    made = best_hop[np.searchsorted(best_key, rows.astype(np.int64) * n + cols)]
    made = made.astype(np.int64)
    if hops.in_order.any():
        cost_of = pair_costs(n, best_key, cost[order][first])
        cols = keep_order(hops.in_order, d, rows, cols, made, cost_of)
    nxt = np.full(n, -1, np.int64)
    nxt[rows] = cols
    has_prev = np.zeros(n, bool)
    has_prev[cols] = True
    labels = np.full(n, -1, np.int64)
    track = 0
    for s in np.flatnonzero(~has_prev):
        k = int(s)
        while k >= 0:
            labels[k] = track
            k = int(nxt[k])
        track += 1
    return relabel(labels), Links(rows, cols, made)
