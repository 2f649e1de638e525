"""A network draw as SUMO sources, its built network, its signal programs and its layout.

``build_draw`` writes the nodes and edges of a ``NetworkDraw`` as plain XML (under
``<cache>/sources/<family>-<draw key>``, like ``family_sources``), builds them with the
shared netconvert cache, and writes the demand file: the routes as the routeDistribution
``demand`` and, for every signalised junction, a static program retimed to the draw (loaded
after the network, so it replaces netconvert's default program). The phases (which
movements go together) are netconvert's; the draw sets the cycle, the green split between
the main road (edges marked ``main``) and the cross streets, and the offset. ``layout``
reads the built network into the contract's mapping form: SUMO edges become links (in the
order of the draw's edges), SUMO's edge-to-edge connections become connections (internal
junction lanes are not links), the first and last edges of the routes become entries and
exits, and the stations sit at their drawn fractions of their edges.
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from xml.sax.saxutils import quoteattr

from .family_sources import _vtypes as vtypes_xml
from .family_sources import draw_key
from .network import ScenarioFiles, SumoError, build_network, default_cache_dir
from .network_families import PRIORITY, NetworkDraw

_HEAD = '<?xml version="1.0" encoding="UTF-8"?>\n'
#: A station keeps this distance [m] from both ends of its link (at most a quarter of it).
STATION_MARGIN = 15.0
#: Shortest green [s] a retimed phase keeps.
MIN_GREEN = 5.0


@dataclass(frozen=True)
class NetworkRoad:
    """A built network with its loops, in the form ``runner.SumoRun`` drives: ``loops[i]``
    the SUMO lanes of station i (index from the right), ``loop_pos[i]`` the loops' position
    on them [m]; ``mapping`` the layout in the contract's mapping form."""

    scenario: str
    files: ScenarioFiles
    net_file: Path
    mapping: dict
    loops: tuple[tuple[str, ...], ...]
    loop_pos: tuple[float, ...]
    edge_ids: tuple[str, ...]  # SUMO edge of link id k
    #: (from link, to link) -> length of the way through the junction [m] (SUMO's internal
    #: lanes, mean over the lane connections): in no link's length
    junction_lengths: dict

    @property
    def lanes(self) -> list[int]:
        return [len(lanes) for lanes in self.loops]


def _nodes_xml(d: NetworkDraw) -> str:
    lines = [
        f'    <node id="{n["id"]}" x="{n["x"]:.1f}" y="{n["y"]:.1f}" type="{n["type"]}"/>'
        for n in d.nodes
    ]
    return _HEAD + '<nodes>\n' + '\n'.join(lines) + '\n</nodes>\n'


def _edges_xml(d: NetworkDraw) -> str:
    lines = [
        f'    <edge id="{e["id"]}" from="{e["from"]}" to="{e["to"]}" numLanes="{e["lanes"]}" '
        f'speed="{e["speed"]:.2f}" priority="{PRIORITY["main" if e["main"] else "minor"]}"/>'
        for e in d.edges
    ]
    return _HEAD + '<edges>\n' + '\n'.join(lines) + '\n</edges>\n'


def _connections_xml(d: NetworkDraw) -> str:
    lines = [
        f'    <connection from="{c["from"]}" to="{c["to"]}" fromLane="{c["fromLane"]}" '
        f'toLane="{c["toLane"]}"/>'
        for c in d.lane_connections
    ]
    return _HEAD + '<connections>\n' + '\n'.join(lines) + '\n</connections>\n'


def _write_once(path: Path, text: str) -> None:
    """Write ``path`` atomically unless it exists (its content is a function of its name)."""
    if path.is_file():
        return
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.')
    with os.fdopen(fd, 'w') as f:
        f.write(text)
    os.replace(tmp, path)


