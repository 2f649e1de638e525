"""Real traffic: every method and the Stone Soup peer on virtual loops over NGSIM I-80.

The trajectories are the repository's NGSIM I-80 part A extract (``data/ngsim_i80``: 111 real
vehicles, congested, stop-and-go; its README says what it is). Loops (``mlkm_core.loops``) are
placed on ``STATIONS`` evenly spaced stations over ``SPAN`` metres of road; the block's first
station is drawn per seed from ``START`` (a family of placements, not one hand-picked layout).
Each cell is (stations, closed or open): closed keeps the vehicles seen at every station (the
paper's closed road), open keeps every observed crossing (vehicles appear and disappear where
their observation starts and ends). Each method sees each dataset with (time, speed) only and
again with lane and vehicle length; the peer (time, speed only) runs on the first variant.
The stream tracker (``StreamConfig`` defaults, the live node's) runs ``BEST`` on every dataset
too, for the stream-against-batch comparison. Every run records how many
``DegradedResultWarning`` the method issued.
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np

from mlkm_core.associators import AssociatorConfig, DegradedResultWarning, make_associator
from mlkm_core.streaming import StreamConfig
from mlkm_core.types import Dataset

from .common import BEST, PEER, Log, pct, run_budgeted, summarise, time_speed_only, timed_row

#: The trajectories, relative to the repository root (where ``make bench`` runs).
DATA = Path('data/ngsim_i80/i80_trajectories_a.csv.gz')
STATIONS = (5, 10, 20)
VARIANTS_ROAD = ('closed', 'open')
SPAN = 400.0  # [m] from the first to the last station
START = (20.0, 100.0)  # [m] range of the first station's position, drawn per seed
#: placements per cell: at 5 stations the spread between placements is several points, and on
#: three of them `multiframe` leads `assignment` where on eight it trails it
SEEDS_FULL = 8
SEEDS_QUICK = 1
VARIANTS = ('time_speed', 'lane_length')
VARIANT_LABELS = {'time_speed': 'time, speed', 'lane_length': '+ lane, length'}
STREAM = 'stream'  # the row of the stream tracker (running BEST)
BUDGET = 300.0  # [s] per (method, cell, variant): all its datasets
PEER_BUDGET = 900.0


def placement(seed: int) -> float:
    """The first station's position [m] of dataset ``seed`` (1, 2, ...)."""
    return float(np.random.default_rng(seed).uniform(*START))


def datasets(traj, stations: int, road: str, seeds: list[int]) -> list[Dataset]:
    """The loops of a cell on ``traj`` (``mlkm_core.trajectories.Trajectories``), one
    dataset per seed's placement."""
    from mlkm_core.loops import even_positions, virtual_loops

    out = []
    for s in seeds:
        x0 = placement(s)
        loops = virtual_loops(traj, even_positions(stations, x0, x0 + SPAN), road == 'closed')
        out.append(loops.dataset)
    return out


def variant(ds: Dataset, name: str) -> Dataset:
    return ds if name == 'lane_length' else time_speed_only(ds)


def _job(method: str, sets: list[Dataset], name: str):
    def make_job():
        if method == PEER:
            from .peer import config_for, stonesoup_associate

            def assoc(ds: Dataset):
                return stonesoup_associate(
                    ds.layout, ds.detections, 0.0, 0.0, config_for(ds.layout, ds.detections)
                )
        elif method == STREAM:
            from .stream_lag import stream_labels

            def assoc(ds: Dataset):
                return stream_labels(ds, StreamConfig.lag, BEST)
        else:
            a = make_associator(method, AssociatorConfig())

            def assoc(ds: Dataset):
                return a.associate(ds.layout, ds.detections, ds.n_targets)

        def run(k: int) -> dict:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter('always', DegradedResultWarning)
                row = timed_row(variant(sets[k], name), assoc)
            row['degraded'] = sum(issubclass(w.category, DegradedResultWarning) for w in caught)
            return row

        return run

    return make_job


def run_real(methods: list[str], seeds: int, log: Log, path: Path = DATA) -> dict:
    """Every cell of ``STATIONS`` x ``VARIANTS_ROAD``; see the module docstring."""
    from .peer import stonesoup_version

    if not path.exists():
        return {'status': f'not run: {path} not found (run from the repository root)'}
    from mlkm_core.trajectories import read_trajectories

    traj = read_trajectories(path)
    version = stonesoup_version()
    seed_list = list(range(1, seeds + 1))
    out: dict = {
        'data': str(path),
        'span_m': SPAN,
        'start_m': list(START),
        'placements_m': {str(s): placement(s) for s in seed_list},
        'peer': {'stonesoup_version': version},
        'stream_lag_s': StreamConfig.lag,
        'cells': [],
    }
    for stations in STATIONS:
        for road in VARIANTS_ROAD:
            sets = datasets(traj, stations, road, seed_list)
            cell: dict = {
                'stations': stations,
                'road': road,
                'detections_mean': float(np.mean([len(d.detections) for d in sets])),
                'vehicles_mean': float(np.mean([d.n_targets for d in sets])),
                'variants': {v: {} for v in VARIANTS},
            }
            for name in VARIANTS:
                runs = [*methods, STREAM] + ([PEER] if version and name == 'time_speed' else [])
                for m in runs:
                    t0 = time.monotonic()
                    rows, status = run_budgeted(
                        _job(m, sets, name), len(sets), PEER_BUDGET if m == PEER else BUDGET
                    )
                    s = summarise(rows)
                    s['degraded'] = int(sum(r['degraded'] for r in rows))
                    cell['variants'][name][m] = {'summary': s, 'status': status, 'runs': rows}
                    log(
                        f'real {stations:2d} stations {road:6s} {name:11s} {m:12s} '
                        f'{s.get("accuracy_mean", float("nan")) * 100:7.3f}% n={s["n"]} '
                        f'degraded={s["degraded"]} {status} ({time.monotonic() - t0:.1f} s)'
                    )
            out['cells'].append(cell)
    return out


