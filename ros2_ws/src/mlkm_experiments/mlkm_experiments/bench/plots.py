"""PNG plots of the accuracy grid and the cost growth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .common import MODES
from .cost import COST_LIMIT


def plot_all(out_dir: Path, grid: dict, cost: dict) -> list[str]:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    files = []
    for mode in MODES:
        cells = [c for c in grid.get('cells', []) if c['mode'] == mode]
        if not cells:
            continue
        methods = list(cells[0]['methods'])
        fig, ax = plt.subplots(figsize=(11, 4.5))
        width = 0.8 / max(len(methods), 1)
        for i, m in enumerate(methods):
            xs, mean, err_lo, err_hi = [], [], [], []
            for j, c in enumerate(cells):
                s = c['methods'][m]['summary']
                if s['n'] == 0:
                    continue
                xs.append(j + (i - len(methods) / 2 + 0.5) * width)
                mean.append(100 * s['accuracy_mean'])
                err_lo.append(100 * (s['accuracy_mean'] - s['accuracy_min']))
                err_hi.append(100 * (s['accuracy_max'] - s['accuracy_mean']))
            ax.bar(xs, mean, width, yerr=[err_lo, err_hi], capsize=2, label=m)
        ax.set_xticks(range(len(cells)))
        ax.set_xticklabels([f'{c["targets"]} targets / {c["sensors"]} sensors' for c in cells])
        ax.set_ylabel('accuracy [%] (bar: mean, whiskers: min..max)')
        ax.set_ylim(0, 101)
        ax.set_title(f'Accuracy grid, {mode} mode (missing bar: stopped at the time limit)')
        ax.legend(fontsize=7, ncol=5, loc='lower left')
        fig.tight_layout()
        name = f'grid_{mode}.png'
        fig.savefig(out_dir / name, dpi=110)
        plt.close(fig)
        files.append(name)
    if not cost.get('methods'):
        return files
    for key, label, fname in (
        ('seconds', 'runtime [s]', 'cost_runtime.png'),
        ('peak_bytes', 'peak memory above start [MiB]', 'cost_memory.png'),
    ):
        fig, ax = plt.subplots(figsize=(8, 5.5))
        for m, rec in cost.get('methods', {}).items():
            pts = rec['points']
            if not pts:
                continue
            x = [p['detections'] for p in pts]
            y = [p[key] / (2**20 if key == 'peak_bytes' else 1) for p in pts]
            slope = rec['time_slope' if key == 'seconds' else 'memory_slope']
            tag = f'{m} (slope {slope:.2f})' if slope is not None else m
            if rec['stopped']:
                tag += ' [stopped at limit]'
            ax.loglog(x, np.maximum(y, 1e-3), 'o-', label=tag)
        if key == 'seconds':
            ax.axhline(cost.get('time_limit_s', COST_LIMIT), color='grey', ls=':', lw=1)
            ax.text(1000, cost.get('time_limit_s', COST_LIMIT) * 1.1, 'time limit', fontsize=8)
        ax.set_xlabel('detections (20 sensors, more targets)')
        ax.set_ylabel(label)
        ax.set_title(f'Cost growth, one core: {label}')
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out_dir / fname, dpi=110)
        plt.close(fig)
        files.append(fname)
    return files


def plot_stream(out_dir: Path, stream: dict) -> list[str]:
    """``stream_lag.png`` (accuracy against the commit lag) and ``stream_rss.png`` (resident
    set of the association node and its tracker process over simulated time)."""
    from .stream_lag import plot_lag
    from .stream_memory import tracker_progress

    files = [f for f in [plot_lag(out_dir, stream.get('lag', {}))] if f]
    mem = stream.get('memory', {})
    pts = [s for s in mem.get('samples', []) if s['node']]
    prog = tracker_progress(pts)
    if prog is None:
        return files
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    x = [mem['duration'] / 60 * p for p in prog]
    fig, ax = plt.subplots(figsize=(8, 4.5))
    node = [s['node'] / 2**20 for s in pts]
    trk = [(s['tracker'] or 0) / 2**20 for s in pts]
    ax.plot(x, node, '-', lw=1, label='association_node')
    ax.plot(x, trk, '-', lw=1, label='its tracker process')
    ax.plot(x, [a + b for a, b in zip(node, trk, strict=True)], '-', lw=1.5, label='sum')
    for f in (1 / 6, 2 / 6, 5 / 6):
        ax.axvline(f * mem['duration'] / 60, color='grey', ls=':', lw=1)
    ax.set_xlabel("simulated time [min] (the tracker's committed stamp time)")
    ax.set_ylabel('resident set [MiB]')
    ax.set_ylim(bottom=0)
    ax.set_title(f'Stream mode memory: {mem.get("scenario", "")}', fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out_dir / 'stream_rss.png', dpi=110)
    plt.close(fig)
    return [*files, 'stream_rss.png']


def plot_sumo_curves(out_dir: Path, sumo: dict) -> list[str]:
    """``sumo_curve_<parameter>_<family>.png`` per curve of the SUMO families: mean accuracy
    (min..max whiskers) of each method against the curve's parameter, both variants."""
    curves = (sumo.get('families') or {}).get('curves', [])
    if not curves:
        return []
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    files = []
    for cv in curves:
        pts = [p for p in cv['points'] if 'error' not in p]
        if not pts:
            continue
        fig, ax = plt.subplots(figsize=(8, 4.8))
        methods = list(pts[0]['variants']['time_speed'])
        for i, m in enumerate(methods):
            for v, style in (('lane_length', '-'), ('time_speed', '--')):
                xs, mean, lo, hi = [], [], [], []
                for p in pts:
                    rec = p['variants'][v].get(m)
                    s = rec['summary'] if rec else {'n': 0}
                    if s['n'] == 0:
                        continue
                    xs.append(p['x'])
                    mean.append(100 * s['accuracy_mean'])
                    lo.append(100 * (s['accuracy_mean'] - s['accuracy_min']))
                    hi.append(100 * (s['accuracy_max'] - s['accuracy_mean']))
                if xs:
                    label = f'{m} ({"+ lane, length" if v == "lane_length" else "time, speed"})'
                    ax.errorbar(
                        xs, mean, yerr=[lo, hi], fmt=style + 'o', color=f'C{i}', capsize=2,
                        ms=3, lw=1.2, label=label,
                    )  # fmt: skip
        if cv['parameter'] == 'spacing':
            ax.set_xscale('log')
            ax.set_xlabel('station spacing [m]')
        else:
            ax.set_xlabel('severity (demand / capacity of the bottleneck)')
        ax.set_xticks([p['x'] for p in pts])
        ax.set_xticklabels([f'{p["x"]:g}' for p in pts])
        ax.set_ylabel('accuracy [%] (mean, whiskers min..max over seeds)')
        ax.set_title(f'SUMO family {cv["family"]}: accuracy against {cv["parameter"]}')
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        fig.tight_layout()
        name = f'sumo_curve_{cv["parameter"]}_{cv["family"]}.png'
        fig.savefig(out_dir / name, dpi=110)
        plt.close(fig)
        files.append(name)
    return files