def write_network_sources(d: NetworkDraw, root: str | Path | None = None) -> ScenarioFiles:
    """Nodes, edges, lane connections (if any) and vehicle types of the draw under
    ``root/sources/<family>-<key>`` (``root`` defaults to the network cache). The demand
    file is written by ``build_draw``, which needs the built network for the signal
    programs."""
    base = Path(root) if root is not None else default_cache_dir()
    entry = base / 'sources' / f'{d.family}-{draw_key(d)}'
    entry.mkdir(parents=True, exist_ok=True)
    files = ScenarioFiles(
        d.family,
        entry / f'{d.family}.nod.xml',
        entry / f'{d.family}.edg.xml',
        entry / f'{d.family}.con.xml' if d.lane_connections else None,
        entry / 'demand.add.xml',  # named after the network by build_draw
        entry / 'vtypes.add.xml',
    )
    _write_once(files.nodes, _nodes_xml(d))
    _write_once(files.edges, _edges_xml(d))
    if files.connections is not None:
        _write_once(files.connections, _connections_xml(d))
    _write_once(files.vtypes, vtypes_xml(d))
    _write_once(entry / 'draw.json', json.dumps(d.to_json(), indent=1))
    return files


def _retimed(tls, d: NetworkDraw, main_edges: set[str]) -> str:
    """The draw's timing of one netconvert program: yellow phases (and any without a major
    green) keep netconvert's duration; the rest of the cycle goes to the green phases of the
    main road (a major green on a ``main`` edge; ``split`` of it) and of the cross streets
    (the rest), shared equally among the phases of each."""
    s = d.signals[tls.getID()]
    program = next(iter(tls.getPrograms().values()))
    phases = program.getPhases()
    in_edge = {}
    for in_lane, _out_lane, index in tls.getConnections():
        in_edge[index] = in_lane.getEdge().getID()

    def role(state: str) -> str:
        if 'y' in state or 'G' not in state:
            return 'fixed'
        greens = {in_edge[i] for i, c in enumerate(state) if c == 'G' and i in in_edge}
        return 'main' if greens & main_edges else 'cross'

    roles = [role(p.state) for p in phases]
    fixed = sum(p.duration for p, r in zip(phases, roles) if r == 'fixed')
    green = max(s['cycle'] - fixed, 2 * MIN_GREEN)
    share = {'main': s['split'], 'cross': 1.0 - s['split']}
    count = {r: roles.count(r) for r in share}
    if not all(count.values()):  # one movement group only: plain green for all of it
        share = {r: 1.0 for r in share}
    lines = [
        f'    <tlLogic id={quoteattr(tls.getID())} type="static" programID="draw" '
        f'offset="{s["offset"]:.1f}">'
    ]
    for p, r in zip(phases, roles):
        dur = p.duration if r == 'fixed' else max(MIN_GREEN, green * share[r] / count[r])
        lines.append(f'        <phase duration="{dur:.1f}" state="{p.state}"/>')
    lines.append('    </tlLogic>')
    return '\n'.join(lines)


def _demand_xml(d: NetworkDraw, net) -> str:
    lines = ['    <routeDistribution id="demand">']
    lines += [
        f'        <route id="r{k}" edges="{" ".join(r["edges"])}" '
        f'probability="{r["probability"]:.6f}"/>'
        for k, r in enumerate(d.routes)
    ]
    lines.append('    </routeDistribution>')
    main = {e['id'] for e in d.edges if e['main']}
    for tls in sorted(net.getTrafficLights(), key=lambda t: t.getID()):
        lines.append(_retimed(tls, d, main))
    return _HEAD + '<additional>\n' + '\n'.join(lines) + '\n</additional>\n'


def _check_routes(d: NetworkDraw, connections: set[tuple[str, str]]) -> None:
    for r in d.routes:
        for a, b in zip(r['edges'], r['edges'][1:]):
            if (a, b) not in connections:
                raise SumoError(f'{d.family} seed {d.seed}: netconvert built no turn {a} -> {b}')


