"""``gmlkm``: a G-MLKM baseline on a road network, written from our reading of the paper.

Tao, Suresh, Votion and Cao, "Graph Based Multi-Layer K-Means++ (G-MLKM) for Sensory Pattern
Analysis in Constrained Spaces", Sensors 21(6):2069, 2021, carries MLKM from one road to a
network: MLKM on each local space (a road between intersections), then the association of
the local results across the intersections, with error-correction mechanisms that exclude
associations which disobey physical rules (92.2 % average accuracy on the authors' own
simulated networks). This module is the product's baseline for networks, as ``mlkm`` is on
one road: the stronger network methods must beat it.

Two steps:

1. Per link: the link's stations are a single road (positions = their offsets along the
   link); the product's faithful MLKM (``mlkm_core.associators.mlkm``, method ``mlkm``)
   associates the link's detections into *link-tracks*. A link with one station cannot be
   clustered along a road: each of its detections is a link-track of its own.
2. Across junctions: each link-track's tail (its last detection: time t, speed v, station s)
   is joined to the head (first detection) of at most one link-track on a link reachable
   next, by nearest neighbour on the predicted arrival t + distance / v, among the joins the
   physical rules allow; joined link-tracks form one track.

Readings of the paper
---------------------
Only the paper's abstract was available to us (found through its arXiv 2009.09925, PMC and
MDPI pages); its body, equations and parameters were not. Every rule below is therefore our
reading of the abstract's description ("first understanding local data-target association,
extracting cross-local data-target association ..., and then analyzing the data association
at intersections"; "error correction mechanisms ... to exclude potential data-target
association errors that disobey physical rules"), made in the spirit of MLKM's own layers:

1. Local spaces are the network's links. The abstract says of its p-dual graph only that it
   represents interconnected local spaces; we read it as the roads (our links) joined where
   a vehicle can pass from one to the next (our connections). MLKM runs on each link
   exactly as on one road (segments of ``segment_size`` stations, Layer 2 correction,
   Layer 3 matching), with n_targets = the largest number of detections at one of the
   link's stations, as the CLI assumes on one road.
2. A link-track's tail is its detection at its most downstream station (the latest there
   when MLKM put several in it); its head is its detection at its most upstream station (the
   earliest there). Link-tracks on the same link are never joined: that is MLKM's job.
3. Cross-local association: the tail (t_a, v_a) at station s is projected forward to a
   station j reachable next, t' = t_a + d / v_a with d the shortest distance from s to j
   (``RoadNetwork.successors``); the head (t_b, v_b) at j is compared to it in the raw
   (v, t) space MLKM clusters in, cost = sqrt((t_b - t')^2 + (v_b - v_a)^2) (m/s and s,
   unscaled, as the paper's K-means features). This is MLKM's Layer 2 prediction
   (argmin |t_{l+1} - (t_l + |R_{l+1} - R_l| / v_l)|) carried across a junction, with the
   speed difference that Layer 3's (v, t') grouping also weighs.
4. Grouping at the intersections: a K-means grouping of projected tails and heads in which
   every group holds at most one tail and one head (reading 5) is a matching of pairs; we
   take the greedy global nearest-neighbour matching: all admissible pairs of the network,
   cheapest first (ties by tail, then head link-track), each accepted when neither end is
   taken. It needs no number of targets per junction, which the data do not give.
5. Error correction by physical rules, applied as gates before the matching:
   a. one vehicle cannot split or merge: a tail continues at most one head, a head at most
      one tail, and no chain of joins may close on itself;
   b. arrival after departure: t_b > t_a;
   c. no faster than plausible: the mean speed over the gap d / (t_b - t_a) is at most
      ``MAX_SPEED_RATIO`` times the faster of v_a and v_b;
   d. no slower than plausible: t_b - t_a is at most d / min(v_a, v_b) plus one wait at a
      junction, ``MAX_WAIT_S`` (a red light, a yielding merge).
   A tail with no admissible head ends its track (the vehicle left the network, or its
   next detection was missed); a head with none starts a track (it entered).
6. A missed detection: a tail may lie up to ``MAX_SKIPPED`` stations before the end of its
   link's stations (chained successors along its link, distances added), so one missed
   passage at a link's last station does not split a track. A head must lie at the first
   station reached on its link: letting it lie further (past a missed first station) let a
   tail reach the heads of two stations of the next link, and the extra candidates cost
   about 13 points of accuracy on the SUMO grid (seeds 1 and 2) in our runs. Speeds are
   floored at ``MIN_SPEED_MPS`` for the divisions (a stopped vehicle reports 0 m/s).
7. Not in the paper: the network's entries and exits are not used; the gates and the
   nearest-neighbour choice alone decide where a track ends. The result is one label per
   detection; every detection gets a track (MLKM labels every detection, clutter
   included). Tracks are numbered 0, 1, ... by their first stamp (then detection index).
"""

