"""The benchmark's targets: each one met or not, with the value measured."""

from __future__ import annotations

from .common import BASELINE, BEST
from .grid import grid_cell
from .sumo_targets import grid_reference_target, sumo_targets


def _acc(
    grid: dict, t: int, s: int, mode: str, m: str, key: str = 'accuracy_mean'
) -> float | None:
    c = grid_cell(grid, t, s, mode)
    if not c or m not in c['methods']:
        return None
    return c['methods'][m]['summary'].get(key)


def evaluate_targets(results: dict[str, dict]) -> list[dict]:
    """Each target: ``{'target', 'met' (True, False or None = not measured), 'value'}``."""
    grid, cost, peer, live = (results.get(k, {}) for k in ('grid', 'cost', 'peer', 'live'))
    out = []

    def check(name: str, ok: bool | None, value: str) -> None:
        out.append({'target': name, 'met': ok, 'value': value})

    def fmt(x: float | None) -> str:
        return 'n/a' if x is None else f'{100 * x:.3f}%'

    a, lo = _acc(grid, 50, 20, 'paper', BEST), _acc(grid, 50, 20, 'paper', BEST, 'accuracy_min')
    check('paper 50/20: best mean >= 99.9%', None if a is None else a >= 0.999, fmt(a))
    check('paper 50/20: no dataset < 99.5%', None if lo is None else lo >= 0.995, fmt(lo))
    a = _acc(grid, 200, 50, 'paper', BEST)
    check('paper 200/50: best >= 99.7%', None if a is None else a >= 0.997, fmt(a))
    a = _acc(grid, 1000, 100, 'paper', BEST)
    check('paper 1000/100: best >= 99.0%', None if a is None else a >= 0.990, fmt(a))
    a = _acc(grid, 50, 20, 'clutter', BEST)
    check('clutter 50/20: best mean >= 99.3%', None if a is None else a >= 0.993, fmt(a))
    r, p = _acc(grid, 50, 20, 'clutter', 'mlkm_robust'), _acc(grid, 50, 20, 'clutter', 'mlkm')
    ok = None if r is None or p is None else r - p >= 0.10
    check(
        'clutter 50/20: mlkm_robust beats mlkm by >= 10 points',
        ok,
        f'{fmt(r)} vs {fmt(p)}' + ('' if ok is None else f' (+{100 * (r - p):.1f})'),
    )
    worse = []
    for c in grid.get('cells', []):
        b = c['methods'].get(BEST, {}).get('summary', {}).get('accuracy_mean')
        s = c['methods'].get(BASELINE, {}).get('summary', {}).get('accuracy_mean')
        if b is not None and s is not None and b < s:
            worse.append(f'{c["targets"]}/{c["sensors"]} {c["mode"]}: {fmt(b)} < {fmt(s)}')
    check(f'{BEST} >= {BASELINE} on every grid cell', not worse, '; '.join(worse) or 'all cells')
    if peer.get('cells'):
        bad = [
            f'{c["targets"]}/{c["sensors"]} {c["mode"]}'
            for c in peer['cells']
            if c[BEST]['accuracy_mean'] < c['stonesoup']['accuracy_mean']
        ]
        check(
            'vs Stone Soup: at least as accurate on every cell',
            not bad,
            '; '.join(
                f'{c["targets"]}/{c["sensors"]} {c["mode"]}: '
                f'{fmt(c[BEST]["accuracy_mean"])} vs '
                f'{fmt(c["stonesoup"]["accuracy_mean"])}'
                for c in peer['cells']
            ),
        )
        sp = min(c['speedup'] for c in peer['cells'])
        check('vs Stone Soup: >= 100x faster', sp >= 100, f'min speedup {sp:.0f}x')
    else:
        check('vs Stone Soup', None, peer.get('error', 'not run'))
    a = grid_cell(grid, 1000, 100, 'paper')
    sec = (
        None
        if a is None or BEST not in a['methods']
        else (a['methods'][BEST]['summary'].get('seconds_mean'))
    )
    check(
        'scale: 1000x100 (1e5 detections) < 30 s',
        None if sec is None else sec < 30,
        'n/a' if sec is None else f'{sec:.1f} s (grid run, child process)',
    )
    sl = cost.get('methods', {}).get(BEST, {}).get('time_slope')
    check(
        'scale: fitted log-log cost slope <= 1.5',
        None if sl is None else sl <= 1.5,
        'n/a' if sl is None else f'{sl:.2f}',
    )
    ratio = live.get('ingest_ratio')
    p95 = live.get('association_node', {}).get('latency_p95')
    check(
        'live: >= 70% of bare subscriber ingest',
        None if ratio is None else ratio >= 0.7,
        live.get('status', '') if ratio is None else f'{ratio:.2f}',
    )
    check(
        'live: p95 latency <= 100 ms',
        None if p95 is None else p95 <= 0.1,
        live.get('status', '') if p95 is None else f'{1000 * p95:.1f} ms',
    )
    soak = results.get('soak', {})
    rss = soak.get('rss', {})
    check(
        'soak: RSS of the association and scorer nodes grows <= 10 %',
        soak.get('rss_ok'),
        '; '.join(
            f'{n} {100 * r["growth"]:+.1f} %' for n, r in rss.items() if r['growth'] is not None
        )
        or soak.get('status', 'not run'),
    )
    check(
        'soak: no detection lost',
        soak.get('nothing_lost'),
        'n/a' if 'nothing_lost' not in soak else f'{soak["scored"]["episodes"]} episodes scored',
    )
    out.append(grid_reference_target(grid, results.get('grid_reference', {})))
    out += sumo_targets(results.get('sumo', {}))
    return out
