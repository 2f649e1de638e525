"""Road networks: the network methods on SUMO's network families, drawn per seed.

Each family cell (``mlkm_sumo.road_networks``: ``interchange``, ``arterial``, ``grid``) runs
every network method (``mlkm_core.network_assoc.NETWORK_METHODS``) on the datasets of seeds
1..N, with (time, speed) only and with lane and length (``assignment`` learns per hop how
the lane follows, ``gmlkm`` uses neither). The speed cell associates one large grid (``SPEED``:
2,000 vehicles) with the best method. Stone Soup (``peer_network``: set up as on one road,
the network's reach given to it as a hypothesiser) runs on every full cell, once per dataset
(it uses time and speed only), not in ``--quick`` runs (tens of seconds per dataset). Every
dataset's draw is written into the JSON, so any cell can be rebuilt from (family, seed). A
``--quick`` run (a smoke run, not figures) draws one seed per family with 50 vehicles and
leaves out the speed cell.
"""

from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

from mlkm_core.types import Detections

from .common import PEER, Log, pct, score_row, stream_rows, summarise

FAMILIES = ('interchange', 'arterial', 'grid')
SEEDS_FULL = 3
SEEDS_QUICK = 1
#: a ``--quick`` run's draws: fewer vehicles than the families' ranges (a smoke run of every
#: method and the stream, not figures)
QUICK_OVERRIDES = {'vehicles': 50}
VARIANTS = ('time_speed', 'lane_length')
VARIANT_LABELS = {'time_speed': 'time, speed', 'lane_length': '+ lane, length'}
#: the baseline every tracking method must beat, and the method of the speed cell
BASELINE = 'gmlkm'
BEST = 'assignment'
#: the best method as a stream (``mlkm_core.network_assoc.stream``, default settings)
STREAM = 'assignment_stream'
#: the issue's bars per family: (time and speed only, with lane and length)
TARGETS = {'interchange': (0.95, 0.99), 'arterial': (0.90, 0.97)}
#: least margin of the best method over the baseline on every family [fraction]
MARGIN = 0.05
#: the speed cell: (family, seed, overrides) and its bar [s]
SPEED = ('grid', 1, {'columns': 6, 'rows': 5, 'vehicles': 2000})
SPEED_LIMIT = 60.0
#: the stream's bar on the speed cell: p95 of the time a detection takes into a track [ms]
STREAM_P95_MS = 50.0
#: the stream's detections are pushed at their stamps this many times faster than real time
#: (the speed cell's 100 minutes of traffic in 5), its solves in a second process [-]
STREAM_SPEEDUP = 20.0
#: G-MLKM's own figure on its own simulated networks (Tao et al., Sensors 21(6):2069, 2021)
PUBLISHED_GMLKM = 0.922


def variant_of(d: Detections, name: str) -> Detections:
    if name == 'lane_length':
        return d
    return Detections(d.sensor_index, d.stamp, d.velocity, d.target)


def _dataset(family: str, seed: int, overrides: dict, cache_dir: Path | None):
    from mlkm_core.network import network_from_mapping
    from mlkm_sumo.road_networks import draw_network, generate_network

    draw = draw_network(family, seed, **overrides)
    ds = generate_network(draw, cache_dir=cache_dir)
    return draw, network_from_mapping(ds.mapping, f'{family} seed {seed}'), ds.detections()


def method_row(net, d: Detections, method: str) -> dict:
    from mlkm_core.network_assoc import associate_network

    from .peer_network import stonesoup_network_associate

    t0 = time.perf_counter()
    if method == PEER:
        labels = stonesoup_network_associate(net, variant_of(d, 'time_speed'))
    elif method == STREAM:
        labels = _streamed(net, d)
    else:
        labels = associate_network(net, d, method)
    return score_row(SimpleNamespace(detections=d), labels, time.perf_counter() - t0)


def _streamed(net, d: Detections):
    """The committed labels of ``d`` pushed in stamp order through the network's stream with
    its default settings (window solves inside the pushes), then flushed."""
    import numpy as np

    from mlkm_core.network_assoc.stream import NetworkStreamTracker

    tracker = NetworkStreamTracker(net)
    labels = np.full(len(d), -1, np.int64)
    updates = [tracker.push(*row) for row in stream_rows(d)]
    for update in [*updates, tracker.flush()]:
        for key, track in update.committed.tolist():
            labels[key] = track
    return labels


