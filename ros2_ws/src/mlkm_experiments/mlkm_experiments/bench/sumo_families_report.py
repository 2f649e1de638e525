"""README section and targets of the SUMO scenario families (``sumo.json`` key ``families``).

The targets are those of the best method (``BEST``), as the issue states them: with lane and
length >= 99 % on free flow, >= 97 % on ramps, >= 95 % at every severity (the work-zone
cell and every point of the severity curve, up to 1.5); with time and speed only >= 85 % at
every severity; and no cliff: no curve drops by more than 5 points between neighbouring
points.
"""

from __future__ import annotations

from .common import BEST, pct

VARIANT_LABELS = {'time_speed': 'time, speed', 'lane_length': '+ lane, length'}
#: largest drop [fraction] between neighbouring points of a curve
CLIFF = 0.05


def _fmt(x: float | None) -> str:
    return 'n/a' if x is None else f'{100 * x:.2f}%'


def _summary(cell: dict | None, variant: str, method: str = BEST) -> dict | None:
    if cell is None or 'error' in cell:
        return None
    rec = cell['variants'].get(variant, {}).get(method)
    return None if rec is None or rec['summary']['n'] == 0 else rec['summary']


def family_cell(fam: dict, name: str) -> dict | None:
    return next((c for c in fam.get('cells', []) if c['family'] == name), None)


def curve(fam: dict, name: str, family: str) -> dict | None:
    return next(
        (c for c in fam.get('curves', []) if (c['name'], c['family']) == (name, family)), None
    )


def _draw_ranges(cell: dict) -> str:
    """What the cell's seeds drew: lanes, length, severity, vehicles, stations, mix."""
    ds = cell.get('draws', [])
    if not ds:
        return ''

    def span(key: str, fmt: str) -> str:
        lo, hi = min(d[key] for d in ds), max(d[key] for d in ds)
        return format(lo, fmt) if lo == hi else f'{format(lo, fmt)}-{format(hi, fmt)}'

    mixes = sorted({d['mix'] for d in ds})
    return (
        f'lanes {span("lanes", "d")}, {span("road_length", ".0f")} m, severity '
        f'{span("severity", ".2f")}, {span("vehicles", "d")} vehicles, station spacing '
        f'{span("spacing", ".0f")} m ({len(min(ds, key=lambda d: len(d["stations"]))["stations"])}'
        f'-{len(max(ds, key=lambda d: len(d["stations"]))["stations"])} stations), mix '
        f'{"/".join(mixes)}'
    )


def _seeds(n: int) -> str:
    return 'seed 1' if n == 1 else f'seeds 1-{n}'


def _cell_text(rec: dict | None, n: int, seconds: bool = True) -> str:
    if rec is None:
        return '—'
    s = rec['summary']
    if s['n'] == 0:
        return rec['status']
    txt = f'{pct(s["accuracy_mean"])} ({pct(s["accuracy_min"])}..{pct(s["accuracy_max"])})'
    if seconds:
        txt += f' {s["seconds_mean"]:.2f} s'
    if s['n'] < n:
        txt += f' [{s["n"]} of {n}]'
    return txt