def find_cell(real: dict, stations: int, road: str) -> dict | None:
    for c in real.get('cells', []):
        if (c['stations'], c['road']) == (stations, road):
            return c
    return None


def report_lines(real: dict) -> list[str]:
    """The README section of the real-traffic part."""
    L = ['## Real traffic: NGSIM I-80', '']
    if not real.get('cells'):
        return L + [str(real.get('status', 'not run')), '']
    starts = ', '.join(f'{v:.1f}' for v in real['placements_m'].values())
    L += [
        f'Virtual loops (`mlkm_core.loops`) on the real trajectories of `{real["data"]}` '
        f'(111 vehicles, congested): N stations evenly spaced over {real["span_m"]:g} m, the '
        f'first at {starts} m (one dataset each). Closed: the vehicles seen at every station; '
        'open: every observed crossing. Cells: mean accuracy [%] (min..max) over the '
        f'placements; `{STREAM}` is the stream tracker running `{BEST}` at the default lag '
        f'({real["stream_lag_s"]:g} s); degraded = DegradedResultWarning issued.',
        '',
        '| stations | road | detections | method | '
        + ' | '.join(VARIANT_LABELS[v] for v in VARIANTS)
        + ' | degraded |',
        '| --- | --- | --- | --- |' + ' --- |' * len(VARIANTS) + ' --- |',
    ]
    for c in real['cells']:
        for m in c['variants']['time_speed']:
            row = [str(c['stations']), c['road'], f'{c["detections_mean"]:.0f}', f'`{m}`']
            degraded = 0
            for v in VARIANTS:
                rec = c['variants'][v].get(m)
                if rec is None:
                    row.append('—')
                    continue
                s = rec['summary']
                degraded += s.get('degraded', 0)
                if s['n'] == 0:
                    row.append(rec['status'])
                    continue
                row.append(
                    f'{pct(s["accuracy_mean"])} ({pct(s["accuracy_min"])}..'
                    f'{pct(s["accuracy_max"])})'
                )
            L.append('| ' + ' | '.join(row) + f' | {degraded} |')
    L.append('')
    return L


#: (time, speed) only: the best method's least accuracy per station count (the issue's bar).
TIME_SPEED_TARGET = {5: 0.92, 10: 0.97, 20: 0.995}
#: Largest allowed gap of the stream below batch [points].
STREAM_GAP = 0.5


def _mean(cell: dict, variant: str, method: str) -> float | None:
    rec = cell['variants'].get(variant, {}).get(method)
    if rec is None or rec['summary']['n'] == 0:
        return None
    return rec['summary']['accuracy_mean']


def real_targets(real: dict) -> list[dict]:
    """The targets on real traffic, each ``{'target', 'met', 'value'}`` (met None = not run)."""
    out: list[dict] = []

    def check(name: str, ok: bool | None, value: str) -> None:
        out.append({'target': name, 'met': ok, 'value': value})

    cells = real.get('cells', [])
    if not cells:
        check('real NGSIM', None, str(real.get('status', 'not run')))
        return out
    for c in cells:
        tag = f'real {c["stations"]} stations {c["road"]}'
        base = _mean(c, 'time_speed', 'assignment')
        best = _mean(c, 'time_speed', BEST)
        want = TIME_SPEED_TARGET[c['stations']]
        check(
            f'{tag}: {BEST} (time, speed) >= {100 * want:g}%',
            None if best is None else best >= want,
            'n/a' if best is None else f'{pct(best)}%',
        )
        worse = []
        for v in VARIANTS:
            b, a = _mean(c, v, BEST), _mean(c, v, 'assignment')
            if b is not None and a is not None and b < a:
                worse.append(f'{VARIANT_LABELS[v]}: {pct(b)} < {pct(a)}')
        check(
            f'{tag}: {BEST} >= assignment',
            None if base is None else not worse,
            '; '.join(worse) or 'both variants',
        )
        full = _mean(c, 'lane_length', BEST)
        check(
            f'{tag}: {BEST} with lane and length = 100%',
            None if full is None else full >= 1.0,
            'n/a' if full is None else f'{pct(full)}%',
        )
        degraded = sum(
            rec['summary'].get('degraded', 0)
            for v in VARIANTS
            for m, rec in c['variants'][v].items()
            if m != PEER
        )
        check(f'{tag}: no DegradedResultWarning', degraded == 0, f'{degraded} issued')
        gaps = []
        for v in VARIANTS:
            b, s = _mean(c, v, BEST), _mean(c, v, STREAM)
            if b is not None and s is not None:
                gaps.append(100 * (b - s))
        check(
            f'{tag}: stream within {STREAM_GAP} points of batch',
            None if not gaps else max(gaps) <= STREAM_GAP,
            ', '.join(f'{g:+.2f}' for g in gaps) + ' points below batch',
        )
    return out
