"""The ways between stations of a road network (``mlkm_core.network``): which station a
vehicle can reach next, how far it is, and whether an entry or exit lies on the way.

A search over links entered at their start (Dijkstra on the distance [m]), stopping at the
first station of every link that has one; it ends on cycles, also on a cycle of links
without stations, where the shortest way counts.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass
from typing import Protocol


class RoadNetwork(Protocol):
    """What the search reads of a ``mlkm_core.network.RoadNetwork`` (which builds on this
    module, so it is not imported here)."""

    entries: tuple[tuple[int, float], ...]
    link_lengths: dict[int, float]
    link_successors: dict[int, tuple[int, ...]]
    stations_along: dict[int, list[tuple[float, int]]]
    entries_along: dict[int, tuple[float, ...]]
    exits_along: dict[int, tuple[float, ...]]
    free_reach: dict[int, frozenset[int]]


@dataclass(frozen=True)
class StationStep:
    """A station a vehicle can reach next, and what lies on the way to it."""

    index: int  # the station reached, an index into the network's station arrays
    distance_m: float  # along the shortest way [m]
    links: tuple[int, ...]  # link ids entered on that way after the start link (junctions)
    may_leave: bool  # an exit lies on a way there: the vehicle may never arrive
    may_join: bool  # an entry lies on a way there: the station may see a vehicle new to it


def free_reach(net: RoadNetwork) -> dict[int, frozenset[int]]:
    """Per link without stations: the links with stations a vehicle can reach from its
    start, passing only links without stations."""
    free = {k for k, v in net.stations_along.items() if not v}
    reach = {}
    for start in free:
        seen, todo, hit = {start}, [start], set()
        while todo:
            for nxt in net.link_successors[todo.pop()]:
                if nxt not in free:
                    hit.add(nxt)
                elif nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        reach[start] = frozenset(hit)
    return reach


def first_steps(net: RoadNetwork) -> list[StationStep]:
    """RoadNetwork.first_stations: the steps from every entry, merged per station."""
    best: dict[int, StationStep] = {}
    for link, x in net.entries:
        for s in steps_from(net, link, x, True):
            old = best.get(s.index)
            if old is not None:
                keep = s if s.distance_m < old.distance_m else old
                leave, join = s.may_leave or old.may_leave, s.may_join or old.may_join
                s = StationStep(s.index, keep.distance_m, keep.links, leave, join)
            best[s.index] = s
    return sorted(best.values(), key=lambda s: (s.distance_m, s.index))


def steps_from(net: RoadNetwork, link: int, x: float, at_entry: bool) -> list[StationStep]:
    """The steps from position ``x`` [m] on ``link``, one per station reached, sorted by
    distance; ``at_entry``: a station at ``x`` counts (a vehicle that enters there passes
    it), else only stations beyond ``x``. An exit at ``x`` lies on the way, an entry at ``x``
    does not."""
    on, length = net.stations_along, net.link_lengths
    entries, exits = net.entries_along, net.exits_along
    ahead = [(o, i) for o, i in on[link] if o > x or (at_entry and o == x)]
    if ahead:
        o, j = ahead[0]
        leave = _has(exits[link], x, o, True, False)
        join = _has(entries[link], x, o, False, True)
        return [StationStep(j, o - x, (), leave, join)]
    leave0 = _has(exits[link], x, length[link], True, True)
    join0 = _has(entries[link], x, length[link], False, True)
    best: dict[int, tuple[float, tuple[int, ...]]] = {}
    heap = [(length[link] - x, (nxt,)) for nxt in net.link_successors[link]]
    heapq.heapify(heap)
    while heap:
        d, path = heapq.heappop(heap)
        here = path[-1]
        if here in best:
            continue
        best[here] = (d, path)
        if not on[here]:
            for nxt in net.link_successors[here]:
                if nxt not in best:
                    heapq.heappush(heap, (d + length[here], (*path, nxt)))
    # links without stations reached on the way that hold an exit / an entry
    leaky = [k for k in best if not on[k] and exits[k]]
    joining = [k for k in best if not on[k] and entries[k]]
    reach = net.free_reach
    steps = []
    for here, (d, path) in best.items():
        if not on[here]:
            continue
        o, j = on[here][0]
        leave = leave0 or _has(exits[here], 0.0, o, True, False)
        join = join0 or _has(entries[here], 0.0, o, True, True)
        leave = leave or any(here in reach[k] for k in leaky)
        join = join or any(here in reach[k] for k in joining)
        steps.append(StationStep(j, d + o, path, leave, join))
    return sorted(steps, key=lambda s: (s.distance_m, s.index))


def _has(points: tuple[float, ...], lo: float, hi: float, lo_in: bool, hi_in: bool) -> bool:
    """Whether one of ``points`` [m] lies between ``lo`` and ``hi``, each end included or
    not."""
    return any((lo < p or (lo_in and p == lo)) and (p < hi or (hi_in and p == hi)) for p in points)
