"""``README.md`` of the bench results: every table, from the JSON files of the parts."""

from __future__ import annotations

import json
from pathlib import Path

from .common import BEST, MODES, pct
from .grid import grid_cell
from .network import report_lines as network_report
from .network_long import long_lines
from .plots import plot_sumo_curves
from .real import report_lines as real_report
from .shards import report_lines as shards_report
from .soak import report_lines as soak_report
from .stream_report import report_lines as stream_report
from .sumo import report_lines as sumo_report
from .sumo_families_report import report_lines as sumo_families_report


def write_readme(out_dir: Path, parts: dict[str, dict], targets: list[dict], meta: dict) -> None:
    """``<out_dir>/README.md`` from the parts' results (``grid``, ``cost``, ``peer``,
    ``live``, ``sumo``, ``soak``; an empty dict for a part never run)."""
    grid, cost, peer, live = (parts.get(k, {}) for k in ('grid', 'cost', 'peer', 'live'))
    L = [
        '# Benchmarks (`make bench`)',
        '',
        f'Written by `mlkm bench --output {meta["out"]}` on {meta["date"]} from the JSON files '
        'of its parts next to this README; every figure below comes from them. A part run '
        'alone (`--only <part>`) replaces only its own file; `--report-only` rewrites this '
        'README, `summary.json` and the plots without running anything. Each part was last '
        'run on a shared 2-core machine: '
        + '; '.join(
            f'{name} {d["wall_s"] / 60:.1f} min ({d.get("date", "?")}'
            f'{", smoke version (--quick)" if d.get("quick") else ""})'
            for name, d in parts.items()
            if d.get('wall_s') is not None
        )
        + '. Regenerate everything with `make bench`.',
        '',
        '## Targets',
        '',
        '| target | met | value |',
        '| --- | --- | --- |',
    ]
    for t in targets:
        met = {True: 'yes', False: '**no**', None: 'n/a'}[t['met']]
        L.append(f'| {t["target"]} | {met} | {t["value"]} |')
    L += [
        '',
        '## Accuracy grid',
        '',
        'Mean accuracy [%] (min..max) over seeded datasets; the same datasets for every '
        'method. Clutter mode: 5% misses, 0.05 false alarms per target per sensor, 0.2 s '
        'stamp noise, 0.5 m/s speed noise. Time budget per (method, cell, mode): '
        + ', '.join(f'{k}: {v:.0f} s' for k, v in grid.get('budget_s', {}).items())
        + '; a method over budget is stopped and marked.',
        '',
    ]
    for mode in MODES:
        cells = [c for c in grid.get('cells', []) if c['mode'] == mode]
        if not cells:
            continue
        L.append(f'### {mode} mode')
        L.append('')
        head = (
            '| method | '
            + ' | '.join(f'{c["targets"]}/{c["sensors"]} (n={len(c["seeds"])})' for c in cells)
            + ' |'
        )
        L += [head, '|' + ' --- |' * (len(cells) + 1)]
        for m in cells[0]['methods']:
            row = [m]
            for c in cells:
                s = c['methods'][m]['summary']
                if s['n'] == 0:
                    row.append('stopped (time limit)')
                    continue
                txt = (
                    f'{pct(s["accuracy_mean"])} ({pct(s["accuracy_min"])}..'
                    f'{pct(s["accuracy_max"])}) {s["seconds_mean"]:.2f} s'
                )
                if c['methods'][m]['status'] != 'ok':
                    txt += f' [{s["n"]} of {len(c["seeds"])}: time limit]'
                row.append(txt)
            L.append('| ' + ' | '.join(row) + ' |')
        L.append('')
        L.append(f'Link precision / recall, identity switches, ARI ({mode}, 50/20):')
        L.append('')
        c = grid_cell(grid, 50, 20, mode)
        if c:
            L += [
                '| method | link precision | link recall | identity switches | ARI |',
                '| --- | --- | --- | --- | --- |',
            ]
            for m, r in c['methods'].items():
                s = r['summary']
                if s['n']:
                    L.append(
                        f'| {m} | {s["link_precision"]:.4f} | {s["link_recall"]:.4f} | '
                        f'{s["identity_switches"]:.2f} | {s["adjusted_rand_index"]:.4f} |'
                    )
        L.append('')
        L.append(f'![grid {mode}](grid_{mode}.png)')
        L.append('')
    L += [
        '## Cost growth (20 sensors, one core)',
        '',
        f'Fresh process per point, one thread; limit {cost.get("time_limit_s", 0):.0f} s per '
        'point. Slope: least-squares fit of log(runtime) on log(detections) over the points '
        'with >= 3000 detections.',
        '',
        '| method | detections reached | runtime at largest [s] | time slope | '
        'memory slope | peak memory at largest [MiB] | note |',
        '| --- | --- | --- | --- | --- | --- | --- |',
    ]
    for m, rec in cost.get('methods', {}).items():
        pts = rec['points']
        if pts:
            p = pts[-1]
            ts = '—' if rec['time_slope'] is None else f'{rec["time_slope"]:.2f}'
            ms = '—' if rec['memory_slope'] is None else f'{rec["memory_slope"]:.2f}'
            L.append(
                f'| {m} | {p["detections"]} | {p["seconds"]:.2f} | {ts} | {ms} | '
                f'{p["peak_bytes"] / 2**20:.1f} | {rec["stopped"] or ""} |'
            )
        else:
            L.append(f'| {m} | — | — | — | — | — | {rec["stopped"] or ""} |')
    L += [
        '',
        '![runtime](cost_runtime.png)',
        '',
        '![memory](cost_memory.png)',
        '',
        '## Stone Soup side by side',
        '',
    ]
    if peer.get('cells'):
        L += [
            f'Stone Soup {peer.get("stonesoup_version", "")}, set up in '
            '`mlkm_experiments.bench.peer.stonesoup_associate` (1-D constant velocity, '
            'measurement of position and speed, Mahalanobis-gated `GNNWith2DAssignment`, '
            '`MultiMeasurementInitiator`, `UpdateTimeDeleter`, told the stamp and speed '
            f'noise); config `{json.dumps(peer["config"])}`. Same datasets (the first ones '
            'of each grid cell), same run.',
            '',
            f'| cell | mode | n | Stone Soup accuracy | {BEST} accuracy | Stone Soup s / 1000 '
            f'det | speedup of {BEST} |',
            '| --- | --- | --- | --- | --- | --- | --- |',
        ]
        for c in peer['cells']:
            L.append(
                f'| {c["targets"]}/{c["sensors"]} | {c["mode"]} | {c["n"]} | '
                f'{pct(c["stonesoup"]["accuracy_mean"])} | '
                f'{pct(c[BEST]["accuracy_mean"])} | '
                f'{c["stonesoup_s_per_1000_det"]:.2f} | {c["speedup"]:.0f}x |'
            )
    else:
        L.append(peer.get('error', 'not run'))
    L += ['', '## Live throughput', '']
    a = live.get('association_node')
    if a:
        sc = live.get('scenario', {})
        L += [
            f'`mlkm bench --only live` (details: [live.md](live.md)): `sensor_sim` at '
            f'real_time_factor 0, {sc.get("targets")} targets x {sc.get("sensors")} sensors, '
            f'{sc.get("episodes")} episodes, method `{sc.get("method")}`; medians of '
            f'{sc.get("repeats")} interleaved runs.',
            '',
            '| figure | value |',
            '| --- | --- |',
            f'| bare rclpy subscriber ingest [msg/s] | {live["bare_subscriber"]["ingest_rate"]} |',
            f'| association node ingest [msg/s] | {a["ingest_rate"]} |',
            f'| ratio (target >= 0.70) | {live.get("ingest_ratio")} |',
            f'| latency p50, segment complete -> tracks [ms] | {1000 * a["latency_p50"]:.1f} |',
            f'| latency p95 (target <= 100 ms) [ms] | {1000 * a["latency_p95"]:.1f} |',
            f'| nothing lost | {live.get("nothing_lost")} |',
        ]
    else:
        L.append(str(live.get('status', 'not run')))
    L.append('')
    L += real_report(parts.get('real', {}))
    L += sumo_report(parts.get('sumo', {}))
    sumo = parts.get('sumo', {})
    L += sumo_families_report(sumo, plot_sumo_curves(out_dir, sumo))
    L += network_report(parts.get('network', {}))
    L += long_lines(parts.get('network', {}).get('long'))
    L += soak_report(parts.get('soak', {}))
    L += stream_report(parts.get('stream', {}))
    L += shards_report(parts.get('shards', {}))
    (out_dir / 'README.md').write_text('\n'.join(L) + '\n')