def report_lines(sumo: dict, plots: list[str] | None = None) -> list[str]:
    """The README section of the families (empty when they did not run)."""
    fam = sumo.get('families')
    if not fam:
        return []
    L = [
        '## SUMO scenario families',
        '',
        'Traffic not tuned by hand: every dataset is `mlkm_sumo.families.draw(family, seed)` '
        '(seeds 1, 2, ...), a road with 2-4 lanes and 3-6 km, a bottleneck, demand, vehicle '
        'mix and station placement drawn from the family ranges (docs/benchmarks.md); the '
        'draws are in `sumo.json` (`families.cells[].draws`). Severity = demand / capacity of '
        f'the bottleneck, capacity = its lanes x {fam.get("capacity_per_lane", 0):.0f} '
        'vehicles/h. Cells: mean accuracy [%] (min..max over seeds), seconds per dataset; '
        f'time budget {fam.get("budget_s", 0):.0f} s per (method, cell, variant), the '
        f'peer budget {fam.get("peer_budget_s", 0):.0f} s per cell on the first '
        f'{fam.get("plan", {}).get("peer_seeds", 0)} dataset(s) of each family cell.',
        '',
    ]
    if sumo.get('cells_run'):
        kept = sumo['cells_run'].get('date') if sumo.get('cells') else None
        L += [
            f'The families ran alone (`--families-only`, {fam.get("wall_s", 0) / 60:.1f} min); '
            + (f'the other SUMO cells are those of {kept}.' if kept else 'no other SUMO cells.'),
            '',
        ]
    for c in fam.get('cells', []):
        L += [f'### Family `{c["family"]}`', '']
        if 'error' in c:
            L += [c['error'], '']
            continue
        n = len(c['seeds'])
        L += [
            f'{fam["families"][c["family"]]["description"]}. Drawn for {_seeds(n)}: '
            f'{_draw_ranges(c)}; {c["detections_mean"]:.0f} detections per dataset.',
            '',
            '| method | ' + ' | '.join(VARIANT_LABELS.values()) + ' |',
            '| --- |' + ' --- |' * len(VARIANT_LABELS),
        ]
        for m in c['variants']['time_speed']:
            row = [f'`{m}`']
            for v in VARIANT_LABELS:
                rec = c['variants'][v].get(m)
                k = n if rec is None else rec.get('datasets', n)
                row.append('same (time and speed only)' if rec is None else _cell_text(rec, k))
            L.append('| ' + ' | '.join(row) + ' |')
        L.append('')
    for cv in fam.get('curves', []):
        pts = cv['points']
        unit = ' [m]' if cv['parameter'] == 'spacing' else ''
        L += [
            f'### Accuracy against {cv["parameter"]}: `{cv["family"]}`',
            '',
            f'{_seeds(len(pts[0]["seeds"]) if pts else 0).capitalize()} of `{cv["family"]}` '
            f'with the {cv["parameter"]} fixed, the rest of each draw unchanged; mean accuracy '
            '[%] (min..max over seeds).',
            '',
            '| method | variant | ' + ' | '.join(f'{p["x"]:g}{unit}' for p in pts) + ' |',
            '| --- | --- |' + ' --- |' * len(pts),
        ]
        methods = next((list(p['variants']['time_speed']) for p in pts if 'error' not in p), [])
        for m in methods:
            for v, label in VARIANT_LABELS.items():
                row = [f'`{m}`', label]
                for p in pts:
                    rec = None if 'error' in p else p['variants'][v].get(m)
                    txt = _cell_text(rec, len(p['seeds']), seconds=False)
                    row.append('—' if rec is None else txt)
                L.append('| ' + ' | '.join(row) + ' |')
        name = f'sumo_curve_{cv["parameter"]}_{cv["family"]}.png'
        if plots is None or name in plots:
            L += ['', f'![{cv["parameter"]} {cv["family"]}]({name})']
        L.append('')
    return L


def family_targets(sumo: dict) -> list[dict]:
    """The families' targets (none when they did not run)."""
    fam = sumo.get('families')
    if not fam:
        return []
    out = []

    def check(name: str, ok: bool | None, value: str) -> None:
        out.append({'target': f'sumo families: {name}', 'met': ok, 'value': value})

    def at_least(cells: list[tuple[str, dict | None]], variant: str, low: float):
        ok: bool | None = True
        parts = []
        for label, cell in cells:
            s = _summary(cell, variant)
            if s is None:
                ok = None if ok is not False else ok
                parts.append(f'{label}: not measured')
                continue
            ok = False if s['accuracy_mean'] < low else ok
            parts.append(f'{label}: {_fmt(s["accuracy_mean"])} (lowest {_fmt(s["accuracy_min"])})')
        return ok, '; '.join(parts)

    ll, ts = 'lane_length', 'time_speed'
    check(
        'free_flow, with lane and length: mean >= 99%',
        *at_least([('free_flow', family_cell(fam, 'free_flow'))], ll, 0.99),
    )
    check(
        'ramps, with lane and length: mean >= 97%',
        *at_least([('ramps', family_cell(fam, 'ramps'))], ll, 0.97),
    )
    sev = curve(fam, 'severity', 'work_zone')
    cells = [('work_zone', family_cell(fam, 'work_zone'))]
    cells += [(f'severity {p["x"]:g}', p) for p in (sev or {}).get('points', [])]
    check(
        'work zone, with lane and length: mean >= 95% at every severity (cell and curve)',
        *at_least(cells, ll, 0.95),
    )
    check(
        'work zone, time and speed only: mean >= 85% at every severity (cell and curve)',
        *at_least(cells, ts, 0.85),
    )
    for cv in fam.get('curves', []):
        drops, measured = [], 0
        for v in (ts, ll):
            pts = [(p['x'], _summary(p, v)) for p in cv['points']]
            for (x0, a), (x1, b) in zip(pts, pts[1:]):
                if a is None or b is None:
                    continue
                measured += 1
                d = a['accuracy_mean'] - b['accuracy_mean']
                if abs(d) > CLIFF:
                    drops.append(f'{v} {x0:g} -> {x1:g}: {100 * -d:+.1f} points')
        check(
            f'no cliff against {cv["parameter"]} on {cv["family"]} (no step > '
            f'{100 * CLIFF:.0f} points between neighbouring points, both variants)',
            None if not measured else not drops,
            '; '.join(drops) or f'{measured} steps compared',
        )
    return out
