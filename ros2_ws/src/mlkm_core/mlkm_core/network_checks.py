"""Validation of a road network's parts (``mlkm_core.network.RoadNetwork``): each function
returns the part in its normal form or raises ValueError naming the entry and the reason."""

from __future__ import annotations

import math

import numpy as np

from mlkm_core.layout_file import NAME


def graph(links, connections) -> tuple[tuple[int, int], ...]:
    """Link ids and names unique; connections between known links, no self-loop, none twice."""
    unique('link id', [k.link_id for k in links])
    unique('link name', [k.name for k in links])
    known = {k.link_id for k in links}
    out = tuple((int(a), int(b)) for a, b in connections)
    for a, b in out:
        for end in (a, b):
            if end not in known:
                raise ValueError(f'connection {a} -> {b}: link {end} is not in the network')
        if a == b:
            raise ValueError(f'connection {a} -> {b} joins a link to itself')
    unique('connection', [f'{a} -> {b}' for a, b in out])
    return out


def stations(ids, names, links, offsets, lanes, lengths: dict[int, float]) -> tuple:
    """(ids int64, names tuple, links int64, offsets float, lanes int64): at least one
    station, parallel, ids >= 0 and names (topic tokens) unique, each on a known link within
    [0, its length] m, no two at one place, lanes >= 0 (None: all unknown, 0)."""
    ids = np.asarray(ids, np.int64).reshape(-1)
    n = ids.size
    if n == 0:
        raise ValueError('a network needs at least one station')
    on = np.asarray(links, np.int64).reshape(-1)
    at = np.asarray(offsets, float).reshape(-1)
    lanes = np.asarray(np.zeros(n) if lanes is None else lanes, np.int64).reshape(-1)
    names = tuple(names)
    if not (len(names) == on.size == at.size == lanes.size == n):
        raise ValueError('station ids, names, links, offsets and lanes differ in length')
    unique('station id', ids.tolist())
    unique('station name', list(names))
    places = set()
    for sid, name, link, x, lane in zip(ids.tolist(), names, on.tolist(), at, lanes):
        where = f'station {sid} ({name})'
        if sid < 0:
            raise ValueError(f'{where}: id must be >= 0')
        if not isinstance(name, str) or not NAME.match(name):
            raise ValueError(f'{where}: name is not a topic name token')
        if link not in lengths:
            raise ValueError(f'{where}: link {link} is not in the network')
        if not (math.isfinite(x) and 0.0 <= x <= lengths[link]):
            raise ValueError(
                f'{where}: position {x:g} m is off link {link} [0, {lengths[link]:g}] m'
            )
        if lane < 0:
            raise ValueError(f'{where}: lanes must be >= 0, got {lane}')
        if (link, x) in places:
            raise ValueError(f'{where}: another station stands on link {link} at {x:g} m')
        places.add((link, x))
    return ids, names, on, at, lanes


def points(what: str, given, lengths: dict[int, float]) -> list[tuple[int, float]]:
    """Entries or exits as (link id, position [m]): on a known link, within it, none twice."""
    out = []
    for link, x in given:
        link, x = int(link), float(x)
        if link not in lengths:
            raise ValueError(f'{what} on link {link}: link {link} is not in the network')
        if not (math.isfinite(x) and 0.0 <= x <= lengths[link]):
            raise ValueError(
                f'{what} on link {link} at {x:g} m: off the link [0, {lengths[link]:g}] m'
            )
        if (link, x) in out:
            raise ValueError(f'{what} on link {link} at {x:g} m is given twice')
        out.append((link, x))
    return out


def unique(what: str, values: list) -> None:
    """ValueError naming the first value given twice."""
    seen = set()
    for v in values:
        if v in seen:
            raise ValueError(f'{what} {v!r} is used twice')
        seen.add(v)
