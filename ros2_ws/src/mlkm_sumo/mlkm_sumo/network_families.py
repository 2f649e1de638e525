"""Road-network scenario families: junction layouts, routes, signals and stations per seed.

A family is a table of ranges (``NETWORK_FAMILIES``); ``draw_network(family, seed)`` turns it
into one ``NetworkDraw``: the nodes and edges of the network (SUMO plain-XML terms), the
routes with their probabilities (route choice and turning shares), the total demand, the
signal timings of the signalised junctions, the vehicle mix and, per edge, how many stations
it carries and where (as fractions of the edge, because the built edge lengths are only known
after netconvert). The draw is a pure function of (family, seed, overrides): ``to_json()``
records everything needed to rebuild the network and the traffic.

Families (x east, y north, positions [m], speeds [m/s], flows [vehicles/h]):

- ``interchange``: a freeway A (edges ``a_in`` -> ``a_out``, eastbound) and a second one C
  (``c_in`` -> ``d_out``, southbound) that crosses it on a bridge; a one-lane connector
  ``link_ac`` leaves A on its right at a diverge and joins C on its right at a merge, onto an
  acceleration lane (edge ``d_acc``) that ends where ``d_out`` begins. Routes: A through, C
  through, A to D (the connector share).
- ``arterial``: a two-way arterial (eastbound ``ae<k>``, westbound ``aw<k>``) through 3-5
  signalised intersections ``j<k>`` with two-way cross streets (``n<k>_in/out``,
  ``s<k>_in/out``); at each intersection a vehicle turns left or right with the drawn shares
  of its approach, else goes straight, so routes are chains of turns.
- ``grid``: a grid of two-way streets (eastbound ``he<c>_<r>``, westbound ``hw<c>_<r>``,
  northbound ``vn<c>_<r>``, southbound ``vs<c>_<r>``) with a stub in and out at every boundary
  side of every boundary junction (``in_<side><k>``, ``out_<side><k>``); each junction is
  signalised with the drawn share, else a priority junction (east-west streets have way);
  random origin-destination routes along random monotone (never backwards) paths.

Signals share one drawn cycle per network (a coordinated plan); each junction draws its green
split and its offset in [0, cycle).
"""

from __future__ import annotations

import json
import zlib
from dataclasses import asdict, dataclass, field

import numpy as np

from .families import COMMON, _vtypes
from .network import SumoError

#: Ranges per family; (low, high) uniform, integer pairs inclusive. Lengths [m], speeds
#: [m/s], flows [vehicles/h], shares as fractions, times [s]. ``spacing`` is the distance
#: between stations along a link, ``coverage`` the share of links that carry stations.
NETWORK_FAMILIES: dict[str, dict] = {
    'interchange': {
        'lanes_a': (2, 3),
        'lanes_c': (2, 3),
        'length_in': (900.0, 1500.0),  # a_in and c_in
        'length_out': (700.0, 1200.0),  # a_out and d_out
        'connector_run': (200.0, 450.0),  # from the diverge along A to C
        'connector_drop': (150.0, 350.0),  # from A along C to the merge
        'accel_length': (200.0, 300.0),  # the acceleration lane after the merge
        'speed': (27.78, 33.33),  # 100-120 km/h
        'connector_speed': (16.67, 22.22),  # 60-80 km/h
        'flow_a': (900.0, 2000.0),
        'flow_c': (600.0, 1500.0),
        'connector_share': (0.15, 0.45),  # of A's vehicles
        'vehicles': (200, 320),
        'spacing': (300.0, 600.0),
        'coverage': (0.8, 1.0),
    },
    'arterial': {
        'intersections': (3, 5),
        'block': (220.0, 420.0),  # between intersections
        'approach': (250.0, 400.0),  # arterial ends and cross streets
        'lanes': (1, 2),  # arterial, per direction (cross streets: 1)
        'speed': (13.89, 16.67),  # 50-60 km/h
        'cross_speed': (11.11, 13.89),  # 40-50 km/h
        'flow_arterial': (350.0, 750.0),  # per direction
        'flow_cross': (60.0, 180.0),  # per cross-street entry
        'turn_arterial': (0.05, 0.2),  # left and right shares each, per intersection
        'turn_cross': (0.2, 0.4),
        'cycle': (60.0, 100.0),
        'split': (0.5, 0.7),  # arterial share of the green time
        'vehicles': (220, 320),
        'spacing': (150.0, 300.0),
        'coverage': (0.8, 1.0),
    },
    'grid': {
        'columns': (3, 4),
        'rows': (3, 3),
        'block': (160.0, 280.0),
        'stub': (150.0, 250.0),
        'speed': (11.11, 13.89),
        'signal_share': (0.3, 1.0),  # of the junctions
        'routes': (30, 60),
        'flow': (700.0, 1300.0),
        'cycle': (50.0, 90.0),
        'split': (0.4, 0.6),  # east-west share of the green time
        'vehicles': (180, 280),
        'spacing': (120.0, 250.0),
        'coverage': (0.75, 1.0),
    },
}
#: Largest share of a station's position jitter (of the gap between stations on its link).
STATION_JITTER = 0.25
#: Priorities of the edge kinds (netconvert gives way to the higher one).
PRIORITY = {'main': 3, 'minor': 1}


