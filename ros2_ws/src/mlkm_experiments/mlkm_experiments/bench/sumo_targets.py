"""The accuracy targets on SUMO traffic, and the grid held against a reference run.

All SUMO targets are those of the best method (``BEST``), from ``sumo.json``; the scenario
families' targets are in ``sumo_families_report``. The grid
reference (``grid_reference.json``) holds the mean accuracies of ``REFERENCE_METHODS`` from a
committed grid run; every rerun of the grid is compared with it cell by cell.
"""

from __future__ import annotations

from .common import BASELINE, BEST, PEER
from .grid import grid_cell
from .sumo import find_cell
from .sumo_families_report import family_targets

#: the methods whose grid accuracy the reference keeps
REFERENCE_METHODS = ('multiframe', 'assignment', 'mlkm_robust')
#: largest drop [fraction] of a grid figure below the reference
REFERENCE_TOLERANCE = 0.001
#: the sizes of the SUMO part that every scenario runs at
SIZES = ((50, 20), (200, 50))


def _fmt(x: float | None) -> str:
    return 'n/a' if x is None else f'{100 * x:.2f}%'


def _summary(cell: dict | None, variant: str, method: str = BEST) -> dict | None:
    if cell is None:
        return None
    rec = cell['variants'].get(variant, {}).get(method)
    if rec is None or rec['summary']['n'] == 0:
        return None
    return rec['summary']


def _threshold(
    sumo: dict,
    cells: list[tuple[str, int, int, str]],
    variant: str,
    mean: float,
    seed_min: float | None = None,
) -> tuple[bool | None, str]:
    """Every cell's mean >= ``mean`` (and, if given, every dataset >= ``seed_min``)."""
    ok: bool | None = True
    parts = []
    for scenario, v, s, measurement in cells:
        sm = _summary(find_cell(sumo, scenario, v, s, measurement), variant)
        if sm is None:
            ok = None if ok is not False else ok
            parts.append(f'{v}x{s}: not measured')
            continue
        good = sm['accuracy_mean'] >= mean
        txt = f'{v}x{s}: {_fmt(sm["accuracy_mean"])}'
        if seed_min is not None:
            good = good and sm['accuracy_min'] >= seed_min
            txt += f' (lowest dataset {_fmt(sm["accuracy_min"])})'
        ok = False if not good else ok
        parts.append(txt)
    return ok, '; '.join(parts)


def _cell_name(c: dict) -> str:
    m = c.get('measurement', 'default')
    return f'{c["scenario"]}{"" if m == "default" else f" ({m})"} {c["vehicles"]}x{c["stations"]}'


def _first(cell: dict, variant: str, method: str, k: int) -> dict | None:
    """Mean accuracy and seconds of ``method`` over the cell's first ``k`` datasets (those the
    peer ran on), None when it has fewer."""
    rec = cell['variants'].get(variant, {}).get(method)
    rows = [] if rec is None else rec['runs'][:k]
    if k == 0 or len(rows) < k:
        return None
    return {
        'accuracy_mean': sum(r['accuracy'] for r in rows) / k,
        'seconds_mean': sum(r['seconds'] for r in rows) / k,
    }


def _peer_seconds(rec: dict, budget: float) -> tuple[float, bool]:
    """The peer's seconds per dataset, and whether that is a lower bound: a peer stopped at
    the budget after k datasets spent more than the budget on k + 1 of them."""
    s = rec['summary']
    if rec['status'] == 'ok':
        return s['seconds_mean'], False
    return budget / (s['n'] + 1), True