def junction_lengths(d: NetworkDraw, net) -> dict[tuple[int, int], float]:
    """(from link, to link) -> mean length [m] of the internal lanes that join them."""
    ids = {e['id']: k for k, e in enumerate(d.edges)}
    ways: dict[tuple[int, int], list[float]] = {}
    for e in d.edges:
        for to, cons in net.getEdge(e['id']).getOutgoing().items():
            for c in cons:
                via = c.getViaLaneID()
                length = 0.0
                while via:  # an internal lane may continue in a second one
                    lane = net.getLane(via)
                    length += lane.getLength()
                    via = next((o.getViaLaneID() for o in lane.getOutgoing()), '')
                ways.setdefault((ids[e['id']], ids[to.getID()]), []).append(length)
    return {k: round(sum(v) / len(v), 2) for k, v in sorted(ways.items())}


def layout(d: NetworkDraw, net) -> tuple[dict, tuple, tuple]:
    """The mapping form of the contract's network layout, the loop lanes per station and the
    loops' positions on them [m] (module docstring)."""
    ids = {e['id']: k for k, e in enumerate(d.edges)}
    edges = [net.getEdge(e['id']) for e in d.edges]
    links = [
        {'id': k, 'name': e.getID(), 'length_m': round(e.getLength(), 2),
         'lanes': e.getLaneNumber(),
         'shape_m': [[round(x, 2), round(y, 2)] for x, y in e.getShape()]}
        for k, e in enumerate(edges)
    ]  # fmt: skip
    pairs = sorted(
        {(ids[e.getID()], ids[t.getID()]) for e in edges for t in e.getOutgoing() if t != e}
    )
    connections = [{'from': a, 'to': b} for a, b in pairs]
    firsts = sorted({ids[r['edges'][0]] for r in d.routes})
    lasts = sorted({ids[r['edges'][-1]] for r in d.routes})
    stations, loops, loop_pos = [], [], []
    for spec in d.stations:
        e = net.getEdge(spec['edge'])
        length = min(lane.getLength() for lane in e.getLanes())
        margin = min(STATION_MARGIN, length / 4)
        for f in spec['fractions']:
            pos = round(margin + f * (length - 2 * margin), 1)
            sid = len(stations)
            stations.append(
                {'id': sid, 'name': f'loop_{sid:03d}', 'link': ids[spec['edge']],
                 'position_m': pos, 'lanes': e.getLaneNumber()}
            )  # fmt: skip
            loops.append(tuple(lane.getID() for lane in e.getLanes()))
            loop_pos.append(pos)
    mapping = {
        'links': links,
        'connections': connections,
        'entries': [{'link': k} for k in firsts],
        'exits': [{'link': k} for k in lasts],
        'stations': stations,
    }
    return mapping, tuple(loops), tuple(loop_pos)


def build_draw(d: NetworkDraw, cache_dir: str | Path | None = None) -> NetworkRoad:
    """Sources, network (netconvert cache), demand file and layout of a draw. Raises
    SumoError."""
    import sumolib

    files = write_network_sources(d, cache_dir)
    net_file = build_network(files, cache_dir)
    net = sumolib.net.readNet(str(net_file), withPrograms=True, withInternal=True)
    edges = {e['id'] for e in d.edges}
    connections = {
        (e.getID(), t.getID())
        for e in net.getEdges(withInternal=False)
        for t in e.getOutgoing()
        if t != e
    }
    _check_routes(d, connections)
    if {e.getID() for e in net.getEdges(withInternal=False)} != edges:
        raise SumoError(f'{d.family} seed {d.seed}: the built network has other edges')
    # the programs are netconvert's: the demand file goes with the network it was made for
    files = replace(files, routes=files.routes.with_name(f'demand-{net_file.parent.name}.add.xml'))
    _write_once(files.routes, _demand_xml(d, net))
    mapping, loops, loop_pos = layout(d, net)
    return NetworkRoad(
        d.family, files, net_file, mapping, loops, loop_pos, tuple(e['id'] for e in d.edges),
        junction_lengths(d, net),
    )  # fmt: skip
