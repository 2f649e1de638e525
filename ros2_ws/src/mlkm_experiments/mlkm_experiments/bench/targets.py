"""The benchmark's targets: each one met or not, with the value measured."""

from __future__ import annotations

from .common import BASELINE, BEST
from .grid import grid_cell
from .network import network_targets
from .real import real_targets
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
    out += real_targets(results.get('real', {}))
    out += sumo_targets(results.get('sumo', {}))
    out += network_targets(results.get('network', {}))
    out += stream_targets(results.get('stream', {}))
    return out


def stream_targets(stream: dict) -> list[dict]:
    """The stream part's targets (latency, memory, throughput, accuracy against the lag)."""
    out = []
    why = stream.get('status', 'not run')

    def check(name: str, ok: bool | None, value: str) -> None:
        out.append({'target': name, 'met': ok, 'value': value})

    for name, r in (stream.get('latency') or {}).items():
        if 'latency_p95' not in r:
            check(f'stream: p95 latency <= 50 ms at {name}', None, r.get('status', why))
            continue
        ms = ', '.join(
            f'{q} {1000 * r[f"latency_{q}"]:.1f} ms'
            for q in ('p50', 'p95', 'p99')
            if r[f'latency_{q}'] is not None
        )
        rate = r.get('delivered_rate')
        check(
            f'stream: p95 latency <= 50 ms at {name}',
            r.get('ok'),
            ms + ('' if rate is None else f' (delivered {rate:.0f} det/s)'),
        )
    if not stream.get('latency'):
        check('stream: p95 latency <= 50 ms', None, why)
    mem = stream.get('memory') or {}
    g = (mem.get('rss_total') or {}).get('growth')
    check(
        'stream: RSS over the last sixth within 10 % of the second sixth (SUMO highway)',
        mem.get('rss_ok'),
        mem.get('status', why)
        if g is None
        else f'{100 * g:+.1f} % over {mem["duration"] / 60:.0f} simulated min',
    )
    c = mem.get('counts')
    check(
        'stream: no detection lost (SUMO highway)',
        mem.get('nothing_lost'),
        mem.get('status', why)
        if c is None
        else f'{c["received"]} of {c["source_published"]} received, {c["rejected"]} rejected, '
        f'{c["pushed"]} through the tracker, working set {c["working_set"]} at the end',
    )
    tp = stream.get('throughput') or {}
    ratio = tp.get('ratio')
    check(
        'stream: >= 70% of bare subscriber ingest',
        None if ratio is None else ratio >= 0.7,
        tp.get('status', why)
        if ratio is None
        else f'{ratio:.3f} ({tp["association_rate"]:.0f} vs {tp["bare_rate"]:.0f} det/s)',
    )
    lag = stream.get('lag') or {}
    for fam, r in (lag.get('families') or {}).items():
        d = lag['default_lag']
        check(
            f'stream: {fam} accuracy at lag {d:g} s within 0.5 points of batch',
            r['ok'],
            f'{100 * r["stream"][str(d)]:.2f} % vs {100 * r["batch"]:.2f} % '
            f'({-r["loss_points"]:+.2f})',
        )
    if not lag.get('families'):
        check('stream: accuracy at the default lag within 0.5 points of batch', None, why)
    return out
