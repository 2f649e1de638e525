"""The scenarios, their road geometry, and sensor stations placed on them.

Every scenario is a straight road along the x axis: the x coordinate is the position along
the road [m]. The mainline edges are named ``m<k>`` in driving order; ramps ``on_<k>`` and
``off_<k>`` join or leave it. A sensor station is one position with one loop detector per
lane there (the lane count can change along the road: lane drops, acceleration lanes).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from mlkm_core.types import Layout

from .network import ScenarioFiles, SumoError, build_network, scenario_files


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    flow: float  # demand [vehicles/h] inserted at the upstream end and on the on-ramps


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario(
            'single_lane',
            'one 5 km lane at 100 km/h, no overtaking: the order of vehicles never changes '
            '(sanity case), 900 vehicles/h',
            900.0,
        ),
        Scenario(
            'highway',
            '5 km, 3 lanes at 120 km/h, free flow at 3,000 vehicles/h, lane changing on; cars '
            '(4.0-5.1 m), vans (6.5 m) and trucks (12-16.5 m, 90 km/h) with spread desired speeds',
            3000.0,
        ),
        Scenario(
            'long_highway',
            'the highway over 20 km (about 11 minutes from end to end), 3,000 vehicles/h: '
            'the long road that association shards split',
            3000.0,
        ),
        Scenario(
            'congested',
            'the highway at 2,400 vehicles/h into road works (from 3.5 km one lane at 60 km/h '
            'for 500 m, about 2,000 vehicles/h): a queue with stop-and-go waves grows upstream',
            2400.0,
        ),
        Scenario(
            'ramps',
            'the highway with two on-ramps (1.2 km, 3.2 km) and two off-ramps (2.3 km, 4.3 km): '
            'about 30 % of the vehicles enter or leave between stations, 3,000 vehicles/h',
            3000.0,
        ),
    )
}

#: Stations keep this distance [m] from both road ends (insertion and arrival zones).
END_MARGIN = 100.0
#: A loop keeps this distance [m] from the ends of its lane (no loop inside a junction).
LANE_MARGIN = 1.0
#: Smallest distance [m] between two randomly placed stations.
MIN_SPACING = 10.0


def scenario(name: str) -> Scenario:
    try:
        return SCENARIOS[name]
    except KeyError:
        raise SumoError(
            f'unknown scenario {name!r}; choose one of {", ".join(SCENARIOS)}'
        ) from None


@dataclass(frozen=True)
class Ramp:
    kind: str  # 'on' (vehicles enter) or 'off' (vehicles leave)
    edge: str
    position: float  # where it joins/leaves the mainline [m]


@dataclass(frozen=True)
class _Segment:
    edge: str
    start: float  # x of its lanes' start [m]
    end: float
    lanes: int


@dataclass(frozen=True)
class Geometry:
    """The mainline of a built network: lane segments along x, and the ramps."""

    road_length: float
    segments: tuple[_Segment, ...]
    ramps: tuple[Ramp, ...]

    def segment_at(self, x: float) -> _Segment | None:
        for s in self.segments:
            if s.start + LANE_MARGIN <= x <= s.end - LANE_MARGIN:
                return s
        return None


def read_geometry(net_file: Path) -> Geometry:
    import sumolib

    net = sumolib.net.readNet(str(net_file))
    main = sorted(
        (e for e in net.getEdges() if re.fullmatch(r'm\d+', e.getID())),
        key=lambda e: int(e.getID()[1:]),
    )
    if not main:
        raise SumoError(f'{net_file}: no mainline edges (m0, m1, ...)')
    segments = []
    for e in main:
        xs = [p[0] for p in e.getLanes()[0].getShape()]
        segments.append(_Segment(e.getID(), min(xs), max(xs), e.getLaneNumber()))
    ramps = []
    for e in net.getEdges():
        m = re.fullmatch(r'(on|off)_\d+', e.getID())
        if m:
            node = e.getToNode() if m.group(1) == 'on' else e.getFromNode()
            ramps.append(Ramp(m.group(1), e.getID(), float(node.getCoord()[0])))
    road_length = float(main[-1].getToNode().getCoord()[0])
    return Geometry(road_length, tuple(segments), tuple(sorted(ramps, key=lambda r: r.position)))


@dataclass(frozen=True)
class Road:
    """Stations on a scenario's road: the product's Layout plus what loop detectors add.

    ``lanes[i]`` is the number of lanes (one loop each) at station i, ``loops[i][l]`` the
    SUMO lane of lane l (index from the right). ``enter_between[i]`` / ``leave_between[i]``
    say whether vehicles can enter / leave the road between station i and i+1 (a ramp there);
    ``enter_before_first`` / ``leave_after_last`` likewise outside the stations. ``files``
    are the sources of a road built outside the named scenarios (``families``), else None.
    """

    scenario: str
    layout: Layout
    lanes: np.ndarray
    loops: tuple[tuple[str, ...], ...]
    loop_pos: np.ndarray  # position of the loops on their lanes [m], per station
    ramps: tuple[Ramp, ...]
    enter_between: np.ndarray
    leave_between: np.ndarray
    net_file: Path
    files: ScenarioFiles | None = None

    @property
    def open_between(self) -> np.ndarray:
        """Vehicles can enter or leave between station i and i+1."""
        return self.enter_between | self.leave_between

    @property
    def n_stations(self) -> int:
        return self.layout.n_sensors


def random_positions(geometry: Geometry, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` sorted station positions, uniform on the road, off junctions, MIN_SPACING apart."""
    lo, hi = END_MARGIN, geometry.road_length - END_MARGIN
    if n < 1 or (n - 1) * MIN_SPACING > (hi - lo) * 0.5:
        raise SumoError(
            f'cannot place {n} stations at least {MIN_SPACING:g} m apart on {hi - lo:g} m of road'
        )
    chosen: list[float] = []
    for _ in range(1000 * n):
        x = float(rng.uniform(lo, hi))
        if geometry.segment_at(x) and all(abs(x - c) >= MIN_SPACING for c in chosen):
            chosen.append(round(x, 1))
            if len(chosen) == n:
                return np.sort(np.array(chosen))
    raise SumoError(f'could not place {n} stations on the road')  # pragma: no cover


