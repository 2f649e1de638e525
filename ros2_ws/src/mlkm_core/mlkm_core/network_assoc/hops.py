"""The station pairs a track may link across on a road network, and what lies between them.

A *hop* goes from a station to one a vehicle can reach next (``RoadNetwork.successors``), or,
over up to ``max_skip`` stations it passed unseen (a missed detection), to one further on. It
carries the distance [m], the stations skipped, the junctions crossed (each a connection
``(from link, to link)``), whether an exit or an entry lies on the way, and whether its
vehicles keep their order (``in_order``: it runs along one link of a single lane, with no
junction, entry, exit or unseen station on the way, so none can overtake another or join
between two others). ``Hops`` also holds,
per station, how many stations a vehicle passes at least between an entry and it
(``before``) and between it and an exit (``after``): a track that starts or ends where no
vehicle can enter or leave has missed those stations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlkm_core.network import RoadNetwork

#: a station count standing for "no entry (exit) reachable" (beyond every cap)
FAR = 1_000_000


@dataclass(frozen=True)
class Hops:
    """Parallel arrays, one row per hop (module docstring)."""

    src: np.ndarray  # station index the hop leaves, int64 (h,)
    dst: np.ndarray  # station index it reaches, int64 (h,)
    distance: np.ndarray  # along the shortest way [m] (h,)
    skipped: np.ndarray  # stations passed unseen on the way, int64 (h,)
    turns: tuple[tuple[tuple[int, int], ...], ...]  # the connections crossed, per hop
    may_leave: np.ndarray  # an exit lies on the way, bool (h,)
    may_join: np.ndarray  # an entry lies on the way, bool (h,)
    in_order: np.ndarray  # its vehicles reach dst in the order they passed src, bool (h,)
    before: np.ndarray  # per station: fewest stations from an entry to it, int64 (n,)
    after: np.ndarray  # per station: fewest stations from it to an exit, int64 (n,)

    @property
    def size(self) -> int:
        return int(self.src.size)


def _turns(start_link: int, links: tuple[int, ...]) -> tuple[tuple[int, int], ...]:
    path = (start_link, *links)
    return tuple(zip(path[:-1], path[1:], strict=False))


def network_hops(net: RoadNetwork, max_skip: int) -> Hops:
    """Every hop of ``net`` over at most ``max_skip`` unseen stations (the shortest way per
    (src, dst, skipped))."""
    n = net.n_stations
    steps = [net.successors(s) for s in range(n)]
    best: dict[tuple[int, int, int], tuple[float, tuple, bool, bool]] = {}
    for s in range(n):
        # (station reached, distance, skipped, connections crossed, leave, join)
        frontier = [(st.index, st.distance_m, 0, _turns(int(net.station_links[s]), st.links),
                     st.may_leave, st.may_join) for st in steps[s]]  # fmt: skip
        while frontier:
            nxt = []
            for j, dist, skip, turns, leave, join in frontier:
                key = (s, j, skip)
                if key not in best or dist < best[key][0]:
                    best[key] = (dist, turns, leave, join)
                if skip < max_skip:
                    for st in steps[j]:
                        more = _turns(int(net.station_links[j]), st.links)
                        nxt.append((st.index, dist + st.distance_m, skip + 1, turns + more,
                                    leave or st.may_leave, join or st.may_join))  # fmt: skip
            frontier = nxt
    keys = sorted(best)
    src = np.array([k[0] for k in keys], np.int64)
    dst = np.array([k[1] for k in keys], np.int64)
    one_lane = {k.link_id: k.lanes == 1 for k in net.links}
    link = net.station_links

    def in_order(key: tuple[int, int, int]) -> bool:
        _, turns, leave, join = best[key]
        same = link[key[0]] == link[key[1]]
        return same and one_lane[int(link[key[0]])] and not (turns or key[2] or leave or join)

    return Hops(
        src=src,
        dst=dst,
        distance=np.array([best[k][0] for k in keys], float),
        skipped=np.array([k[2] for k in keys], np.int64),
        turns=tuple(best[k][1] for k in keys),
        may_leave=np.array([best[k][2] for k in keys], bool),
        may_join=np.array([best[k][3] for k in keys], bool),
        in_order=np.array([in_order(k) for k in keys], bool),
        before=_before(net, steps),
        after=_after(net, steps),
    )


def _before(net: RoadNetwork, steps: list) -> np.ndarray:
    """Fewest stations a vehicle passes between an entry and each station (0: reachable
    first from an entry, or an entry just before it)."""
    n = net.n_stations
    out = np.full(n, FAR, np.int64)
    for st in net.first_stations():
        out[st.index] = 0
    for s in range(n):
        for st in steps[s]:
            if st.may_join:
                out[st.index] = 0
    for _ in range(n):  # relax along the hops (Bellman-Ford on unit weights)
        changed = False
        for s in range(n):
            for st in steps[s]:
                if out[s] + 1 < out[st.index]:
                    out[st.index] = out[s] + 1
                    changed = True
        if not changed:
            break
    return out


def _after(net: RoadNetwork, steps: list) -> np.ndarray:
    """Fewest stations a vehicle passes between each station and an exit (0: an exit lies
    before the next station, or there is none)."""
    n = net.n_stations
    out = np.full(n, FAR, np.int64)
    for s in range(n):
        if not steps[s] or any(st.may_leave for st in steps[s]):
            out[s] = 0
    for _ in range(n):
        changed = False
        for s in range(n):
            for st in steps[s]:
                if out[st.index] + 1 < out[s]:
                    out[s] = out[st.index] + 1
                    changed = True
        if not changed:
            break
    return out