@dataclass
class NetworkDraw:
    """One drawn network scenario (module docstring). ``params`` holds every drawn scalar;
    ``nodes``: ``{id, x, y, type}``; ``edges``: ``{id, from, to, lanes, speed, main}`` in the
    order that numbers the links; ``routes``: ``{edges, probability}``; ``signals``: per
    signalised node ``{cycle, split, offset}`` [s, share, s]; ``stations``: per edge with
    stations ``{edge, fractions}``; ``vtypes`` as ``families.Draw``."""

    family: str
    seed: int
    overrides: dict
    params: dict
    flow: float  # total demand [vehicles/h]
    vehicles: int
    nodes: list[dict] = field(default_factory=list)
    edges: list[dict] = field(default_factory=list)
    routes: list[dict] = field(default_factory=list)
    signals: dict = field(default_factory=dict)
    stations: list[dict] = field(default_factory=list)
    mix: str = 'two_type'
    vtypes: list[dict] = field(default_factory=list)
    lane_connections: list[dict] = field(default_factory=list)

    def to_json(self) -> dict:
        return asdict(self)

    def __str__(self) -> str:
        n_st = sum(len(s['fractions']) for s in self.stations)
        lines = [
            f'{self.family} seed {self.seed}: {len(self.edges)} links, {len(self.nodes)} nodes, '
            f'{len(self.signals)} signals, {len(self.routes)} routes, {n_st} stations, '
            f'{self.vehicles} vehicles at {self.flow:g} vehicles/h, {self.mix} mix',
            '  ' + json.dumps(self.params, sort_keys=True),
        ]
        for node, s in sorted(self.signals.items()):
            lines.append(
                f'  signal {node}: cycle {s["cycle"]:g} s, split {s["split"]:g}, '
                f'offset {s["offset"]:g} s'
            )
        return '\n'.join(lines)


class _Drawer:
    """Draws of one family and seed; an override replaces a drawn scalar after its draw, so
    that the random stream (and the rest of the draw) stays that of (family, seed)."""

    def __init__(self, name: str, seed: int, overrides: dict) -> None:
        self.ranges = NETWORK_FAMILIES[name]
        self.overrides = overrides
        self.rng = np.random.default_rng([zlib.crc32(name.encode()), int(seed)])
        self.params: dict = {}

    def __call__(self, key: str, digits: int = 2):
        lo, hi = self.ranges[key]
        if isinstance(lo, int):
            value = int(self.rng.integers(lo, hi + 1))
        else:
            value = round(float(self.rng.uniform(lo, hi)), digits)
        if key in self.overrides:
            value = type(value)(self.overrides[key])
        self.params[key] = value
        return value

    def each(self, key: str, n: int, digits: int = 3) -> list[float]:
        """``n`` independent draws of ``key`` (per junction, per entry); an override sets
        them all."""
        values = [round(float(x), digits) for x in self.rng.uniform(*self.ranges[key], n)]
        if key in self.overrides:
            values = [float(self.overrides[key])] * n
        self.params.setdefault(key, []).extend(values)
        return values


def _node(nid: str, x: float, y: float, kind: str = 'priority') -> dict:
    return {'id': nid, 'x': round(x, 1), 'y': round(y, 1), 'type': kind}


def _edge(eid: str, a: str, b: str, lanes: int, speed: float, main: bool) -> dict:
    return {'id': eid, 'from': a, 'to': b, 'lanes': lanes, 'speed': speed, 'main': main}