def run_network(log: Log, quick: bool, cache_dir: Path | None = None) -> dict:
    """Every network method on every family cell, both variants; the speed cell."""
    from mlkm_core.network_assoc import NETWORK_METHODS

    from .peer import stonesoup_version

    methods = [*NETWORK_METHODS, STREAM]
    peer = [PEER] if stonesoup_version() and not quick else []
    seeds = list(range(1, (SEEDS_QUICK if quick else SEEDS_FULL) + 1))
    overrides = QUICK_OVERRIDES if quick else {}
    cells = []
    for family in FAMILIES:
        t0 = time.monotonic()
        sets = [_dataset(family, s, overrides, cache_dir) for s in seeds]
        cell: dict = {
            'family': family,
            'seeds': seeds,
            'overrides': overrides,
            'draws': [draw.to_json() for draw, _, _ in sets],
            'detections_mean': sum(len(d) for _, _, d in sets) / len(sets),
            'stations_mean': sum(n.n_stations for _, n, _ in sets) / len(sets),
            'variants': {},
        }
        log(
            f'network {family}: {len(seeds)} datasets, {cell["detections_mean"]:.0f} detections,'
            f' {cell["stations_mean"]:.1f} stations each ({time.monotonic() - t0:.1f} s)'
        )
        for variant in VARIANTS:
            cell['variants'][variant] = {}
            for m in methods:
                rows = [method_row(n, variant_of(d, variant), m) for _, n, d in sets]
                s = summarise(rows)
                cell['variants'][variant][m] = {'summary': s, 'runs': rows}
                log(
                    f'network {family:12s} {variant:11s} {m:12s} {100 * s["accuracy_mean"]:7.3f}%'
                    f' n={s["n"]} ({sum(r["seconds"] for r in rows):.1f} s)'
                )
        for m in peer:  # time and speed only: one run serves both variants
            rows = [method_row(n, d, m) for _, n, d in sets]
            s = summarise(rows)
            for variant in VARIANTS:
                cell['variants'][variant][m] = {'summary': s, 'runs': rows}
            log(
                f'network {family:12s} {"both":11s} {m:12s} {100 * s["accuracy_mean"]:7.3f}%'
                f' n={s["n"]} ({sum(r["seconds"] for r in rows):.1f} s)'
            )
        cells.append(cell)
    out: dict = {
        'cells': cells,
        'methods': methods + peer,
        'published_gmlkm': PUBLISHED_GMLKM,
    }
    if not quick:
        family, seed, overrides = SPEED
        _, net, d = _dataset(family, seed, overrides, cache_dir)
        row = method_row(net, d, BEST)
        out['speed'] = {
            'family': family,
            'seed': seed,
            'overrides': overrides,
            'stations': net.n_stations,
            'detections': len(d),
            'method': BEST,
            'seconds': row['seconds'],
            'accuracy': row['accuracy'],
        }
        log(
            f'network speed: {BEST} on {net.n_stations} stations, {len(d)} detections: '
            f'{row["seconds"]:.1f} s, {100 * row["accuracy"]:.2f}%'
        )
        from .network_stream import paced_stream

        st = out['stream_speed'] = paced_stream(net, d, STREAM_SPEEDUP)
        log(
            f'network stream speed: {len(d)} detections at {STREAM_SPEEDUP:g}x real time, '
            f'latency p50 {st["latency_ms_p50"]:.1f} ms, p95 {st["latency_ms_p95"]:.1f} ms, '
            f'max {st["latency_ms_max"]:.0f} ms, {100 * st["accuracy"]:.2f}% '
            f'({st["seconds"]:.0f} s)'
        )
    return out


def _mean(cell: dict, variant: str, method: str) -> float | None:
    rec = cell['variants'].get(variant, {}).get(method)
    return None if rec is None or rec['summary']['n'] == 0 else rec['summary']['accuracy_mean']


def _best(cell: dict, variant: str) -> tuple[str | None, float | None]:
    """(method, mean accuracy) of the most accurate tracking method of a cell's variant (not
    the baseline, not the peer); (None, None) when none ran."""
    got = [
        (acc, m)
        for m in cell['variants'].get(variant, {})
        if m not in (BASELINE, PEER) and (acc := _mean(cell, variant, m)) is not None
    ]
    if not got:
        return None, None
    acc, m = max(got, key=lambda g: g[0])  # a tie: the first method run
    return m, acc


