"""A road network: directed links (road sections) joined at junctions, stations on the links.

A vehicle drives along a link from its start (0 m) to its end (``length`` m) and, at the end,
may continue at the start of any link a connection ``(from, to)`` names. It comes into the
network at an *entry* (a link start, or a point inside a link: a driveway, a parking exit)
and leaves it at an *exit* (a link end, or a point inside a link). Stations stand on links,
at a position along their link [m]; their ids and names are unique over the network.

Implicit ends: a link that no connection leads into and that has no explicit entry gets an
entry at its start; a link that no connection leaves and that has no explicit exit gets an
exit at its end. :attr:`RoadNetwork.entries` and :attr:`RoadNetwork.exits` include them, so a
network written out and read back is the same network.

A single road (the product's original world, :class:`mlkm_core.layout_file.RoadLayout`) is
the simple case: :meth:`RoadNetwork.single_road` makes its one-link network and
:meth:`RoadNetwork.road_layout` turns a chain of links back into one road. The YAML form
(``mlkm_core.network_file``) and the ``SensorLayout`` message (``mlkm_ros``) carry the same
description; :func:`network_from_mapping` / :func:`network_to_mapping` convert it to and from
plain data (what a YAML file holds).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from mlkm_core import network_checks as check
from mlkm_core.layout_file import NAME, LayoutFileError, RoadLayout, finite, unknown_keys
from mlkm_core.network_links import RoadLink, default_link_name
from mlkm_core.network_paths import StationStep, first_steps, free_reach, steps_from
from mlkm_core.types import Layout, default_sensor_name

LINK_KEYS = ('id', 'name', 'length_m', 'lanes', 'shape_m')
STATION_KEYS = ('id', 'name', 'link', 'position_m', 'lanes')
POINT_KEYS = ('link', 'position_m')
STATION_FIELDS = (
    'station_ids',
    'station_names',
    'station_links',
    'station_offsets',
    'station_lanes',
)
TOP_KEYS = ('links', 'connections', 'entries', 'exits', 'stations')


@dataclass(frozen=True, eq=False)
class RoadNetwork:
    """Links, connections, stations and the places vehicles enter and leave (module
    docstring). Stations are parallel arrays, in the order given. Raises ValueError with the
    reason when the description is inconsistent."""

    links: tuple[RoadLink, ...]
    connections: tuple[tuple[int, int], ...]  # (from link id, to link id)
    station_ids: np.ndarray  # int64 (n,), unique, >= 0
    station_names: tuple[str, ...]  # unique topic name tokens
    station_links: np.ndarray  # link id of each station, int64 (n,)
    station_offsets: np.ndarray  # position along the station's link [m], float (n,)
    station_lanes: np.ndarray = field(default=None)  # loops per station, 0 = unknown (n,)
    entries: tuple[tuple[int, float], ...] = ()  # (link id, position [m]), implicit added
    exits: tuple[tuple[int, float], ...] = ()  # (link id, position [m]), implicit added

    def __post_init__(self) -> None:
        links = tuple(self.links)
        if not links or not all(isinstance(k, RoadLink) for k in links):
            raise ValueError('a network needs at least one RoadLink')
        lengths = {k.link_id: k.length for k in links}
        connections = check.graph(links, self.connections)
        stations = check.stations(
            self.station_ids, self.station_names, self.station_links, self.station_offsets,
            self.station_lanes, lengths,
        )  # fmt: skip
        entries = check.points('entry', self.entries, lengths)
        exits = check.points('exit', self.exits, lengths)
        into, out_of = {b for _, b in connections}, {a for a, _ in connections}
        with_entry, with_exit = {k for k, _ in entries}, {k for k, _ in exits}
        entries += [(k.link_id, 0.0) for k in links if k.link_id not in into | with_entry]
        exits += [(k.link_id, k.length) for k in links if k.link_id not in out_of | with_exit]
        order = {k.link_id: i for i, k in enumerate(links)}
        values = dict(zip(STATION_FIELDS, stations), links=links, connections=connections)
        for name, points in (('entries', entries), ('exits', exits)):
            values[name] = tuple(sorted(points, key=lambda p: (order[p[0]], p[1])))
        for name, value in values.items():
            object.__setattr__(self, name, value)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RoadNetwork):
            return NotImplemented
        arrays = ('station_ids', 'station_links', 'station_offsets', 'station_lanes')
        plain = ('links', 'connections', 'station_names', 'entries', 'exits')
        return all(getattr(self, a) == getattr(other, a) for a in plain) and all(
            np.array_equal(getattr(self, a), getattr(other, a)) for a in arrays
        )

    __hash__ = None  # holds arrays

    @property
    def n_stations(self) -> int:
        return int(self.station_ids.size)

    # --- the graph ------------------------------------------------------------------------

    @cached_property
    def link_lengths(self) -> dict[int, float]:
        """{link id: its length [m]}."""
        return {k.link_id: k.length for k in self.links}

    @cached_property
    def link_successors(self) -> dict[int, tuple[int, ...]]:
        """{link id: the ids of the links a vehicle can continue on at its end}."""
        out: dict[int, list[int]] = {k.link_id: [] for k in self.links}
        for a, b in self.connections:
            out[a].append(b)
        return {k: tuple(sorted(v)) for k, v in out.items()}

    @cached_property
    def stations_along(self) -> dict[int, list[tuple[float, int]]]:
        """{link id: (position [m], station index) of its stations, in driving order}."""
        on: dict[int, list[tuple[float, int]]] = {k.link_id: [] for k in self.links}
        for i, (link, x) in enumerate(zip(self.station_links.tolist(), self.station_offsets)):
            on[link].append((float(x), i))
        return {k: sorted(v) for k, v in on.items()}

    @cached_property
    def entries_along(self) -> dict[int, tuple[float, ...]]:
        """{link id: the positions [m] of its entries}."""
        return self._along(self.entries)

    @cached_property
    def exits_along(self) -> dict[int, tuple[float, ...]]:
        """{link id: the positions [m] of its exits}."""
        return self._along(self.exits)

    def _along(self, points) -> dict[int, tuple[float, ...]]:
        return {k.link_id: tuple(x for j, x in points if j == k.link_id) for k in self.links}

    @cached_property
    def free_reach(self) -> dict[int, frozenset[int]]:
        """{link without stations: the links with stations reachable from it through links
        without stations} (mlkm_core.network_paths)."""
        return free_reach(self)

    def successors(self, station_index: int) -> list[StationStep]:
        """The stations a vehicle seen at ``station_index`` can reach next without passing
        another station: the next one downstream on its own link if there is one, else the
        first station on each link reachable across junctions through links without stations.

        One step per station, sorted by distance: the distance and ``links`` of the shortest
        way (a cycle of links without a station makes the ways many, the shortest counts);
        ``may_leave`` / ``may_join`` say whether an exit / entry lies on any way there. An exit
        at a station's position lies after it, an entry at a station's position before it."""
        if not 0 <= station_index < self.n_stations:
            raise IndexError(f'station index {station_index} outside [0, {self.n_stations})')
        link = int(self.station_links[station_index])
        return steps_from(self, link, float(self.station_offsets[station_index]), False)

    def first_stations(self) -> list[StationStep]:
        """The stations a vehicle can reach first from the entries (an entry at a station's
        position lies before it): one step per station, over every entry, with the shortest
        distance from an entry and its ``links``; ``may_join`` says whether another entry lies
        on a way there, ``may_leave`` whether an exit does."""
        return first_steps(self)

    # --- the single road ------------------------------------------------------------------

    def _chain(self) -> list[int] | str:
        """The link ids of a single road in driving order, or why the network is not one."""
        ins: dict[int, int] = {k.link_id: 0 for k in self.links}
        for _, b in self.connections:
            ins[b] += 1
        for k, nxt in self.link_successors.items():
            if len(nxt) > 1:
                return f'link {k} branches into links {list(nxt)}'
            if ins[k] > 1:
                return f'link {k} is where {ins[k]} links merge'
        heads = [k for k, n in ins.items() if n == 0]
        if len(heads) != 1:
            return 'its links form a cycle' if not heads else f'it has {len(heads)} separate roads'
        chain = heads
        while self.link_successors[chain[-1]]:
            chain.append(self.link_successors[chain[-1]][0])
        if len(chain) != len(self.links):
            return 'some of its links form a cycle apart from the road'
        return chain

    def is_single_road(self) -> bool:
        """One chain of links (no branch, no merge, no cycle); entries and exits may lie
        anywhere on it."""
        return not isinstance(self._chain(), str)

    @classmethod
    def single_road(cls, road: RoadLayout) -> RoadNetwork:
        """The one-link network of a single road: link 0 (``link_0``) of the road's length,
        entered at its start and left at its end, with the road's ramps as entries and exits
        inside the link."""
        lay = road.layout
        length = float(lay.road_length)
        entries = dict.fromkeys([(0, 0.0), *((0, float(x)) for x in road.entries)])
        exits = dict.fromkeys([*((0, float(x)) for x in road.exits), (0, length)])
        return cls(
            links=(RoadLink(0, default_link_name(0), length),),
            connections=(),
            station_ids=lay.sensor_ids,
            station_names=lay.names,
            station_links=np.zeros(lay.n_sensors, np.int64),
            station_offsets=lay.positions,
            station_lanes=road.lanes,
            entries=tuple(entries),
            exits=tuple(exits),
        )

    def road_layout(self) -> RoadLayout:
        """A single road as the product's RoadLayout: positions along the chain of links,
        the entries and exits other than the chain's start and end as its ramps. ValueError
        when the network is not a single road."""
        chain = self._chain()
        if isinstance(chain, str):
            raise ValueError(f'not a single road: {chain}')
        start, at = {}, 0.0
        for k in chain:
            start[k] = at
            at += self.link_lengths[k]
        pos = np.array([start[k] + x for k, x in zip(self.station_links, self.station_offsets)])
        order = np.argsort(pos, kind='stable')
        head, tail = (chain[0], 0.0), (chain[-1], self.link_lengths[chain[-1]])
        layout = Layout(at, pos[order], self.station_ids[order],
                        tuple(self.station_names[i] for i in order))  # fmt: skip
        return RoadLayout(
            layout,
            self.station_lanes[order],
            tuple(sorted(start[k] + x for k, x in self.entries if (k, x) != head)),
            tuple(sorted(start[k] + x for k, x in self.exits if (k, x) != tail)),
        )


# --- plain data (the YAML form) -------------------------------------------------------------


def network_from_mapping(data: dict, source: str) -> RoadNetwork:
    """The network of a mapping in the YAML form (``mlkm_core.network_file``): ``links``
    (id, name = ``link_<id>``, length_m, lanes = 0, shape_m = none: [[x, y], ...] [m]),
    ``connections`` (from, to), ``entries``
    (link, position_m = 0), ``exits`` (link, position_m = the link's length), ``stations`` (id,
    name = ``sensor_<id>``, link, position_m, lanes = 0). Raises LayoutFileError naming
    ``source`` (a file) and the entry; unknown keys are errors."""
    if not isinstance(data, dict):
        raise LayoutFileError(f'{source}: expected a mapping with {", ".join(TOP_KEYS)}')
    unknown_keys(data, TOP_KEYS, source)
    links = []
    for at, d in _entries(data, 'links', LINK_KEYS, source, needed=True):
        link_id = _count(d, 'id', at, None)
        length = d.get('length_m')
        if not finite(length) or not length > 0:
            raise LayoutFileError(f'{at}: length_m must be a finite number > 0, got {length!r}')
        name = _name(d, at, default_link_name(link_id))
        try:
            links.append(RoadLink(link_id, name, float(length), _count(d, 'lanes', at, 0),
                                  d.get('shape_m') or ()))  # fmt: skip
        except ValueError as exc:
            raise LayoutFileError(f'{at}: {exc}') from None
    lengths = {k.link_id: k.length for k in links}
    connections = []
    for at, d in _entries(data, 'connections', ('from', 'to'), source):
        connections.append((_count(d, 'from', at, None), _count(d, 'to', at, None)))
    ends = []
    for key in ('entries', 'exits'):
        points = []
        for at, d in _entries(data, key, POINT_KEYS, source):
            link = _count(d, 'link', at, None)
            if link not in lengths:
                raise LayoutFileError(f'{at}: link {link} is not one of the links')
            end = 0.0 if key == 'entries' else lengths[link]
            points.append((link, _position(d, at, end)))
        ends.append(tuple(points))
    rows = []
    for at, d in _entries(data, 'stations', STATION_KEYS, source, needed=True):
        sid = _count(d, 'id', at, None)
        rows.append((sid, _name(d, at, default_sensor_name(sid)), _count(d, 'link', at, None),
                     _position(d, at, None), _count(d, 'lanes', at, 0)))  # fmt: skip
    try:
        return RoadNetwork(
            tuple(links),
            tuple(connections),
            np.array([r[0] for r in rows], np.int64),
            tuple(r[1] for r in rows),
            np.array([r[2] for r in rows], np.int64),
            np.array([r[3] for r in rows], float),
            np.array([r[4] for r in rows], np.int64),
            *ends,
        )
    except ValueError as exc:
        raise LayoutFileError(f'{source}: {exc}') from None


def network_to_mapping(net: RoadNetwork) -> dict:
    """The YAML form of ``net`` as plain data (what :func:`network_from_mapping` reads back to
    an equal network). An entry or exit the implicit rule would add anyway is left out."""
    into = {b for _, b in net.connections}
    out_of = {a for a, _ in net.connections}
    length = {k.link_id: k.length for k in net.links}

    def implicit(points, link: int, x: float, joined: set[int], end: float) -> bool:
        return (
            link not in joined and x == end and [p for p in points if p[0] == link] == [(link, x)]
        )

    return {
        'links': [
            {'id': k.link_id, 'name': k.name, 'length_m': k.length, 'lanes': k.lanes}
            | ({'shape_m': [list(p) for p in k.shape]} if k.shape else {})
            for k in net.links
        ],
        'connections': [{'from': a, 'to': b} for a, b in net.connections],
        'entries': [
            {'link': k, 'position_m': x}
            for k, x in net.entries
            if not implicit(net.entries, k, x, into, 0.0)
        ],
        'exits': [
            {'link': k, 'position_m': x}
            for k, x in net.exits
            if not implicit(net.exits, k, x, out_of, length[k])
        ],
        'stations': [
            {'id': int(i), 'name': n, 'link': int(k), 'position_m': float(x), 'lanes': int(c)}
            for i, n, k, x, c in zip(
                net.station_ids,
                net.station_names,
                net.station_links,
                net.station_offsets,
                net.station_lanes,
            )  # fmt: skip
        ],
    }


def _entries(data: dict, key: str, keys: tuple[str, ...], source: str, needed: bool = False):
    """(where, mapping) of each entry of the list ``data[key]``."""
    values = data.get(key)
    if values is None and not needed:
        return
    if not isinstance(values, list) or (needed and not values):
        raise LayoutFileError(f'{source}: {key}: a {"non-empty " * needed}list is needed')
    for k, d in enumerate(values):
        at = f'{source}: {key}[{k}]'
        if not isinstance(d, dict):
            raise LayoutFileError(f'{at}: expected a mapping with {", ".join(keys)}')
        unknown_keys(d, keys, at)
        yield at, d


def _count(d: dict, key: str, at: str, default: int | None) -> int:
    v = d.get(key, default)
    if not isinstance(v, int) or isinstance(v, bool) or v < 0:
        raise LayoutFileError(f'{at}: {key} must be an integer >= 0, got {v!r}')
    return v


def _position(d: dict, at: str, default: float | None) -> float:
    v = d.get('position_m', default)
    if not finite(v) or v < 0:
        raise LayoutFileError(f'{at}: position_m must be a finite number >= 0, got {v!r}')
    return float(v)


def _name(d: dict, at: str, default: str) -> str:
    name = d.get('name', default)
    if not isinstance(name, str) or not NAME.match(name):
        raise LayoutFileError(
            f'{at}: name {name!r} is not a topic name token (a letter, then letters, digits or _)'
        )
    return name