from __future__ import annotations

import numpy as np

from mlkm_core.associators import AssociatorConfig, make_associator
from mlkm_core.network import RoadNetwork
from mlkm_core.types import Detections, Layout

#: Fastest plausible mean speed over a gap between link-tracks, as a multiple of the faster
#: of the two measured speeds (reading 5c).
MAX_SPEED_RATIO = 1.5
#: Longest plausible wait at a junction beyond the slower speed's travel time [s] (5d).
MAX_WAIT_S = 120.0
#: Floor of the speeds a travel time is divided by [m/s] (reading 6).
MIN_SPEED_MPS = 0.5
#: Stations of its own link a vehicle may pass unseen after a tail (reading 6).
MAX_SKIPPED = 1


def gmlkm_associate(net: RoadNetwork, d: Detections, seed: int = 0) -> np.ndarray:
    """One label per detection of ``d`` on ``net`` (``d.sensor_index`` indexes the network's
    station arrays): a track id >= 0 (module docstring: MLKM per link, then nearest-neighbour
    joins across junctions gated by physical rules). Deterministic for a ``seed`` (MLKM's
    K-means++ seed). ValueError when a detection names a station the network lacks."""
    n = len(d)
    if n == 0:
        return np.zeros(0, np.int64)
    if d.sensor_index.min() < 0 or d.sensor_index.max() >= net.n_stations:
        raise ValueError(f'a detection names a station outside [0, {net.n_stations})')
    piece = link_tracks(net, d, seed)
    joins = junction_joins(net, d, piece)
    return number_tracks(d, piece, joins)


def link_tracks(
    net: RoadNetwork, d: Detections, seed: int = 0, method: str = 'mlkm'
) -> np.ndarray:
    """Step 1: the link-track (0, 1, ... over the network) of every detection: MLKM (or the
    one-road ``method``) on each link's detections (readings 1 and 2), the link's entries and
    exits inside it given as the road's; on a one-station link each detection alone, and a
    detection the method leaves alone a link-track of its own."""
    piece = np.full(len(d), -1, np.int64)
    next_id = 0
    for link, along in net.stations_along.items():
        stations = np.array([i for _, i in along], np.int64)
        mine = np.flatnonzero(np.isin(d.sensor_index, stations))
        if mine.size == 0:
            continue
        if stations.size == 1:
            local = np.arange(mine.size, dtype=np.int64)
        else:
            local_index = np.full(net.n_stations, -1, np.int64)
            local_index[stations] = np.arange(stations.size)
            sub = d.subset(mine)
            sub.sensor_index = local_index[sub.sensor_index]
            layout = Layout(
                net.link_lengths[link],
                np.array([x for x, _ in along], float),
                net.station_ids[stations],
            )
            inside = [
                tuple(x for k, x in points if k == link and 0.0 < x < net.link_lengths[link])
                for points in (net.entries, net.exits)
            ]
            config = AssociatorConfig(seed=seed, entries=inside[0], exits=inside[1])
            n_targets = int(np.bincount(sub.sensor_index).max())
            local = make_associator(method, config).associate(layout, sub, n_targets)
            stray = local < 0  # none from MLKM, which labels every detection
            local[stray] = local.max(initial=-1) + 1 + np.arange(int(stray.sum()))
        _, local = np.unique(local, return_inverse=True)
        piece[mine] = next_id + local
        next_id += int(local.max()) + 1
    return piece


def _reach(net: RoadNetwork, station: int, cache: dict) -> dict[int, float]:
    """{station j: shortest distance [m]} of the first stations on other links than
    ``station``'s that a vehicle can reach next, also past at most ``MAX_SKIPPED`` stations
    of its own link where it went unseen (reading 6)."""
    if station in cache:
        return cache[station]
    link = int(net.station_links[station])
    best: dict[int, float] = {}
    here, d0 = station, 0.0
    for _ in range(MAX_SKIPPED + 1):
        own = None
        for step in net.successors(here):
            dist = d0 + step.distance_m
            if int(net.station_links[step.index]) == link:
                own = (step.index, dist)
            elif dist < best.get(step.index, np.inf):
                best[step.index] = dist
        if own is None:
            break
        here, d0 = own
    cache[station] = best
    return best