def report_lines(net: dict) -> list[str]:
    """The README section of the network part."""
    L = ['## Road networks: SUMO network families', '']
    if not net.get('cells'):
        return L + [str(net.get('status', 'not run')), '']
    L += [
        'The network methods (`mlkm_core.network_assoc`) on SUMO networks drawn per seed '
        '(`mlkm_sumo.road_networks`): a freeway interchange, a signalised arterial, a small '
        "grid. Cells: mean accuracy [%] (min..max) over the seeds. G-MLKM's authors report "
        f'{100 * net["published_gmlkm"]:.1f} % on their own simulated networks (published '
        'reference, not rerun here). `stonesoup` is Stone Soup set up as on one road, the '
        "network's reach given to it as a hypothesiser (`bench/peer_network.py`); it uses "
        'time and speed only, so both columns show its one run. `assignment_stream` is '
        '`assignment` as a stream (`mlkm_core.network_assoc.stream`, default settings: lag '
        '15 s growing to twice the p95 link time, nothing committed before the model was '
        'fitted on 500 detections).',
        '',
        '| family | stations | detections | method | '
        + ' | '.join(VARIANT_LABELS[v] for v in VARIANTS)
        + ' |',
        '| --- | --- | --- | --- |' + ' --- |' * len(VARIANTS),
    ]
    for c in net['cells']:
        for m in c['variants']['time_speed']:
            row = [c['family'], f'{c["stations_mean"]:.0f}', f'{c["detections_mean"]:.0f}']
            row.append(f'`{m}`')
            for v in VARIANTS:
                s = c['variants'][v][m]['summary']
                row.append(
                    f'{pct(s["accuracy_mean"])} ({pct(s["accuracy_min"])}..'
                    f'{pct(s["accuracy_max"])})'
                )
            L.append('| ' + ' | '.join(row) + ' |')
    sp = net.get('speed')
    if sp:
        L += [
            '',
            f'Speed: `{sp["method"]}` on a {sp["family"]} of {sp["stations"]} stations '
            f'({sp["overrides"]}), {sp["detections"]} detections: {sp["seconds"]:.1f} s, '
            f'{pct(sp["accuracy"])} %.',
        ]
    st = net.get('stream_speed')
    if st:
        L += [
            '',
            f'The stream on the same grid (`{STREAM}`, `bench/network_stream.py`): the '
            f'detections pushed at their stamps {st["speedup"]:g} times faster than real time '
            f'({st["stamp_span"] / 60:.0f} minutes of traffic in {st["seconds"] / 60:.1f}), the '
            'window solves in a second process as in the live node. From the moment a '
            'detection is due to its push returning with it in a track (the immediate link): '
            f'{st["latency_ms_p50"]:.1f} ms (median), {st["latency_ms_p95"]:.1f} ms (p95), '
            f'{st["latency_ms_p99"]:.1f} ms (p99), {st["latency_ms_max"]:.0f} ms at most; '
            f'{st["solves"]} window solves, {pct(st["accuracy"])} % committed. Core only: '
            'the node adds its transport.',
        ]
    L.append('')
    return L


def network_targets(net: dict) -> list[dict]:
    """The network targets, each ``{'target', 'met', 'value'}`` (met None = not run)."""
    out: list[dict] = []

    def check(name: str, ok: bool | None, value: str) -> None:
        out.append({'target': name, 'met': ok, 'value': value})

    if not net.get('cells'):
        check('network', None, str(net.get('status', 'not run')))
        return out
    for c in net['cells']:
        fam = c['family']
        if fam in TARGETS:
            for v, want in zip(VARIANTS, TARGETS[fam], strict=True):
                m, got = _best(c, v)
                check(
                    f'network {fam}: the best method ({VARIANT_LABELS[v]}) >= {100 * want:g}%',
                    None if got is None else got >= want,
                    'n/a' if got is None else f'{m} {pct(got)}%',
                )
        gaps = {}  # the best method of each variant -> its points above the baseline
        for v in VARIANTS:
            (m, best), base = _best(c, v), _mean(c, v, BASELINE)
            if best is not None and base is not None:
                gaps[f'{m} ({VARIANT_LABELS[v]})'] = 100 * (best - base)
        check(
            f'network {fam}: the best method >= {BASELINE} + {100 * MARGIN:g} points',
            bool(gaps) and min(gaps.values()) >= 100 * MARGIN,
            ', '.join(f'{k} {g:+.2f}' for k, g in gaps.items()) + ' points',
        )
        behind = []  # (method, variant, points) of every tracking method below the baseline
        for m in c['variants'][VARIANTS[0]]:
            if m in (BASELINE, PEER):
                continue
            for v in VARIANTS:
                got, base = _mean(c, v, m), _mean(c, v, BASELINE)
                if got is not None and base is not None and got < base:
                    behind.append(f'{m} ({VARIANT_LABELS[v]}) {100 * (got - base):+.2f}')
        check(
            f'network {fam}: every tracking method >= {BASELINE}',
            not behind,
            '; '.join(behind) + ' points' if behind else 'all at or above',
        )
    st = net.get('stream_speed')
    check(
        f'network stream: p95 detection-to-track latency < {STREAM_P95_MS:g} ms '
        f'on {SPEED[2]["vehicles"]} vehicles (core, {STREAM_SPEEDUP:g}x real time)',
        None if not st else st['latency_ms_p95'] < STREAM_P95_MS,
        'not run'
        if not st
        else f'p95 {st["latency_ms_p95"]:.1f} ms, max {st["latency_ms_max"]:.0f} ms',
    )
    sp = net.get('speed')
    check(
        f'network speed: {SPEED[2]["vehicles"]} vehicles associate in < {SPEED_LIMIT:g} s',
        None if not sp else sp['seconds'] < SPEED_LIMIT,
        'not run' if not sp else f'{sp["seconds"]:.1f} s on {sp["stations"]} stations',
    )
    return out