def _lane(a: str, b: str, from_lane: int, to_lane: int) -> dict:
    return {'from': a, 'to': b, 'fromLane': from_lane, 'toLane': to_lane}


def _interchange(d: _Drawer) -> tuple[list, list, list, dict, float, list]:
    la, lc = d('lanes_a'), d('lanes_c')
    ina, inc = d.each('length_in', 2, 1)
    outa, outc = d.each('length_out', 2, 1)
    run, drop = d('connector_run', 1), d('connector_drop', 1)
    acc = d('accel_length', 1)
    v, vc = d('speed'), d('connector_speed')
    fa, fc, share = d('flow_a', 1), d('flow_c', 1), d('connector_share', 3)
    # A runs east along y = 0; C runs south along x = xc and crosses A on a bridge (no
    # junction); the connector leaves A on its right at the diverge and joins C on its right
    # at the merge, ``run`` m east of the diverge and ``drop`` m south of A, onto an
    # acceleration lane (``d_acc``, one lane more than C) that ends ``acc`` m further on.
    xc = ina + run
    nodes = [
        _node('a0', 0.0, 0.0), _node('div', ina, 0.0), _node('a1', ina + outa, 0.0),
        _node('c0', xc, inc - drop), _node('mrg', xc, -drop), _node('acc', xc, -drop - acc),
        _node('d1', xc, -drop - acc - outc),
    ]  # fmt: skip
    edges = [
        _edge('a_in', 'a0', 'div', la, v, True),
        _edge('a_out', 'div', 'a1', la, v, True),
        _edge('link_ac', 'div', 'mrg', 1, vc, False),
        _edge('c_in', 'c0', 'mrg', lc, v, True),
        _edge('d_acc', 'mrg', 'acc', lc + 1, v, True),
        _edge('d_out', 'acc', 'd1', lc, v, True),
    ]
    lanes = [_lane('link_ac', 'd_acc', 0, 0)]
    lanes += [_lane('c_in', 'd_acc', i, i + 1) for i in range(lc)]
    lanes += [_lane('d_acc', 'd_out', i + 1, i) for i in range(lc)]
    total = fa + fc
    routes = [
        {'edges': ['a_in', 'a_out'], 'probability': fa * (1 - share) / total},
        {'edges': ['a_in', 'link_ac', 'd_acc', 'd_out'], 'probability': fa * share / total},
        {'edges': ['c_in', 'd_acc', 'd_out'], 'probability': fc / total},
    ]
    return nodes, edges, routes, {}, total, lanes


def _signal(d: _Drawer, cycle: float) -> dict:
    """One junction's timing on the network's common cycle [s]: its green split and offset."""
    split = d.each('split', 1)[0]
    offset = round(float(d.rng.uniform(0.0, cycle)), 1)
    return {'cycle': cycle, 'split': split, 'offset': offset}


