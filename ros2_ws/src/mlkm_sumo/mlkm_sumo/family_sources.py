"""A family draw as SUMO plain-XML sources, and its simulation.

``write_sources`` writes the nodes, edges, lane connections, routes and vehicle types of a
``families.Draw`` into a directory named after a hash of the draw (so that a draw is written
once and its network is built once, by the same netconvert path as the named scenarios);
``generate_family`` runs it through ``api.generate`` with the draw's flow, vehicle count
and stations.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

from .api import SumoDataset, generate
from .families import CLASSES, Draw
from .measurement import MeasurementConfig
from .network import ScenarioFiles, default_cache_dir

_HEAD = '<?xml version="1.0" encoding="UTF-8"?>\n'


def draw_key(d: Draw) -> str:
    """A short hash of everything the draw holds."""
    text = json.dumps(d.to_json(), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def _nodes(d: Draw) -> str:
    xs = [s['start'] for s in d.segments] + [d.road_length]
    lines = [f'    <node id="n{k}" x="{x:.1f}" y="0" type="priority"/>' for k, x in enumerate(xs)]
    for r in d.ramps:  # the far end of a ramp lies 400 m up- or downstream, off the road
        x = r['position'] + (-400.0 if r['kind'] == 'on' else 400.0)
        lines.append(f'    <node id="{r["edge"]}_end" x="{x:.1f}" y="-150" type="priority"/>')
    return _HEAD + '<nodes>\n' + '\n'.join(lines) + '\n</nodes>\n'


def _edges(d: Draw) -> str:
    lines = [
        f'    <edge id="m{k}" from="n{k}" to="n{k + 1}" numLanes="{s["lanes"]}" '
        f'speed="{s["speed"]:.2f}" priority="3"/>'
        for k, s in enumerate(d.segments)
    ]
    for r in d.ramps:
        j = r['mainline'] + (0 if r['kind'] == 'on' else 1)  # the merge / diverge node
        ends = [f'{r["edge"]}_end', f'n{j}']
        if r['kind'] == 'off':
            ends.reverse()
        lines.append(
            f'    <edge id="{r["edge"]}" from="{ends[0]}" to="{ends[1]}" numLanes="1" '
            f'speed="{r["speed"]:.2f}" priority="1"/>'
        )
    return _HEAD + '<edges>\n' + '\n'.join(lines) + '\n</edges>\n'


def _connections(d: Draw) -> str:
    lines = []
    for k, pairs in enumerate(d.links):
        for a, b in pairs:
            lines.append(
                f'    <connection from="m{k}" to="m{k + 1}" fromLane="{a}" toLane="{b}"/>'
            )
    for r in d.ramps:
        j = r['mainline']
        if r['kind'] == 'on':
            lines.append(f'    <connection from="{r["edge"]}" to="m{j}" fromLane="0" toLane="0"/>')
        else:
            lines.append(f'    <connection from="m{j}" to="{r["edge"]}" fromLane="0" toLane="0"/>')
    return _HEAD + '<connections>\n' + '\n'.join(lines) + '\n</connections>\n'


def _routes(d: Draw) -> str:
    lines = [
        f'        <route id="r{k}" edges="{" ".join(r["edges"])}" '
        f'probability="{r["probability"]:.5f}"/>'
        for k, r in enumerate(d.routes)
    ]
    return (
        _HEAD + '<additional>\n    <routeDistribution id="demand">\n' + '\n'.join(lines)
        + '\n    </routeDistribution>\n</additional>\n'
    )  # fmt: skip


def _vtypes(d: Draw) -> str:
    lines = []
    for t in d.vtypes:
        vclass, vmax, accel, decel, gap, tau, mean, (lo, hi) = CLASSES[t['cls']]
        lines.append(
            f'        <vType id="{t["id"]}" probability="{t["share"]:.5f}" vClass="{vclass}" '
            f'length="{t["length"]:.2f}" minGap="{gap}" maxSpeed="{vmax}" accel="{accel}" '
            f'decel="{decel}" sigma="0.5" tau="{tau}" '
            f'speedFactor="normc({mean},{t["speed_sd"]},{lo},{hi})"/>'
        )
    return (
        _HEAD + '<additional>\n    <vTypeDistribution id="mix">\n' + '\n'.join(lines)
        + '\n    </vTypeDistribution>\n</additional>\n'
    )  # fmt: skip


def write_sources(d: Draw, root: str | Path | None = None) -> ScenarioFiles:
    """The draw's sources under ``root/sources/<family>-<key>`` (``root`` defaults to the
    network cache); written once, atomically."""
    base = Path(root) if root is not None else default_cache_dir()
    name = d.family
    entry = base / 'sources' / f'{name}-{draw_key(d)}'
    files = ScenarioFiles(
        name,
        entry / f'{name}.nod.xml',
        entry / f'{name}.edg.xml',
        entry / f'{name}.con.xml',
        entry / f'{name}.rou.xml',
        entry / 'vtypes.add.xml',
    )
    if not entry.is_dir():
        entry.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(dir=entry.parent, prefix=f'.{name}-'))
        texts = (_nodes(d), _edges(d), _connections(d), _routes(d), _vtypes(d))
        for path, text in zip(files.sources() + [files.routes, files.vtypes], texts, strict=True):
            (tmp / path.name).write_text(text)
        (tmp / 'draw.json').write_text(json.dumps(d.to_json(), indent=1))
        try:
            os.replace(tmp, entry)
        except OSError:  # a concurrent writer won; its files are the same
            for p in tmp.iterdir():
                p.unlink()
            tmp.rmdir()
    return files


def generate_family(
    d: Draw,
    cache_dir: str | Path | None = None,
    measurement: MeasurementConfig | None = None,
    step_length: float = 0.2,
) -> SumoDataset:
    """Simulate the draw: ``d.vehicles`` vehicles at ``d.flow`` vehicles/h, loops at
    ``d.stations``, SUMO seeded with ``d.seed``. Raises SumoError."""
    files = write_sources(d, cache_dir)
    return generate(
        d.family,
        n_vehicles=d.vehicles,
        seed=d.seed,
        stations_at=d.stations,
        measurement=measurement,
        cache_dir=cache_dir,
        step_length=step_length,
        flow=d.flow,
        files=files,
    )
