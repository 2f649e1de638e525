"""The network stream's detection-to-track latency, as a live source would drive it.

The detections are pushed at their stamps, ``speedup`` times faster than real time, into a
``NetworkStreamTracker`` whose window solves run in a second process (a
``ProcessPoolExecutor`` of one worker, as the live node's solver process). Between two
detections the caller polls every ``POLL_PERIOD`` while a solve is in flight, as the node's
stream worker does. A detection's latency runs from the moment it is due (its stamp, scaled)
to the return of its push, when it is in a track: it includes the wait behind a poll that
applies a solve, and the push's own immediate link.
"""

from __future__ import annotations

import time
from concurrent.futures import ProcessPoolExecutor
from types import SimpleNamespace

import numpy as np

from .common import score_row, stream_rows

#: [s] between two polls while a window solve is in flight (the node's stream worker: 2 ms)
POLL_PERIOD = 0.002


def paced_stream(net, d, speedup: float) -> dict:
    """Latency percentiles [ms], the committed accuracy and the run's wall time [s]."""
    import multiprocessing

    from mlkm_core.network_assoc.stream import NetworkStreamTracker

    ctx = multiprocessing.get_context('spawn')
    with ProcessPoolExecutor(1, mp_context=ctx) as pool:
        pool.submit(int, 0).result()  # the worker is up before the clock starts
        tracker = NetworkStreamTracker(net, executor=pool)
        labels = np.full(len(d), -1, np.int64)

        def take(update) -> None:
            for key, track in update.committed.tolist():
                labels[key] = track

        rows = stream_rows(d)
        latency = np.zeros(len(rows))
        start, first = time.perf_counter(), rows[0][2]
        for n, row in enumerate(rows):
            due = start + (row[2] - first) / speedup
            while (now := time.perf_counter()) < due:
                if tracker.solving:
                    take(tracker.poll())
                    time.sleep(max(0.0, min(POLL_PERIOD, due - time.perf_counter())))
                else:
                    time.sleep(due - now)
            take(tracker.push(*row))
            latency[n] = time.perf_counter() - due
        take(tracker.flush())
        wall = time.perf_counter() - start
    ms = 1000 * latency
    stats = tracker.stats()
    return {
        'speedup': speedup,
        'latency_ms_p50': float(np.percentile(ms, 50)),
        'latency_ms_p95': float(np.percentile(ms, 95)),
        'latency_ms_p99': float(np.percentile(ms, 99)),
        'latency_ms_max': float(ms.max()),
        'seconds': wall,
        'stamp_span': float(d.stamp.max() - d.stamp.min()),
        'solves': stats['solves'],
        'revision_rate': stats['revision_rate'],
        'accuracy': score_row(SimpleNamespace(detections=d), labels, 0.0)['accuracy'],
    }