def _arterial(d: _Drawer) -> tuple[list, list, list, dict, float, list]:
    n = d('intersections')
    lanes, v, vc = d('lanes'), d('speed'), d('cross_speed')
    approach = d('approach', 1)
    blocks = d.each('block', n - 1, 1)
    xs = [approach + sum(blocks[:k]) for k in range(n)]
    nodes = [_node('w', 0.0, 0.0), _node('e', xs[-1] + approach, 0.0)]
    nodes += [_node(f'j{k}', x, 0.0, 'traffic_light') for k, x in enumerate(xs)]
    nodes += [_node(f'{s}{k}', x, y * approach) for k, x in enumerate(xs) for s, y in
              (('n', 1.0), ('s', -1.0))]  # fmt: skip
    chain = ['w', *(f'j{k}' for k in range(n)), 'e']
    edges = []
    for k in range(n + 1):  # arterial segment k joins chain[k] and chain[k + 1]
        edges.append(_edge(f'ae{k}', chain[k], chain[k + 1], lanes, v, True))
        edges.append(_edge(f'aw{k}', chain[k + 1], chain[k], lanes, v, True))
    for k in range(n):
        for s in 'ns':
            edges.append(_edge(f'{s}{k}_in', f'{s}{k}', f'j{k}', 1, vc, False))
            edges.append(_edge(f'{s}{k}_out', f'j{k}', f'{s}{k}', 1, vc, False))
    cycle = d('cycle', 1)
    signals = {f'j{k}': _signal(d, cycle) for k in range(n)}
    # per intersection and arterial direction: (left, right) shares; per cross entry too
    art = {(k, h): d.each('turn_arterial', 2) for k in range(n) for h in 'EW'}
    cross = {(k, h): d.each('turn_cross', 2) for k in range(n) for h in 'SN'}
    fe, fw = d.each('flow_arterial', 2, 1)
    fcross = iter(d.each('flow_cross', 2 * n, 1))
    # (first edge, heading, the junction it reaches, flow): the arterial ends, then the cross
    # streets (from the north heading south, from the south heading north)
    entries = [('ae0', 'E', 0, fe), (f'aw{n}', 'W', n - 1, fw)]
    entries += [
        (f'{s}{k}_in', h, k, next(fcross)) for k in range(n) for s, h in (('n', 'S'), ('s', 'N'))
    ]
    total = sum(e[3] for e in entries)
    routes: list[dict] = []

    def arterial_exit(h: str, k: int) -> str:  # leaving junction k along the arterial
        return f'ae{k + 1}' if h == 'E' else f'aw{k}'

    def walk(edges_so_far: list[str], h: str, k: int, p: float) -> None:
        """A vehicle heading ``h`` arrives at junction k: branch over its moves."""
        if h in 'EW':
            left, right = art[k, h]
            side_l, side_r = ('n', 's') if h == 'E' else ('s', 'n')
            moves = [(f'{side_l}{k}_out', None, left), (f'{side_r}{k}_out', None, right)]
            moves.append((arterial_exit(h, k), h, 1.0 - left - right))
        else:
            left, right = cross[k, h]
            # heading south: left is east, right is west; heading north the other way round
            el, er = ('E', 'W') if h == 'S' else ('W', 'E')
            moves = [(arterial_exit(el, k), el, left), (arterial_exit(er, k), er, right)]
            moves.append((f'{"s" if h == "S" else "n"}{k}_out', None, 1.0 - left - right))
        for edge, heading, q in moves:
            path = [*edges_so_far, edge]
            nxt = None if heading is None else k + (1 if heading == 'E' else -1)
            if nxt is None or not 0 <= nxt < n:
                routes.append({'edges': path, 'probability': p * q})
            else:
                walk(path, heading, nxt, p * q)

    for first, h, k, f in entries:
        walk([first], h, k, f / total)
    return nodes, edges, routes, signals, total, []


def _grid(d: _Drawer) -> tuple[list, list, list, dict, float, list]:
    nx, ny = d('columns'), d('rows')
    v, stub = d('speed'), d('stub', 1)
    gx, gy = d.each('block', nx - 1, 1), d.each('block', ny - 1, 1)
    xs = [stub + sum(gx[:c]) for c in range(nx)]
    ys = [stub + sum(gy[:r]) for r in range(ny)]
    share = d('signal_share', 3)
    signalised = d.rng.random((nx, ny)) < share
    nodes = [
        _node(f'g{c}_{r}', xs[c], ys[r], 'traffic_light' if signalised[c, r] else 'priority')
        for c in range(nx)
        for r in range(ny)
    ]
    edges = []
    for r in range(ny):
        for c in range(nx - 1):
            a, b = f'g{c}_{r}', f'g{c + 1}_{r}'
            edges += [_edge(f'he{c}_{r}', a, b, 1, v, True), _edge(f'hw{c}_{r}', b, a, 1, v, True)]
    for c in range(nx):
        for r in range(ny - 1):
            a, b = f'g{c}_{r}', f'g{c}_{r + 1}'
            edges += [
                _edge(f'vn{c}_{r}', a, b, 1, v, False), _edge(f'vs{c}_{r}', b, a, 1, v, False)
            ]  # fmt: skip
    # boundary stubs: side -> (junction of stub k, outward direction)
    sides = {
        'w': [((0, r), (-1, 0)) for r in range(ny)],
        'e': [((nx - 1, r), (1, 0)) for r in range(ny)],
        's': [((c, 0), (0, -1)) for c in range(nx)],
        'n': [((c, ny - 1), (0, 1)) for c in range(nx)],
    }
    stubs = []
    for side, items in sides.items():
        for k, ((c, r), (dx, dy)) in enumerate(items):
            f, g = f'f{side}{k}', f'g{c}_{r}'
            nodes.append(_node(f, xs[c] + dx * stub, ys[r] + dy * stub))
            edges.append(_edge(f'in_{side}{k}', f, g, 1, v, side in 'we'))
            edges.append(_edge(f'out_{side}{k}', g, f, 1, v, side in 'we'))
            stubs.append((side, k, c, r))
    cycle = d('cycle', 1)
    signals = {n['id']: _signal(d, cycle) for n in nodes if n['type'] == 'traffic_light'}
    n_routes = d('routes')
    routes = []
    for _ in range(n_routes):
        i, j = d.rng.choice(len(stubs), 2, replace=False)
        (s0, k0, c0, r0), (s1, k1, c1, r1) = stubs[i], stubs[j]
        steps = ['x'] * abs(c1 - c0) + ['y'] * abs(r1 - r0)
        path, c, r = [f'in_{s0}{k0}'], c0, r0
        for step in d.rng.permutation(steps) if steps else []:
            if step == 'x':
                dc = 1 if c1 > c else -1
                path.append(f'he{c}_{r}' if dc > 0 else f'hw{c - 1}_{r}')
                c += dc
            else:
                dr = 1 if r1 > r else -1
                path.append(f'vn{c}_{r}' if dr > 0 else f'vs{c}_{r - 1}')
                r += dr
        path.append(f'out_{s1}{k1}')
        routes.append({'edges': path, 'probability': float(d.rng.uniform(0.5, 1.5))})
    total = d('flow', 1)
    return nodes, edges, routes, signals, total, []