def sumo_targets(sumo: dict) -> list[dict]:
    out = []

    def check(name: str, ok: bool | None, value: str) -> None:
        out.append({'target': f'sumo: {name}', 'met': ok, 'value': value})

    if not sumo.get('cells'):
        check('accuracy and speed targets', None, str(sumo.get('status', 'not run')))
        return out + family_targets(sumo)
    ll, ts = 'lane_length', 'time_speed'
    check(
        'single_lane, with lane and length: mean >= 99.9%',
        *_threshold(sumo, [('single_lane', v, s, 'default') for v, s in SIZES], ll, 0.999),
    )
    hw = [('highway', v, s, 'default') for v, s in SIZES]
    check(
        'highway, with lane and length: mean >= 99.0%, no dataset < 97%',
        *_threshold(sumo, hw, ll, 0.99, 0.97),
    )
    check(
        'highway, time and speed only: mean >= 95.0%, no dataset < 90%',
        *_threshold(sumo, hw, ts, 0.95, 0.90),
    )
    check(
        'highway in clutter, with lane and length: mean >= 97%',
        *_threshold(sumo, [('highway', v, s, 'clutter') for v, s in SIZES], ll, 0.97),
    )
    check(
        'congested 200x40, with lane and length: mean >= 97%',
        *_threshold(sumo, [('congested', 200, 40, 'default')], ll, 0.97),
    )
    check(
        'ramps, with lane and length: mean >= 98%',
        *_threshold(sumo, [('ramps', v, s, 'default') for v, s in SIZES], ll, 0.98),
    )
    cells = [c for c in sumo['cells'] if 'error' not in c]
    worse, compared = [], 0
    for c in cells:
        peer = c['variants'][ts].get(PEER)
        if peer is None or peer['status'] != 'ok':
            continue
        best = _first(c, ts, BEST, peer['summary']['n'])
        if best is None:
            continue
        compared += 1
        if best['accuracy_mean'] < peer['summary']['accuracy_mean']:
            worse.append(
                f'{_cell_name(c)}: {_fmt(best["accuracy_mean"])} < '
                f'{_fmt(peer["summary"]["accuracy_mean"])}'
            )
    check(
        f'at least as accurate as {PEER} (time and speed, as the peer) on the datasets it '
        'finished',
        None if not compared else not worse,
        '; '.join(worse) or f'all {compared} cells',
    )
    worse, compared = [], 0
    for c in cells:
        for variant in (ts, ll):
            b, a = _summary(c, variant), _summary(c, variant, BASELINE)
            if b is None or a is None:
                continue
            compared += 1
            if b['accuracy_mean'] < a['accuracy_mean']:
                worse.append(
                    f'{_cell_name(c)} {variant}: {_fmt(b["accuracy_mean"])} < '
                    f'{_fmt(a["accuracy_mean"])}'
                )
    check(
        f'at least as accurate as {BASELINE} on every cell and variant',
        None if not compared else not worse,
        '; '.join(worse) or f'all {compared} cells and variants',
    )
    speed = []
    budget = sumo.get('peer_budget_s', sumo['budget_s']).get('200x50', 0.0)
    for c in cells:
        if (c['vehicles'], c['stations']) != (200, 50):
            continue
        peer = c['variants'][ts].get(PEER)
        if peer is None:
            continue
        best = _first(c, ts, BEST, max(peer['summary']['n'], 1))
        if best is None:
            continue
        secs, bound = _peer_seconds(peer, budget)
        speed.append((secs / best['seconds_mean'], bound, _cell_name(c)))
    if speed:
        ratio, bound, name = min(speed)
        value = f'lowest {"at least " if bound else ""}{ratio:.0f}x ({name})'
        if bound:
            value += (
                f'; the peer stopped at the {budget:.0f} s budget counts as taking at least the '
                'budget for the dataset it was on'
            )
        check(f'200x50: >= 10x faster than {PEER}', ratio >= 10, value)
    else:
        check(f'200x50: >= 10x faster than {PEER}', None, 'not measured')
    return out + family_targets(sumo)


def grid_reference_target(grid: dict, reference: dict) -> dict:
    """No figure of ``REFERENCE_METHODS`` on the grid more than ``REFERENCE_TOLERANCE`` below
    the reference run's."""
    name = (
        f'grid: no figure of {", ".join(REFERENCE_METHODS)} more than '
        f'{100 * REFERENCE_TOLERANCE:.1f} point below the {reference.get("date", "reference")} '
        'run'
    )
    if not reference.get('cells') or not grid.get('cells'):
        return {'target': name, 'met': None, 'value': 'no reference or no grid run'}
    drops, compared, worst = [], 0, None
    for ref in reference['cells']:
        c = grid_cell(grid, ref['targets'], ref['sensors'], ref['mode'])
        for m, r in ref['methods'].items():
            if c is None or m not in c['methods'] or r.get('accuracy_mean') is None:
                continue
            now = c['methods'][m]['summary'].get('accuracy_mean')
            if now is None:
                drops.append(f'{ref["targets"]}/{ref["sensors"]} {ref["mode"]} {m}: not measured')
                continue
            compared += 1
            d = now - r['accuracy_mean']
            label = f'{ref["targets"]}/{ref["sensors"]} {ref["mode"]} {m}'
            if worst is None or d < worst[0]:
                worst = (d, label)
            if d < -REFERENCE_TOLERANCE:
                drops.append(f'{label}: {_fmt(now)} vs {_fmt(r["accuracy_mean"])}')
    value = '; '.join(drops) if drops else f'{compared} figures compared'
    if worst is not None:
        value += f'; smallest change {100 * worst[0]:+.3f} points ({worst[1]})'
    return {'target': name, 'met': None if not compared else not drops, 'value': value}
