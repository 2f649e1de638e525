"""SUMO scenario families: traffic drawn per seed from ranges, not tuned by hand.

Each family cell runs the methods on the datasets of seeds 1..N of one family
(``mlkm_sumo.families.draw(family, seed)``: road, bottleneck, demand, vehicle mix and station
placement all drawn); each curve point fixes one parameter of a family's draws (the station
spacing or the severity) and runs seeds 1..M. Every dataset's draw is written into the JSON,
so any cell can be rebuilt from (family, seed, overrides). The methods see each dataset with
(time, speed) only and with lane and length, told the drawn road's ramps; the Stone Soup peer
runs on the time-and-speed variant of the family cells' first datasets.
"""

from __future__ import annotations

import time
from pathlib import Path

from mlkm_core.associators import AssociatorConfig, make_associator
from mlkm_core.types import Dataset

from .common import PEER, Log, run_budgeted, summarise, timed_row
from .sumo_data import DatasetCache, load

#: the family cells, in report order
FAMILY_CELLS = ('free_flow', 'ramps', 'work_zone', 'lane_drop')
#: (name, family, parameter, values): accuracy against the station spacing [m] and the
#: congestion severity (demand / capacity of the bottleneck)
CURVES = (
    ('spacing', 'free_flow', 'spacing', (100.0, 200.0, 300.0, 500.0, 1000.0)),
    ('spacing', 'work_zone', 'spacing', (100.0, 200.0, 300.0, 500.0, 1000.0)),
    ('severity', 'work_zone', 'severity', (0.6, 0.9, 1.1, 1.3, 1.5)),
)
#: seeds per family cell, per curve point, and the peer's datasets per family cell
PLANS = {
    'full': {'seeds': 5, 'curve_seeds': 3, 'peer_seeds': 5},
    'quick': {'seeds': 2, 'curve_seeds': 1, 'peer_seeds': 1},
}
#: methods on the curve points (every method runs on the family cells)
CURVE_METHODS = ('assignment', 'multiframe', 'mlkm_robust', 'mlkm')
#: time budget [s] of one (method, cell, variant), and the peer's of one family cell
BUDGET = 300.0
PEER_BUDGET = 1500.0
VARIANTS = ('time_speed', 'lane_length')


def plan(quick: bool) -> dict:
    """The family plan of a full or a quick (``--quick``) run."""
    return dict(PLANS['quick' if quick else 'full'])


def _job(method: str, paths: list[Path], configs: list[AssociatorConfig], variant: str):
    """Job factory for ``run_budgeted``: dataset k with the ramps of its own road."""

    def make_job():
        if method == PEER:
            from .peer import config_for, stonesoup_associate

            def assoc(k: int, d: Dataset):  # no measurement noise (default measurement)
                return stonesoup_associate(
                    d.layout, d.detections, 0.0, 0.0, config_for(d.layout, d.detections)
                )
        else:

            def assoc(k: int, d: Dataset):
                a = make_associator(method, configs[k])
                return a.associate(d.layout, d.detections, d.n_targets)

        return lambda k: timed_row(load(paths[k], variant), lambda d: assoc(k, d))

    return make_job


def run_cell(
    family: str,
    seeds: list[int],
    overrides: dict,
    methods: list[str],
    cache: DatasetCache,
    log: Log,
    peer_n: int = 0,
    label: str = '',
) -> dict:
    """Every method on the draws of ``seeds`` (with ``overrides``), both variants; the peer
    on the first ``peer_n`` of them (time and speed)."""
    from mlkm_sumo.families import draw

    label = label or family
    entry: dict = {'family': family, 'overrides': overrides, 'seeds': seeds, 'variants': {}}
    t0 = time.monotonic()
    try:
        draws = [draw(family, s, **overrides) for s in seeds]
        paths = [cache.family(d) for d in draws]
    except Exception as exc:  # SumoError, a failing netconvert: the cell is reported as such
        entry['error'] = f'{type(exc).__name__}: {exc}'
        log(f'sumo family {label}: datasets failed: {entry["error"]}')
        return entry
    entry['draws'] = [d.to_json() for d in draws]
    configs = [AssociatorConfig(entries=d.entries, exits=d.exits) for d in draws]
    sets = [load(p, 'lane_length') for p in paths]
    entry['detections_mean'] = sum(len(d.detections) for d in sets) / len(sets)
    entry['vehicles_mean'] = sum(d.n_targets for d in sets) / len(sets)
    entry['stations_mean'] = sum(d.layout.n_sensors for d in sets) / len(sets)
    log(
        f'sumo family {label}: {len(seeds)} datasets, {entry["detections_mean"]:.0f} '
        f'detections, {entry["stations_mean"]:.1f} stations each ({time.monotonic() - t0:.1f} s)'
    )
    for variant in VARIANTS:
        entry['variants'][variant] = {}
        for m in [*methods, *([PEER] if peer_n and variant == 'time_speed' else [])]:
            t1 = time.monotonic()
            count, budget = len(seeds), BUDGET
            if m == PEER:
                count, budget = min(peer_n, len(seeds)), PEER_BUDGET
            rows, status = run_budgeted(_job(m, paths, configs, variant), count, budget)
            rec = {'summary': summarise(rows), 'status': status, 'runs': rows, 'datasets': count}
            entry['variants'][variant][m] = rec
            s = rec['summary']
            log(
                f'sumo family {label:24s} {variant:11s} {m:12s} '
                f'{s.get("accuracy_mean", float("nan")) * 100:7.3f}% n={s["n"]} {status} '
                f'({time.monotonic() - t1:.1f} s)'
            )
    return entry


def run_families(methods: list[str], plan: dict, log: Log, cache: DatasetCache) -> dict:
    """The family cells and the curves of ``plan`` (``plan(quick)``)."""
    from mlkm_sumo.families import CAPACITY_PER_LANE, COMMON, FAMILIES

    from .peer import stonesoup_version

    t0 = time.monotonic()
    seeds = list(range(1, plan['seeds'] + 1))
    curve_seeds = list(range(1, plan['curve_seeds'] + 1))
    peer_n = plan['peer_seeds'] if stonesoup_version() is not None else 0
    curve_methods = [m for m in methods if m in CURVE_METHODS]
    out: dict = {
        'plan': plan,
        'families': {
            n: {'description': f.description, 'ranges': {**COMMON, **f.ranges}}
            for n, f in FAMILIES.items()
        },
        'capacity_per_lane': CAPACITY_PER_LANE,
        'budget_s': BUDGET,
        'peer_budget_s': PEER_BUDGET,
        'curve_methods': curve_methods,
        'cells': [run_cell(f, seeds, {}, methods, cache, log, peer_n) for f in FAMILY_CELLS],
        'curves': [],
    }
    for name, family, param, values in CURVES:
        points = []
        for x in values:
            label = f'{family} {param}={x:g}'
            cell = run_cell(family, curve_seeds, {param: x}, curve_methods, cache, log, 0, label)
            points.append({'x': x, **cell})
        out['curves'].append(
            {'name': name, 'family': family, 'parameter': param, 'points': points}
        )
    out['wall_s'] = time.monotonic() - t0
    return out
