"""Scenario families: roads, demand, vehicle mixes and stations drawn per seed from ranges.

A family is a small table of ranges (``FAMILIES``, over the shared ``COMMON`` one); ``draw``
turns (family, seed) into one ``Draw``: lane count, road length, speed limit, the mainline
segments (a one-lane work zone, a lane drop or on/off-ramps with their acceleration and
deceleration lanes at drawn positions), the routes, the demand, the vehicle types and the
station positions. It is a pure function of (family, seed) and of the curve overrides
(``spacing``, ``severity``): the same arguments give the same draw, and ``Draw.to_json()``
records everything needed to rebuild the road and the traffic. ``family_sources`` writes a
draw as SUMO plain-XML sources, ``generate_family`` simulates it.

Severity is demand over the capacity of the bottleneck, estimated as its lane count times
``CAPACITY_PER_LANE``: 2,000 vehicles/h per lane, the top of the 1,800-2,000 usually quoted
for a freeway lane, because SUMO's one-lane work zones at 60-80 km/h with these vehicle
mixes discharge 2,000-2,150 vehicles/h once a queue stands upstream (measured at the
downstream stations at severity 1.5, seeds 1-3); counted in vehicles, whatever the share
of trucks. The bottleneck is the
one-lane work zone, the lanes left after a lane drop, or the plain mainline (free flow,
ramps: the most loaded mainline section, through traffic plus what the on-ramps add).
"""

from __future__ import annotations

import math
import zlib
from dataclasses import asdict, dataclass, field

import numpy as np

from .network import SumoError

#: Capacity [vehicles/h] of one lane at the bottleneck (the severity's denominator).
CAPACITY_PER_LANE = 2000.0

#: Ranges shared by every family (a family's own table overrides them). Lengths [m], speeds
#: [m/s], shares and jitter as fractions; (low, high) is uniform, integers inclusive.
COMMON: dict = {
    'road_length': (3000.0, 6000.0),
    'speed_limit': (27.78, 36.11),  # 100-130 km/h
    'vehicles': (60, 120),
    'spacing': (300.0, 1000.0),  # station spacing
    'jitter': (0.0, 0.2),  # uniform +- this share of the spacing per station
    'mix': ('continuous', 'two_type'),  # drawn with equal odds
    'truck_share': (0.05, 0.25),
    'van_share': (0.03, 0.12),  # continuous mix only
    'car_speed_sd': (0.05, 0.15),  # std of the cars' desired-speed factor
    'truck_speed_sd': (0.02, 0.06),
}


@dataclass(frozen=True)
class Family:
    name: str
    description: str
    ranges: dict

    def range(self, key: str):
        return self.ranges.get(key, COMMON.get(key))


FAMILIES: dict[str, Family] = {
    f.name: f
    for f in (
        Family(
            'free_flow',
            '2-4 lanes, 3-6 km, no bottleneck, demand 20-60 % of capacity',
            {'lanes': (2, 4), 'severity': (0.2, 0.6)},
        ),
        Family(
            'ramps',
            '2-4 lanes, 2-4 on/off-ramps (at least one of each) 600-1,400 m apart with '
            '200-300 m acceleration / deceleration lanes, 15-40 % of the vehicles on ramps, '
            'demand 30-90 % of the mainline capacity',
            {
                'lanes': (2, 4),
                'severity': (0.3, 0.9),
                'ramps': (2, 4),
                'ramp_spacing': (600.0, 1400.0),
                'aux_length': (200.0, 300.0),
                'ramp_share': (0.15, 0.4),
                'ramp_speed': (19.44, 22.22),  # 70-80 km/h
            },
        ),
        Family(
            'work_zone',
            '2-4 lanes into a one-lane work zone of 300-900 m (starting at 35-65 % of the '
            'road, 60-80 km/h): demand 0.8-1.5 x the capacity of one lane, a queue upstream; '
            '100-150 vehicles',
            {
                'lanes': (2, 4),
                'severity': (0.8, 1.5),
                'zone_length': (300.0, 900.0),
                'zone_start': (0.35, 0.65),  # share of the road length
                'zone_speed': (16.67, 22.22),
                'vehicles': (100, 150),  # enough of them for a queue to stand
            },
        ),
        Family(
            'lane_drop',
            '2-4 lanes, the left lane ends at 40-70 % of the road: demand 0.5-1.2 x the '
            'capacity of the lanes left; 100-150 vehicles',
            {
                'lanes': (2, 4),
                'severity': (0.5, 1.2),
                'drop_at': (0.4, 0.7),
                'vehicles': (100, 150),
            },
        ),
    )
}
#: Parameters a curve may fix instead of drawing them.
OVERRIDES = ('spacing', 'severity')
#: A station keeps this distance [m] from the road ends and from every node of the mainline
#: (netconvert's junctions at ramps reach up to about 70 m along the road).
END_MARGIN = 100.0
NODE_MARGIN = 80.0
#: Vehicle types drawn for the continuous length spread, per class.
TYPES_PER_CLASS = {'car': 20, 'van': 4, 'truck': 8}
#: Class parameters of the vehicle types: SUMO vClass, maxSpeed [m/s], accel, decel [m/s^2],
#: minGap [m], tau [s], desired-speed factor mean and its clip range.
CLASSES = {
    'car': ('passenger', 55.0, 2.6, 4.5, 2.5, 1.0, 1.0, (0.7, 1.35)),
    'van': ('delivery', 44.0, 2.0, 4.0, 2.5, 1.1, 0.95, (0.7, 1.2)),
    'truck': ('truck', 25.0, 1.0, 4.0, 3.0, 1.2, 1.0, (0.85, 1.15)),
}
#: Lengths [m]: cars lognormal (mean, std, clip), vans and trucks uniform; the two-type mix.
CAR_LENGTH = (4.5, 0.4, (3.4, 6.0))
VAN_LENGTH = (5.5, 7.5)
TRUCK_LENGTH = (10.0, 18.0)
TWO_TYPE = {'car': 4.8, 'truck': 16.5}


