"""What every bench part shares: dataset seeds, scoring rows, summaries and the budgeted
child process that runs one method on a list of datasets."""

from __future__ import annotations

import multiprocessing as mp
import os
import time
from collections.abc import Callable
from dataclasses import asdict

import numpy as np

from mlkm_core.metrics import score
from mlkm_core.simulator import SimConfig
from mlkm_core.types import Dataset, Detections

CLUTTER = dict(miss_probability=0.05, false_alarm_rate=0.05, stamp_noise=0.2, velocity_noise=0.5)
MODES = ('paper', 'clutter')
BEST = 'multiframe'
BASELINE = 'assignment'
#: Name under which the Stone Soup tracker appears beside the registered methods.
PEER = 'stonesoup'
ONE_THREAD = {
    'OMP_NUM_THREADS': '1',
    'OPENBLAS_NUM_THREADS': '1',
    'MKL_NUM_THREADS': '1',
    'NUMEXPR_NUM_THREADS': '1',
    'VECLIB_MAXIMUM_THREADS': '1',
}

Log = Callable[[str], None]
#: Called in the child process; returns the job that scores dataset k (0, 1, ...).
JobFactory = Callable[[], Callable[[int], dict]]


def sim_config(mode: str, n_targets: int, n_sensors: int) -> SimConfig:
    extra = CLUTTER if mode == 'clutter' else {}
    return SimConfig(n_targets=n_targets, n_sensors=n_sensors, **extra)


def dataset_seed(n_targets: int, n_sensors: int, k: int) -> int:
    return 1000 * n_targets + 10 * n_sensors + k  # distinct per cell, same for every method


def score_row(ds: Dataset, labels: np.ndarray, seconds: float) -> dict:
    s = score(ds.detections, labels)
    row = asdict(s)
    row['seconds'] = seconds
    row['detections'] = len(ds.detections)
    return {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in row.items()}


def timed_row(ds: Dataset, associate: Callable[[Dataset], np.ndarray]) -> dict:
    """Score ``associate(ds)``, timing only the association."""
    t0 = time.perf_counter()
    labels = associate(ds)
    return score_row(ds, labels, time.perf_counter() - t0)


def summarise(rows: list[dict]) -> dict:
    if not rows:
        return {'n': 0}
    acc = np.array([r['accuracy'] for r in rows])
    return {
        'n': len(rows),
        'accuracy_mean': float(acc.mean()),
        'accuracy_min': float(acc.min()),
        'accuracy_max': float(acc.max()),
        'link_precision': float(np.mean([r['link_precision'] for r in rows])),
        'link_recall': float(np.mean([r['link_recall'] for r in rows])),
        'identity_switches': float(np.mean([r['identity_switches'] for r in rows])),
        'adjusted_rand_index': float(np.mean([r['adjusted_rand_index'] for r in rows])),
        'seconds_mean': float(np.mean([r['seconds'] for r in rows])),
        'detections_mean': float(np.mean([r['detections'] for r in rows])),
    }


def _child(make_job: JobFactory, n: int, conn) -> None:
    for k, v in ONE_THREAD.items():
        os.environ.setdefault(k, v)
    job = make_job()
    for k in range(n):
        conn.send(job(k))
    conn.send(None)
    conn.close()


def run_budgeted(make_job: JobFactory, n: int, budget: float) -> tuple[list[dict], str]:
    """Run ``make_job()(k)`` for k = 0 .. n-1 in a forked child process; stop the child
    when ``budget`` seconds are spent. Returns the rows it finished and a status."""
    ctx = mp.get_context('fork')
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(make_job, n, child))
    proc.start()
    child.close()
    rows: list[dict] = []
    status = 'ok'
    deadline = time.monotonic() + budget
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not parent.poll(left):
                status = (
                    f'stopped at the {budget:.0f} s time limit after {len(rows)} of {n} datasets'
                )
                break
            try:
                msg = parent.recv()
            except EOFError:
                status = f'crashed after {len(rows)} datasets (exit {proc.exitcode})'
                break
            if msg is None:
                break
            rows.append(msg)
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join()
    return rows, status


def pct(x: float | None) -> str:
    return '—' if x is None else f'{100 * x:.2f}'


def time_speed_only(ds: Dataset) -> Dataset:
    """``ds`` with (time, speed) only: lane and length stripped from its detections."""
    d = ds.detections
    return Dataset(
        ds.layout, Detections(d.sensor_index, d.stamp, d.velocity, d.target), ds.n_targets
    )


def stream_rows(d: Detections) -> list[tuple[int, int, float, float, int, float]]:
    """The arguments of a stream tracker's ``push`` for each detection of ``d``, in the order
    a stream delivers them (stamp, then station, then index): (key = index, station, stamp
    [s], speed [m/s], lane (-1 unknown), length [m] (NaN unknown))."""
    n = len(d)
    lane = d.lane if d.lane is not None else np.full(n, -1, np.int64)
    length = d.length if d.length is not None else np.full(n, np.nan)
    return [
        (i, int(d.sensor_index[i]), float(d.stamp[i]), float(d.velocity[i]), int(lane[i]),
         float(length[i]))
        for i in np.lexsort((np.arange(n), d.sensor_index, d.stamp)).tolist()
    ]  # fmt: skip
