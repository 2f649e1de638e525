"""SUMO traffic: every method and the Stone Soup peer on the SUMO scenarios.

Datasets come from ``mlkm_sumo.api.generate(scenario, n_vehicles, n_stations, seed)`` (seeds
1, 2, ...), generated once per run into a cache directory and shared by every method. Each
method sees every dataset twice: with (time, speed) only (``lane`` and ``length`` stripped
from the detections) and with lane and vehicle length added. Each (method, cell, variant)
runs in a child process with a time budget, as in the grid. The peer uses (time, speed) only,
so it runs on the first variant alone. It has budgets of its own (``PEER_BUDGET``: it takes
15-40 s per 50 x 20 dataset and about 40 minutes per 200 x 50 one); on the
larger cells it runs on the first dataset of ``PEER_LARGE`` only, which is enough for the
speed comparison at 200 x 50 and keeps the part's wall time near an hour.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

from mlkm_core.associators import AssociatorConfig, make_associator
from mlkm_core.types import Dataset

from .common import PEER, Log, pct, run_budgeted, summarise, timed_row
from .sumo_data import CLUTTER, FALSE_ALARMS_PER_VEHICLE, DatasetCache, load, measurement_config

SCENARIOS = ('single_lane', 'highway', 'congested', 'ramps')
#: (vehicles, stations) -> datasets per scenario
SEEDS_FULL = {(50, 20): 3, (200, 50): 2}
SEEDS_QUICK = {(50, 20): 1}
#: further cells, (scenario, measurement, (vehicles, stations)) -> datasets: the highway in
#: clutter and the congested road at 200 x 40
EXTRA_FULL = {
    ('highway', 'clutter', (50, 20)): 3,
    ('highway', 'clutter', (200, 50)): 2,
    ('congested', 'default', (200, 40)): 2,
}
EXTRA_QUICK = {('highway', 'clutter', (50, 20)): 1}
#: time budget [s] of one (method, cell, variant): all its datasets
BUDGET = {(50, 20): 120.0, (200, 40): 150.0, (200, 50): 150.0}
#: the peer's time budget [s] of one cell: all its datasets
PEER_BUDGET = {(50, 20): 400.0, (200, 40): 3000.0, (200, 50): 3000.0}
#: methods run on the larger cells (every method runs on the others)
LARGE = ('assignment', 'multiframe', 'mlkm_robust', 'mlkm')
LARGE_METHODS = {(200, 40): LARGE, (200, 50): LARGE}
#: (scenario, measurement, cell) of the larger cells the peer runs on, with its datasets
PEER_LARGE = {('highway', 'default', (200, 50)): 1}
VARIANTS = ('time_speed', 'lane_length')
VARIANT_LABELS = {'time_speed': 'time, speed', 'lane_length': '+ lane, length'}


def sumo_job(
    method: str, paths: list[Path], variant: str, measurement: str, config: AssociatorConfig
):
    """Job factory for ``run_budgeted``: load dataset k, associate, score. The methods get
    ``config`` (the road's ramps); the peer is told the measurement's noise."""

    def make_job():
        if method == PEER:
            from .peer import config_for, stonesoup_associate

            m = measurement_config(measurement)

            def assoc(d: Dataset):
                cfg = config_for(d.layout, d.detections)
                return stonesoup_associate(
                    d.layout, d.detections, m.stamp_jitter, m.speed_noise, cfg
                )
        else:
            a = make_associator(method, config)

            def assoc(d: Dataset):
                return a.associate(d.layout, d.detections, d.n_targets)

        return lambda k: timed_row(load(paths[k], variant), assoc)

    return make_job


def _peer_budget(cell: tuple[int, int]) -> float:
    return PEER_BUDGET.get(cell, BUDGET[cell])


def run_sumo(
    methods: list[str],
    seeds_per_cell: dict,
    log: Log,
    cache_dir: Path | None = None,
    extra: dict | None = None,
    families: dict | None = None,
    previous: dict | None = None,
    peer_rows: dict | None = None,
):
    """Every method (and the peer when Stone Soup is installed) on every scenario and cell,
    then on the ``extra`` cells (default: ``EXTRA_FULL`` with ``SEEDS_FULL``, else
    ``EXTRA_QUICK``), then the scenario families of ``families`` (a ``sumo_families.plan``;
    none without it). With ``previous`` (the part's last JSON: ``--families-only``) only the
    families run; the other cells are kept from it. With ``peer_rows`` (``peer_rows`` of the
    last JSON: ``--keep-peer``) a cell's peer row is taken from there where it has one."""
    import tempfile

    from .peer import PeerConfig, stonesoup_version
    from .sumo_families import plan, run_families

    if previous is not None:
        out = {k: v for k, v in previous.items() if k not in ('families', 'status')}
        # the run that made the cells kept: an earlier families-only run kept them too
        out['cells_run'] = previous.get('cells_run') or {
            k: previous.get(k) for k in ('date', 'wall_s', 'quick')
        }
        out.setdefault('cells', [])
        with tempfile.TemporaryDirectory(prefix='mlkm_bench_sumo_') as tmp:
            cache = DatasetCache(cache_dir or Path(tmp))
            out['families'] = run_families(methods, families or plan(False), log, cache)
        return out
    if extra is None:
        extra = EXTRA_FULL if seeds_per_cell == SEEDS_FULL else EXTRA_QUICK
    cases = [(sc, 'default', cell, n) for cell, n in seeds_per_cell.items() for sc in SCENARIOS]
    cases += [(sc, meas, cell, n) for (sc, meas, cell), n in extra.items()]
    version = stonesoup_version()
    out: dict = {
        'scenarios': list(SCENARIOS),
        'budget_s': {f'{a}x{b}': BUDGET[(a, b)] for a, b in sorted({c[2] for c in cases})},
        'peer_budget_s': {
            f'{a}x{b}': _peer_budget((a, b)) for a, b in sorted({c[2] for c in cases})
        },
        'measurement': asdict(measurement_config('default')),
        'clutter': {**CLUTTER, 'false_alarms_per_vehicle_per_station': FALSE_ALARMS_PER_VEHICLE},
        'peer': {
            'stonesoup_version': version,
            'config': asdict(PeerConfig()),
            'fitted_per_dataset': ['v_nominal', 'delete_after'],
        },
        'cells': [],
    }
    if version is None:
        log('sumo: stonesoup is not installed (make setup installs it); peer left out')
    with tempfile.TemporaryDirectory(prefix='mlkm_bench_sumo_') as tmp:
        cache = DatasetCache(cache_dir or Path(tmp))
        for scenario, measurement, cell, n in cases:
            cell_methods = [m for m in methods if m in LARGE_METHODS.get(cell, methods)]
            large = cell in LARGE_METHODS
            peer_n = PEER_LARGE.get((scenario, measurement, cell), 0) if large else n
            if version is not None and peer_n:
                cell_methods.append(PEER)
            kept = (peer_rows or {}).get((scenario, measurement, *cell))
            if kept is not None and PEER in cell_methods:
                cell_methods.remove(PEER)
            entry = _run_cell(scenario, measurement, cell, n, cell_methods, cache, log, peer_n)
            if kept is not None and 'error' not in entry:
                entry['variants']['time_speed'][PEER] = kept
                log(
                    f'sumo {scenario} ({measurement}) {cell[0]}x{cell[1]}: peer row kept from '
                    f'the run of {kept["ran"]}'
                )
            out['cells'].append(entry)
        if families:
            out['families'] = run_families(methods, families, log, cache)
    return out


def _run_cell(
    scenario: str,
    measurement: str,
    cell: tuple[int, int],
    n: int,
    methods,
    cache,
    log: Log,
    peer_n: int = 0,
) -> dict:
    """Every method on the cell's ``n`` datasets, the peer on the first ``peer_n``."""
    vehicles, stations = cell
    seeds = list(range(1, n + 1))
    name = scenario if measurement == 'default' else f'{scenario} ({measurement})'
    entry: dict = {
        'scenario': scenario,
        'measurement': measurement,
        'vehicles': vehicles,
        'stations': stations,
        'seeds': seeds,
        'variants': {v: {} for v in VARIANTS},
    }
    t0 = time.monotonic()
    try:
        paths = [cache.get(scenario, vehicles, stations, s, measurement) for s in seeds]
        roads = [cache.ramps(scenario, stations, s) for s in seeds]
    except Exception as exc:  # SumoError, a failing netconvert: the cell is reported as such
        entry['error'] = f'{type(exc).__name__}: {exc}'
        log(f'sumo {name} {vehicles}x{stations}: datasets failed: {entry["error"]}')
        return entry
    entries, exits = roads[0][0], roads[0][1]  # the ramps are the scenario's, not the seed's
    for p, (_, _, positions) in zip(paths, roads):
        if list(load(p, 'time_speed').layout.positions) != list(positions):
            raise RuntimeError(f'{p}: stations differ from the road of its seed')
    entry['entries'], entry['exits'] = list(entries), list(exits)
    config = AssociatorConfig(entries=entries, exits=exits)
    sets = [load(p, 'time_speed').detections for p in paths]
    entry['detections_mean'] = sum(len(d) for d in sets) / len(sets)
    entry['false_alarms_mean'] = sum(int((d.target < 0).sum()) for d in sets) / len(sets)
    log(
        f'sumo {name} {vehicles}x{stations}: {n} datasets, '
        f'{entry["detections_mean"]:.0f} detections each, ramps {entries} / {exits} '
        f'({time.monotonic() - t0:.1f} s)'
    )
    for variant in VARIANTS:
        for m in methods:
            if m == PEER and variant != 'time_speed':
                continue
            t1 = time.monotonic()
            job = sumo_job(m, paths, variant, measurement, config)
            count, budget = (
                (min(peer_n, n), _peer_budget(cell)) if m == PEER else (n, BUDGET[cell])
            )
            rows, status = run_budgeted(job, count, budget)
            entry['variants'][variant][m] = {
                'summary': summarise(rows),
                'status': status,
                'runs': rows,
                'datasets': count,
            }
            s = entry['variants'][variant][m]['summary']
            log(
                f'sumo {name:19s} {vehicles}x{stations} {variant:11s} {m:12s} '
                f'{s.get("accuracy_mean", float("nan")) * 100:7.3f}% n={s["n"]} {status} '
                f'({time.monotonic() - t1:.1f} s)'
            )
    return entry


def peer_rows(previous: dict) -> dict:
    """The peer's record of each cell of a ``sumo.json`` by (scenario, measurement, vehicles,
    stations), each with ``ran``: the date of the run that made it (kept over kept runs)."""
    ran = (previous.get('cells_run') or {}).get('date') or previous.get('date') or 'unknown'
    out = {}
    for c in previous.get('cells', []):
        rec = c.get('variants', {}).get('time_speed', {}).get(PEER)
        if rec is not None and 'error' not in c:
            key = (c['scenario'], c.get('measurement', 'default'), c['vehicles'], c['stations'])
            out[key] = {**rec, 'ran': rec.get('ran', ran)}
    return out


def find_cell(
    sumo: dict, scenario: str, vehicles: int, stations: int, measurement: str = 'default'
) -> dict | None:
    """The cell of ``sumo.json`` with these keys (``measurement`` 'default' when absent)."""
    for c in sumo.get('cells', []):
        key = (c['scenario'], c['vehicles'], c['stations'], c.get('measurement', 'default'))
        if key == (scenario, vehicles, stations, measurement) and 'error' not in c:
            return c
    return None


def _cell_text(rec: dict | None, n: int) -> str:
    if rec is None:
        return '—'
    s = rec['summary']
    if s['n'] == 0:
        return rec['status']
    txt = (
        f'{pct(s["accuracy_mean"])} ({pct(s["accuracy_min"])}..{pct(s["accuracy_max"])}) '
        f'{s["seconds_mean"]:.2f} s'
    )
    if rec['status'] != 'ok':
        txt += f' [{s["n"]} of {n}: {rec["status"].split(" after")[0]}]'
    return txt


def report_lines(sumo: dict) -> list[str]:
    """The README section of the SUMO part."""
    L = ['## SUMO traffic', '']
    if not sumo.get('cells'):
        return L + [str(sumo.get('status', 'not run')), '']
    peer = sumo.get('peer', {})
    L += [
        'Datasets from `mlkm_sumo.api.generate(scenario, vehicles, stations, seed)` (seeds '
        '1, 2, ...; default measurement: no noise, lane-change double reports kept as false '
        'alarms). Rows marked (clutter) add 5 % missed passages, 0.2 s stamp jitter and 0.05 '
        "false alarms per vehicle per station (the same count as the simulator's clutter "
        "mode; no speed or length noise, the measurement model's default). Every method is "
        "told the road's on- and off-ramp positions (`AssociatorConfig.entries` / `exits`; "
        'only `ramps` has any) and sees each dataset with (time, speed) only and again with '
        'lane and vehicle length added; cells are mean accuracy [%] (min..max) and seconds per '
        'dataset. Time budget per (method, cell, variant): '
        + ', '.join(f'{k}: {v:.0f} s' for k, v in sumo.get('budget_s', {}).items())
        + "; the peer's: "
        + ', '.join(f'{k}: {v:.0f} s' for k, v in sumo.get('peer_budget_s', {}).items())
        + f'. `{PEER}` is Stone Soup {peer.get("stonesoup_version") or "(not installed)"}, '
        'set up as in the peer part, with the nominal speed and the deletion time fitted to '
        'each dataset (`peer.config_for`: median speed; 1.5 x the longest station gap at the '
        '5th-percentile speed); it uses time and speed only, so it runs once, and on the '
        'larger cells it runs on the first dataset of the highway at 200 x 50 only (about 40 '
        'minutes each); the targets compare it with the best method on the datasets it '
        'finished.',
        '',
    ]
    kept = sorted(
        {
            c['variants']['time_speed'][PEER]['ran']
            for c in sumo['cells']
            if 'ran' in c.get('variants', {}).get('time_speed', {}).get(PEER, {})
        }
    )
    if kept:
        L += [
            f'The `{PEER}` rows were kept from the run of {", ".join(kept)} '
            '(`mlkm bench --only sumo --keep-peer`): the peer and its datasets did not change, '
            'the methods ran again.',
            '',
        ]
    extra = sumo.get('extra_cells')
    if extra:
        L += [
            f'The cells {", ".join(extra["cells"])} ran in a second process at the same time '
            f'as the others ({extra["wall_s"] / 60:.1f} min, {extra["date"]}; same code, same '
            'machine).',
            '',
        ]
    sizes = sorted({(c['vehicles'], c['stations']) for c in sumo['cells']})
    for vehicles, stations in sizes:
        cells = [
            c for c in sumo['cells'] if (c['vehicles'], c['stations']) == (vehicles, stations)
        ]
        L += [
            f'### {vehicles} vehicles, {stations} stations',
            '',
            '| scenario | detections | method | '
            + ' | '.join(VARIANT_LABELS[v] for v in VARIANTS)
            + ' |',
            '| --- | --- | --- |' + ' --- |' * len(VARIANTS),
        ]
        for c in cells:
            if 'error' in c:
                L.append(f'| {c["scenario"]} | — | — |' + f' {c["error"]} |' * len(VARIANTS))
                continue
            n = len(c['seeds'])
            det = f'{c["detections_mean"]:.0f} (n={n})'
            name = c['scenario']
            if c.get('measurement', 'default') != 'default':
                name += f' ({c["measurement"]})'
            for m in c['variants']['time_speed']:
                row = [name, det, f'`{m}`']
                for v in VARIANTS:
                    rec = c['variants'][v].get(m)
                    k = n if rec is None else rec.get('datasets', n)
                    txt = 'same (time and speed only)' if rec is None else _cell_text(rec, k)
                    row.append(txt + (f' (dataset 1 of {n})' if k == 1 < n else ''))
                L.append('| ' + ' | '.join(row) + ' |')
        L.append('')
    return L
