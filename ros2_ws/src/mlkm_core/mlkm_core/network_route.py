"""A route through a road network as one road: what the time-space diagram draws of a network.

A network's positions lie on different links, so they share no axis. A *route* (links each of
which a connection joins to the one before) is a road again: a station on it stands at the
lengths of the route's links before its own plus its offset along its link. The diagram of a
route draws the detections of the stations on it against that distance, each track through
its detections there; a track that leaves the route leaves the picture.
"""

from __future__ import annotations

from collections.abc import Sequence

from mlkm_core.network import RoadNetwork


def parse_route(net: RoadNetwork, text: str) -> tuple[int, ...]:
    """'main_in,main_out' (link names or ids, comma-separated) -> link ids; ValueError naming
    an unknown link or a step no connection joins."""
    by_name = {k.name: k.link_id for k in net.links}
    ids = {k.link_id for k in net.links}
    route = []
    for token in (t.strip() for t in text.split(',')):
        if token in by_name:
            route.append(by_name[token])
        elif token.isdigit() and int(token) in ids:
            route.append(int(token))
        else:
            known = ', '.join(k.name for k in net.links)
            raise ValueError(f'route: no link {token!r} in the network (links: {known})')
    check_route(net, route)
    return tuple(route)


def check_route(net: RoadNetwork, route: Sequence[int]) -> None:
    """ValueError unless ``route`` is a non-empty path through the network's connections."""
    if not route:
        raise ValueError('route: give at least one link')
    if len(set(route)) < len(route):
        raise ValueError('route: a link appears twice')
    joined = set(net.connections)
    names = {k.link_id: k.name for k in net.links}
    for a, b in zip(route[:-1], route[1:]):
        if (a, b) not in joined:
            raise ValueError(f'route: no connection joins link {names[a]} to link {names[b]}')


def route_stations(net: RoadNetwork, route: Sequence[int]) -> dict[int, float]:
    """Station index -> its distance along ``route`` [m] for the stations on the route."""
    check_route(net, route)
    length = net.link_lengths
    out: dict[int, float] = {}
    before = 0.0
    for link in route:
        for offset, station in net.stations_along.get(link, ()):
            out[station] = before + offset
        before += length[link]
    return out


def main_route(net: RoadNetwork) -> tuple[int, ...]:
    """The route drawn when none is given: from each link a vehicle can start on, the next
    link with the most stations (then the first in the network's order) until none follows
    or a link would come twice; of those, the route with the most stations (then the
    longest, then the first)."""
    order = {k.link_id: i for i, k in enumerate(net.links)}
    count = {k.link_id: len(net.stations_along.get(k.link_id, ())) for k in net.links}
    after: dict[int, list[int]] = {}
    for a, b in net.connections:
        after.setdefault(a, []).append(b)
    starts = sorted({k for k, _ in net.entries}, key=order.get)
    best: tuple = ()
    best_key = None
    for start in starts:
        route = [start]
        while True:
            nxt = [b for b in after.get(route[-1], []) if b not in route]
            if not nxt:
                break
            route.append(max(nxt, key=lambda b: (count[b], -order[b])))
        key = (sum(count[k] for k in route), sum(net.link_lengths[k] for k in route))
        if best_key is None or key > best_key:
            best, best_key = tuple(route), key
    return best