@dataclass
class Draw:
    """One drawn scenario. Positions [m] along the road, speeds [m/s], flow [vehicles/h].

    ``segments``: mainline edges ``m<k>`` in driving order, ``{start, end, lanes, speed}``;
    ``links``: per boundary between m<k> and m<k+1> the lane connections ``[from, to]``;
    ``ramps``: ``{kind ('on'/'off'), edge, position, speed, mainline (index of the segment it
    joins, the acceleration lane, or leaves, the deceleration lane)}``; ``routes``:
    ``{edges, probability}``; ``vtypes``: ``{id, cls, length, share, speed_sd}``."""

    family: str
    seed: int
    overrides: dict
    lanes: int
    road_length: float
    speed_limit: float
    severity: float
    capacity: float  # of the bottleneck [vehicles/h]
    flow: float
    vehicles: int
    mix: str
    spacing: float
    jitter: float
    stations: list[float]
    segments: list[dict] = field(default_factory=list)
    links: list[list[list[int]]] = field(default_factory=list)
    ramps: list[dict] = field(default_factory=list)
    routes: list[dict] = field(default_factory=list)
    vtypes: list[dict] = field(default_factory=list)
    bottleneck: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return asdict(self)

    @property
    def entries(self) -> tuple[float, ...]:
        return tuple(r['position'] for r in self.ramps if r['kind'] == 'on')

    @property
    def exits(self) -> tuple[float, ...]:
        return tuple(r['position'] for r in self.ramps if r['kind'] == 'off')


def family(name: str) -> Family:
    try:
        return FAMILIES[name]
    except KeyError:
        raise SumoError(f'unknown family {name!r}; choose one of {", ".join(FAMILIES)}') from None


def _rng(name: str, seed: int) -> np.random.Generator:
    return np.random.default_rng([zlib.crc32(name.encode()), int(seed)])


def _u(rng: np.random.Generator, lo_hi, digits: int = 2) -> float:
    return round(float(rng.uniform(*lo_hi)), digits)


def _same(n: int) -> list[list[int]]:
    return [[i, i] for i in range(n)]


