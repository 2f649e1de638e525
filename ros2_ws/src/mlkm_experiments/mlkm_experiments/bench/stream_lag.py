"""Stream accuracy against the commit lag (offline, the core only): part of ``mlkm bench --only
stream``.

Each dataset is pushed into a ``StreamTracker`` (method ``multiframe``) detection by detection
in stamp order (ties by station, then index) and flushed at the end; the committed labels are
scored like the batch ``multiframe`` association of the same dataset. Datasets: the paper
simulator in clutter mode (50 targets on 20 sensors; its vehicles enter the road spread over
several minutes, as on an open road) and SUMO ``highway`` (200 vehicles on 20 stations, with
lane and length), cached like the ``sumo`` part's.
"""

from __future__ import annotations

import pickle
import time
from pathlib import Path

import numpy as np

from .common import BEST, CLUTTER, Log, stream_rows

LAGS = (5.0, 10.0, 15.0, 30.0, 60.0)
SIM_SEEDS = (0, 1, 2)
#: Wall-time budget per dataset family [s]: the datasets not started by then are left out.
BUDGET = 420.0
SUMO_SEEDS = (1, 2)
SUMO_CELL = ('highway', 200, 20)
#: Largest allowed accuracy loss of the stream at the default lag against batch [points].
LAG_LOSS_MAX = 0.5


def stream_labels(ds, lag: float, method: str = BEST, executor=None) -> np.ndarray:
    """Committed track of every detection of ``ds`` (-1 unassigned) after pushing it in stamp
    order into a stream tracker with commit lag ``lag`` [s] and flushing (``executor``: the
    tracker's, where its window solves run)."""
    from mlkm_core.streaming import StreamConfig, StreamTracker

    d = ds.detections
    tracker = StreamTracker(ds.layout, StreamConfig(method=method, lag=lag), executor=executor)
    n = len(d.stamp)
    labels = np.full(n, -1, np.int64)
    seen = np.zeros(n, bool)

    def take(update) -> None:
        for key, track in update.committed.tolist():
            labels[key], seen[key] = track, True

    for row in stream_rows(d):
        take(tracker.push(*row))
    take(tracker.flush())
    if not seen.all():
        raise RuntimeError(f'{int((~seen).sum())} detections were never committed')
    return labels


def _datasets(cache_dir: Path | None, sumo_seeds, sim_seeds, log: Log) -> dict[str, list]:
    from mlkm_core.simulator import SimConfig, simulate

    out = {'clutter': [simulate(SimConfig(**CLUTTER), s) for s in sim_seeds], 'sumo': []}
    if not sumo_seeds:
        return out
    from .sumo import DatasetCache

    root = cache_dir or Path('/tmp/mlkm_bench_stream_cache')
    cache = DatasetCache(root)
    for s in sumo_seeds:
        t0 = time.monotonic()
        path = cache.get(*SUMO_CELL, s)
        out['sumo'].append(pickle.loads(path.read_bytes()))
        log(f'stream lag: SUMO {SUMO_CELL} seed {s} ready in {time.monotonic() - t0:.0f} s')
    return out


def run_lag(
    log: Log,
    cache_dir: Path | None = None,
    lags=LAGS,
    sim_seeds=SIM_SEEDS,
    sumo_seeds=SUMO_SEEDS,
    default_lag: float | None = None,
    budget: float = BUDGET,
) -> dict:
    """Accuracy of batch and of the stream at each lag, per dataset family."""
    from mlkm_core.associators import make_associator
    from mlkm_core.metrics import accuracy
    from mlkm_core.streaming import StreamConfig

    default_lag = StreamConfig().lag if default_lag is None else default_lag
    lags = sorted(set(lags) | {default_lag})
    out: dict = {'method': BEST, 'default_lag': default_lag, 'lags': lags, 'families': {}}
    for family, sets in _datasets(cache_dir, sumo_seeds, sim_seeds, log).items():
        if not sets:
            continue
        batch, stream = [], {lag: [] for lag in lags}
        t0 = time.monotonic()
        done = 0
        for ds in sets:
            if time.monotonic() - t0 > budget:
                break
            done += 1
            d = ds.detections
            b = make_associator(BEST).associate(ds.layout, d, ds.n_targets)
            batch.append(accuracy(b, d.target).accuracy)
            for lag in lags:
                stream[lag].append(accuracy(stream_labels(ds, lag), d.target).accuracy)
        if not done:
            continue
        rec = {
            'datasets': done,
            'status': 'ok'
            if done == len(sets)
            else f'{done} of {len(sets)} datasets within the {budget:.0f} s budget',
            'detections_mean': float(np.mean([len(ds.detections.stamp) for ds in sets[:done]])),
            'batch': float(np.mean(batch)),
            'batch_runs': [float(x) for x in batch],
            'stream': {str(lag): float(np.mean(v)) for lag, v in stream.items()},
            'stream_runs': {str(lag): [float(x) for x in v] for lag, v in stream.items()},
            'seconds': time.monotonic() - t0,
        }
        rec.update(lag_verdict(rec['batch'], rec['stream'][str(default_lag)]))
        out['families'][family] = rec
        log(
            f'stream lag: {family} batch {100 * rec["batch"]:.2f} %, stream '
            + ', '.join(f'{k} s {100 * v:.2f}' for k, v in rec['stream'].items())
        )
    out['scenarios'] = {
        'clutter': f'paper simulator, 50 targets x 20 sensors, clutter, seeds {list(sim_seeds)}',
        'sumo': f'SUMO {SUMO_CELL[0]}, {SUMO_CELL[1]} vehicles x {SUMO_CELL[2]} stations, '
        f'seeds {list(sumo_seeds)}',
    }
    oks = [f['ok'] for f in out['families'].values()]
    out['ok'] = bool(oks) and all(oks)
    return out


def lag_verdict(batch: float, stream: float, limit: float = LAG_LOSS_MAX) -> dict:
    """Stream accuracy ``stream`` against ``batch`` (fractions): the loss in points and
    whether it is at most ``limit`` points."""
    loss = 100 * (batch - stream)
    return {'loss_points': loss, 'ok': bool(loss <= limit)}


def plot_lag(out_dir: Path, lag: dict) -> str | None:
    """``stream_lag.png``: stream accuracy against the lag, batch as a dashed line."""
    fams = lag.get('families') or {}
    if not fams:
        return None
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for (family, rec), color in zip(fams.items(), ('tab:blue', 'tab:orange'), strict=False):
        xs = [float(k) for k in rec['stream']]
        ax.plot(
            xs,
            [100 * v for v in rec['stream'].values()],
            'o-',
            color=color,
            label=f'{family}: stream',
        )
        ax.axhline(100 * rec['batch'], color=color, ls='--', lw=1, label=f'{family}: batch')
    ax.axvline(lag['default_lag'], color='grey', ls=':', lw=1)
    ax.set_xscale('log')
    ax.xaxis.set_minor_formatter(plt.NullFormatter())
    ax.set_xticks(lag['lags'])
    ax.set_xticklabels([f'{x:g}' for x in lag['lags']])
    ax.set_xlabel('commit lag [s of stamp time]')
    ax.set_ylabel('accuracy [%]')
    ax.set_title(f'Stream ({lag["method"]}) against batch; dotted: default lag')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out_dir / 'stream_lag.png', dpi=110)
    plt.close(fig)
    return 'stream_lag.png'