def make_road(
    name: str,
    n_stations: int = 20,
    rng: np.random.Generator | None = None,
    stations_at: list[float] | np.ndarray | None = None,
    cache_dir: str | Path | None = None,
    files: ScenarioFiles | None = None,
) -> Road:
    """Build (or reuse) the scenario's network and place the stations on it. ``files``
    replaces the named scenario's sources (a road of ``families``; ``name`` is then a label)."""
    own = files
    if files is None:
        scenario(name)
        files = scenario_files(name)
    net = build_network(files, cache_dir)
    geo = read_geometry(net)
    if stations_at is not None:
        pos = np.asarray(stations_at, dtype=float).ravel()
        if pos.size == 0:
            raise SumoError('stations_at is empty')
        if np.any(np.diff(pos) <= 0):
            raise SumoError('station positions must be strictly increasing')
        lo, hi = END_MARGIN, geo.road_length - END_MARGIN
        for x in pos:
            if not lo <= x <= hi:
                raise SumoError(
                    f'station at {x:g} m is outside the usable road [{lo:g}, {hi:g}] m of '
                    f'scenario {name!r}'
                )
            if geo.segment_at(x) is None:
                raise SumoError(
                    f'station at {x:g} m lies in a junction of scenario {name!r}; move it '
                    'a few metres'
                )
    else:
        pos = random_positions(geo, n_stations, rng or np.random.default_rng())
    segs = [geo.segment_at(float(x)) for x in pos]
    lanes = np.array([s.lanes for s in segs], np.int64)
    loops = tuple(tuple(f'{s.edge}_{lane}' for lane in range(s.lanes)) for s in segs)
    loop_pos = np.array([x - s.start for x, s in zip(pos, segs)])
    enter = np.zeros(max(pos.size - 1, 0), bool)
    leave = np.zeros_like(enter)
    for r in geo.ramps:
        i = int(np.searchsorted(pos, r.position)) - 1  # stations i, i+1 enclose the ramp
        if 0 <= i < pos.size - 1:
            (enter if r.kind == 'on' else leave)[i] = True
    layout = Layout(
        geo.road_length, pos, names=tuple(f'{name}_station_{i}' for i in range(pos.size))
    )
    return Road(name, layout, lanes, loops, loop_pos, geo.ramps, enter, leave, net, own)


def enters_before_first(road: Road) -> bool:
    return any(r.kind == 'on' and r.position < road.layout.positions[0] for r in road.ramps)


def leaves_after_last(road: Road) -> bool:
    return any(r.kind == 'off' and r.position > road.layout.positions[-1] for r in road.ramps)


def loop_id(station: int, lane: int) -> str:
    return f's{station}_l{lane}'


def write_detectors(road: Road, path: Path, instant_output: Path | None = None) -> None:
    """The additional file with one loop per lane at every station.

    The loops read in process are SUMO ``inductionLoop``s; with ``instant_output`` every
    position also gets an ``instantInductionLoop`` writing SUMO's own passage records to that
    file (for auditing the in-process reading against them).
    """
    lines = ['<additional>']
    for i, lane_ids in enumerate(road.loops):
        for lane, lane_id in enumerate(lane_ids):
            common = f'lane={quoteattr(lane_id)} pos="{road.loop_pos[i]:.3f}"'
            lines.append(
                f'    <inductionLoop id="{loop_id(i, lane)}" {common} period="86400" file="NUL"/>'
            )
            if instant_output is not None:
                lines.append(
                    f'    <instantInductionLoop id="i{loop_id(i, lane)}" {common} '
                    f'file={quoteattr(str(instant_output))}/>'
                )
    lines.append('</additional>')
    path.write_text('\n'.join(lines) + '\n')