_BUILDERS = {'interchange': _interchange, 'arterial': _arterial, 'grid': _grid}


def _stations(d: _Drawer, nodes: list[dict], edges: list[dict]) -> list[dict]:
    """Per covered edge: ``round(length / spacing)`` stations (at least one), evenly spread
    with a jitter, as fractions of the edge (its built length is known after netconvert)."""
    spacing, coverage = d('spacing', 1), d('coverage', 3)
    xy = {n['id']: (n['x'], n['y']) for n in nodes}
    out = []
    for e in edges:
        (x0, y0), (x1, y1) = xy[e['from']], xy[e['to']]
        length = float(np.hypot(x1 - x0, y1 - y0))
        covered = d.rng.random() < coverage
        count = max(1, round(length / spacing))
        jitter = d.rng.uniform(-STATION_JITTER, STATION_JITTER, count)
        if covered:
            fr = [round(float((k + 0.5 + j) / count), 4) for k, j in enumerate(jitter)]
            out.append({'edge': e['id'], 'fractions': fr})
    return out


def draw_network(family: str, seed: int, **overrides) -> NetworkDraw:
    """The network scenario of ``family`` for ``seed``. ``overrides`` fix any scalar of the
    family's ranges (``NETWORK_FAMILIES``), e.g. ``vehicles=100``; one that changes a count
    (intersections, columns) changes the draws that follow it. Raises SumoError."""
    if family not in NETWORK_FAMILIES:
        raise SumoError(
            f'unknown network family {family!r}; choose one of {", ".join(NETWORK_FAMILIES)}'
        )
    bad = sorted(set(overrides) - set(NETWORK_FAMILIES[family]))
    if bad:
        raise SumoError(f'{family}: cannot override {", ".join(bad)}')
    d = _Drawer(family, seed, overrides)
    nodes, edges, routes, signals, flow, lanes = _BUILDERS[family](d)
    total = sum(r['probability'] for r in routes)
    routes = [{**r, 'probability': round(r['probability'] / total, 6)} for r in routes]
    stations = _stations(d, nodes, edges)
    vehicles = d('vehicles')
    mix = str(d.rng.choice(COMMON['mix']))
    shares = [round(float(d.rng.uniform(*COMMON[k])), 3) for k in ('truck_share', 'van_share')]
    sds = [round(float(d.rng.uniform(*COMMON[k])), 3) for k in ('car_speed_sd', 'truck_speed_sd')]
    vtypes = _vtypes(d.rng, mix, shares[0], shares[1] if mix == 'continuous' else 0.0, *sds)
    return NetworkDraw(
        family, int(seed), dict(overrides), d.params, round(flow, 1), vehicles, nodes, edges,
        routes, signals, stations, mix, vtypes, lanes,
    )  # fmt: skip
