"""Long inputs on a network: an hour of continuous interchange traffic, in batch and as a stream.

A family cell is one episode (a few hundred vehicles in about ten minutes). Users also hand
the batch association a long log of a network: ``SEEDS`` draws of ``FAMILY`` run as
continuous traffic for ``DURATION`` (``mlkm_sumo.road_networks.network_stream``: the draw's
flow on its routes, measured as the passages come), and ``assignment`` links each in batch
and as a stream (``assignment_stream``, default settings), with time and speed only and with
lane and length. Not in ``--quick`` runs.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from mlkm_core.types import FALSE_ALARM, Detections

from .common import Log, pct
from .network import BEST, STREAM, VARIANT_LABELS, VARIANTS, method_row, variant_of

FAMILY = 'interchange'
SEEDS = (1, 2, 3)
DURATION = 3600.0  # [s]
METHODS = (BEST, STREAM)


def hour_dataset(family: str, seed: int, duration: float, cache_dir: Path | None):
    """(draw, network, detections) of ``duration`` [s] of continuous traffic on the draw
    ``(family, seed)``; a detection's target is its vehicle (``FALSE_ALARM`` for a double
    report or clutter)."""
    from mlkm_core.network import network_from_mapping
    from mlkm_sumo.measurement import PASSAGE
    from mlkm_sumo.road_networks import draw_network, network_stream

    draw = draw_network(family, seed)
    stream = network_stream(draw, duration=duration, cache_dir=cache_dir)
    passages = list(stream)
    ids: dict[str, int] = {}
    # as in the episodes' datasets: a double report or a false alarm targets no vehicle
    target = [ids.setdefault(p.vehicle, len(ids)) if p.kind == PASSAGE else FALSE_ALARM
              for p in passages]  # fmt: skip
    d = Detections(
        np.array([p.station for p in passages], np.int64),
        np.array([p.time for p in passages]),
        np.array([p.speed for p in passages]),
        np.array(target, np.int64),
        np.array([p.lane for p in passages], np.int64),
        np.array([p.length for p in passages]),
    )
    return draw, network_from_mapping(stream.road.mapping, f'{family} seed {seed}, hour'), d


def run_long(log: Log, cache_dir: Path | None = None) -> dict:
    """Both methods on every hour, both variants (module docstring)."""
    runs = []
    for seed in SEEDS:
        t0 = time.monotonic()
        draw, net, d = hour_dataset(FAMILY, seed, DURATION, cache_dir)
        log(
            f'network long: {FAMILY} seed {seed}, {DURATION:g} s, {len(d)} detections '
            f'({time.monotonic() - t0:.0f} s)'
        )
        run: dict = {'seed': seed, 'draw': draw.to_json(), 'detections': len(d), 'rows': {}}
        for variant in VARIANTS:
            for m in METHODS:
                row = method_row(net, variant_of(d, variant), m)
                run['rows'].setdefault(variant, {})[m] = row
                log(
                    f'network long seed {seed} {variant:11s} {m:17s} '
                    f'{100 * row["accuracy"]:7.3f}% ({row["seconds"]:.0f} s)'
                )
        runs.append(run)
    return {'family': FAMILY, 'duration': DURATION, 'methods': list(METHODS), 'runs': runs}


def long_lines(long: dict) -> list[str]:
    """The README section of the long inputs."""
    if not long or not long.get('runs'):
        return []
    L = [
        f'### Long inputs: an hour of {long["family"]} traffic',
        '',
        f'Continuous traffic for {long["duration"]:g} s on each draw '
        '(`bench/network_long.py`), linked in one batch run and as a stream. Accuracy [%].',
        '',
        '| seed | detections | method | ' + ' | '.join(VARIANT_LABELS[v] for v in VARIANTS) + ' |',
        '| --- | --- | --- |' + ' --- |' * len(VARIANTS),
    ]
    for run in long['runs']:
        for m in long['methods']:
            cells = [pct(run['rows'][v][m]['accuracy']) for v in VARIANTS]
            L.append(f'| {run["seed"]} | {run["detections"]} | `{m}` | {" | ".join(cells)} |')
    L.append('')
    return L