def _mainline(f: Family, rng, lanes: int, length: float, speed: float):
    """Segments, lane links, ramps and bottleneck of the family's road."""
    seg = lambda a, b, n, v=speed: {'start': a, 'end': b, 'lanes': n, 'speed': v}  # noqa: E731
    if f.range('zone_length'):
        z0 = round(length * _u(rng, f.range('zone_start')), 1)
        z1 = round(min(z0 + _u(rng, f.range('zone_length'), 1), length - 500.0), 1)
        zs = _u(rng, f.range('zone_speed'))
        segs = [seg(0.0, z0, lanes), seg(z0, z1, 1, zs), seg(z1, length, lanes)]
        links = [[[0, 0]], [[0, j] for j in range(lanes)]]
        return segs, links, [], {'kind': 'work_zone', 'start': z0, 'end': z1, 'lanes': 1}
    if f.range('drop_at'):
        x = round(length * _u(rng, f.range('drop_at')), 1)
        segs = [seg(0.0, x, lanes), seg(x, length, lanes - 1)]
        return segs, [_same(lanes - 1)], [], {'kind': 'lane_drop', 'start': x, 'lanes': lanes - 1}
    if not f.range('ramps'):
        return [seg(0.0, length, lanes)], [], [], {'kind': 'none', 'lanes': lanes}
    lo, hi = f.range('ramps')
    spacing = _u(rng, f.range('ramp_spacing'), 1)
    count = min(int(rng.integers(lo, hi + 1)), int((length - 1200.0) // spacing) + 1)
    kinds = [str(k) for k in rng.choice(['on', 'off'], count)]
    if len(set(kinds)) == 1:
        kinds[-1] = 'off' if kinds[0] == 'on' else 'on'
    first = _u(rng, (600.0, length - 600.0 - (count - 1) * spacing), 1)
    aux = _u(rng, f.range('aux_length'), 1)
    ramp_speed = _u(rng, f.range('ramp_speed'))
    segs, links, ramps, x = [], [], [], 0.0
    for k, kind in enumerate(kinds):
        at = round(first + k * spacing, 1)
        a, b = (at, at + aux) if kind == 'on' else (at - aux, at)
        segs += [seg(x, a, lanes), seg(a, b, lanes + 1)]
        # on: the ramp feeds lane 0, the acceleration lane, which then ends; off: a
        # deceleration lane opens as lane 0 and leads onto the off-ramp
        shift_up = [[i, i + 1] for i in range(lanes)]
        links += [shift_up if kind == 'on' else [[0, 0], *shift_up]]
        links += [[[i + 1, i] for i in range(lanes)]]
        ramps.append(
            {'kind': kind, 'edge': f'{kind}_{k + 1}', 'position': at, 'speed': ramp_speed,
             'mainline': len(segs) - 1}
        )  # fmt: skip
        x = b
    segs.append(seg(x, length, lanes))
    return segs, links, ramps, {'kind': 'none', 'lanes': lanes, 'ramp_share': None}


def _routes(f: Family, rng, segs: list[dict], ramps: list[dict], bottleneck: dict) -> list:
    """Every (entry, exit) pair with its probability: start or an on-ramp in, end or a later
    off-ramp out; the ramps together carry ``ramp_share`` of the entries and of the exits."""
    last = len(segs) - 1
    if not ramps:
        return [{'edges': [f'm{k}' for k in range(len(segs))], 'probability': 1.0}]
    share = _u(rng, f.range('ramp_share'), 3)
    bottleneck['ramp_share'] = share
    ons = [r for r in ramps if r['kind'] == 'on']
    offs = [r for r in ramps if r['kind'] == 'off']
    entries = [(None, 0, 1.0 - share)] + [(r, r['mainline'], share / len(ons)) for r in ons]
    routes = []
    for on, j0, p_in in entries:
        outs = [(None, last, 1.0 - share)]
        outs += [(r, r['mainline'], share / len(offs)) for r in offs if r['mainline'] >= j0]
        total = sum(p for *_, p in outs)
        for off, j1, p_out in outs:
            edges = ([on['edge']] if on else []) + [f'm{k}' for k in range(j0, j1 + 1)]
            edges += [off['edge']] if off else []
            routes.append({'edges': edges, 'probability': round(p_in * p_out / total, 5)})
    return routes


def _vtypes(rng, mix: str, truck_share: float, van_share: float, sd_car: float, sd_truck: float):
    out = []
    if mix == 'two_type':
        for cls, share in (('car', 1.0 - truck_share), ('truck', truck_share)):
            sd = sd_truck if cls == 'truck' else sd_car
            out.append({'id': cls, 'cls': cls, 'length': TWO_TYPE[cls], 'share': share,
                        'speed_sd': sd})  # fmt: skip
        return out
    mean, sd, clip = CAR_LENGTH
    s2 = math.log(1.0 + (sd / mean) ** 2)
    shares = {'car': 1.0 - truck_share - van_share, 'van': van_share, 'truck': truck_share}
    for cls, n in TYPES_PER_CLASS.items():
        if cls == 'car':
            lengths = np.clip(rng.lognormal(math.log(mean) - s2 / 2, math.sqrt(s2), n), *clip)
        else:
            lengths = rng.uniform(*(VAN_LENGTH if cls == 'van' else TRUCK_LENGTH), n)
        for k, length in enumerate(lengths):
            out.append({'id': f'{cls}_{k}', 'cls': cls, 'length': round(float(length), 2),
                        'share': round(shares[cls] / n, 5),
                        'speed_sd': sd_truck if cls == 'truck' else sd_car})  # fmt: skip
    return out


def _off_nodes(x: float, nodes: list[float], length: float) -> float | None:
    """``x``, or the nearest position NODE_MARGIN away from every node (None if none is
    within one margin)."""

    def free(y: float) -> bool:
        ok = END_MARGIN <= y <= length - END_MARGIN
        return ok and all(abs(y - n) >= NODE_MARGIN for n in nodes)

    if free(x):
        return x
    options = [n + s * NODE_MARGIN for n in nodes for s in (-1, 1) if abs(x - n) < NODE_MARGIN]
    options = sorted((abs(y - x), y) for y in options if free(y))
    return options[0][1] if options else None


def _stations(rng, length: float, spacing: float, jitter: float, segs: list[dict]) -> list:
    """Every ``spacing`` m from a random start, each moved by up to ``jitter`` x spacing, off
    the road ends and the nodes."""
    nodes = sorted({s['start'] for s in segs} | {length})
    x0 = END_MARGIN + float(rng.uniform(0.0, 0.5)) * spacing
    out: list[float] = []
    k = 0
    while (nominal := x0 + k * spacing) <= length - END_MARGIN:
        x = nominal + float(rng.uniform(-jitter, jitter)) * spacing
        x = min(max(x, END_MARGIN), length - END_MARGIN)
        x = _off_nodes(x, nodes, length)
        if x is not None and (not out or x > out[-1] + 1.0):
            out.append(round(x, 1))
        k += 1
    if len(out) < 2:
        raise SumoError(f'{spacing:g} m spacing leaves fewer than 2 stations on {length:g} m')
    return out


def draw(name: str, seed: int, **overrides: float) -> Draw:
    """The scenario of family ``name`` for ``seed``; ``overrides`` (``OVERRIDES``) fix the
    station spacing [m] or the severity instead of drawing them. Raises SumoError."""
    f = family(name)
    bad = sorted(set(overrides) - set(OVERRIDES))
    if bad:
        raise SumoError(f'cannot override {", ".join(bad)}; only {", ".join(OVERRIDES)}')
    rng = _rng(name, seed)
    lo, hi = f.range('lanes')
    lanes = int(rng.integers(lo, hi + 1))
    length = round(_u(rng, f.range('road_length'), 0), 1)
    speed = _u(rng, f.range('speed_limit'))
    severity = _u(rng, f.range('severity'), 3)
    lo, hi = f.range('vehicles')
    vehicles = int(rng.integers(lo, hi + 1))
    mix = str(rng.choice(f.range('mix')))
    shares = [_u(rng, f.range(k), 3) for k in ('truck_share', 'van_share')]
    sds = [_u(rng, f.range(k), 3) for k in ('car_speed_sd', 'truck_speed_sd')]
    vtypes = _vtypes(rng, mix, shares[0], shares[1] if mix == 'continuous' else 0.0, *sds)
    spacing = _u(rng, f.range('spacing'), 1)
    jitter = _u(rng, f.range('jitter'), 3)
    segs, links, ramps, bottleneck = _mainline(f, rng, lanes, length, speed)
    routes = _routes(f, rng, segs, ramps, bottleneck)
    # the curve overrides replace drawn values after every draw, so that the rest of the
    # scenario stays that of (family, seed)
    severity = round(float(overrides.get('severity', severity)), 3)
    spacing = round(float(overrides.get('spacing', spacing)), 1)
    stations = _stations(rng, length, spacing, jitter, segs)
    capacity = bottleneck['lanes'] * CAPACITY_PER_LANE
    # share of the demand on the most loaded plain mainline section (1 without ramps)
    load = max(
        sum(r['probability'] for r in routes if f'm{k}' in r['edges'])
        for k, s in enumerate(segs)
        if s['lanes'] == lanes or not ramps
    )
    flow = round(severity * capacity / load, 1)
    return Draw(
        name, int(seed), dict(overrides), lanes, length, speed, severity, capacity, flow,
        vehicles, mix, spacing, jitter, stations, segs, links, ramps, routes, vtypes, bottleneck,
    )  # fmt: skip