def _ends(net: RoadNetwork, d: Detections, piece: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(head, tail): the detection index of each link-track's first and last detection,
    by (position along the link, stamp, index) (reading 2)."""
    offset = net.station_offsets[d.sensor_index]
    order = np.lexsort((np.arange(len(d)), d.stamp, offset, piece))
    p = piece[order]
    first = np.flatnonzero(np.r_[True, p[1:] != p[:-1]])
    last = np.r_[first[1:] - 1, p.size - 1]
    return order[first], order[last]


def junction_joins(net: RoadNetwork, d: Detections, piece: np.ndarray) -> list[tuple[int, int]]:
    """Step 2: the accepted (tail link-track, head link-track) joins across junctions
    (readings 3 to 6), cheapest first."""
    head, tail = _ends(net, d, piece)
    speed = np.maximum(d.velocity, MIN_SPEED_MPS)
    # heads per station, by stamp, for the time window of each tail
    head_station = d.sensor_index[head]
    by_station: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for j in np.unique(head_station):
        ks = np.flatnonzero(head_station == j)
        ks = ks[np.argsort(d.stamp[head[ks]], kind='stable')]
        by_station[int(j)] = (ks, d.stamp[head[ks]])
    cache: dict = {}
    cost, tails, heads = [], [], []  # admissible pairs
    for a in range(tail.size):
        i = tail[a]
        ta, va = d.stamp[i], speed[i]
        for j, dist in _reach(net, int(d.sensor_index[i]), cache).items():
            if j not in by_station:
                continue
            ks, stamps = by_station[j]
            hi = ta + dist / MIN_SPEED_MPS + MAX_WAIT_S
            b = ks[np.searchsorted(stamps, ta, 'right') : np.searchsorted(stamps, hi, 'right')]
            gap = d.stamp[head[b]] - ta  # > 0 by the window (rule 5b)
            vb = speed[head[b]]
            ok = dist <= MAX_SPEED_RATIO * np.maximum(va, vb) * gap  # rule 5c
            ok &= gap <= dist / np.minimum(va, vb) + MAX_WAIT_S  # rule 5d
            cost.append(np.hypot(gap[ok] - dist / va, vb[ok] - va))
            tails.append(np.full(int(ok.sum()), a))
            heads.append(b[ok])
    if not cost:
        return []
    cost, tails, heads = (np.concatenate(x) for x in (cost, tails, heads))
    pairs = np.lexsort((heads, tails, cost))  # cheapest first, ties by tail then head
    root = list(range(tail.size))

    def find(x: int) -> int:
        while root[x] != x:
            root[x] = root[root[x]]
            x = root[x]
        return x

    taken_tail, taken_head, joins = set(), set(), []
    for a, b in zip(tails[pairs].tolist(), heads[pairs].tolist()):
        if a in taken_tail or b in taken_head or find(a) == find(b):  # rule 5a
            continue
        taken_tail.add(a)
        taken_head.add(b)
        root[find(a)] = find(b)
        joins.append((a, b))
    return joins


def number_tracks(d: Detections, piece: np.ndarray, joins: list[tuple[int, int]]) -> np.ndarray:
    """Track id per detection: link-tracks chained by ``joins``, tracks numbered by their
    first stamp, then their first detection index."""
    n_pieces = int(piece.max()) + 1
    nxt = dict(joins)
    starts = sorted(set(range(n_pieces)) - {b for _, b in joins})
    chain = np.empty(n_pieces, np.int64)
    for c, a in enumerate(starts):
        while True:
            chain[a] = c
            if a not in nxt:
                break
            a = nxt[a]
    group = chain[piece]
    order = np.lexsort((np.arange(len(d)), d.stamp, group))
    g = group[order]
    first = order[np.flatnonzero(np.r_[True, g[1:] != g[:-1]])]  # per track, in track order
    rank = np.empty(first.size, np.int64)
    rank[np.lexsort((first, d.stamp[first]))] = np.arange(first.size)
    return rank[group]
