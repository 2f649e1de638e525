"""Running an associator over a CSV's detections for ``mlkm associate``: batch or stream.

``run_batch`` calls the method once on every valid detection (segment by segment where the
method has a session, to show progress). ``run_stream`` pushes the detections in stamp order
through ``mlkm_core.streaming.StreamTracker`` (key = the data row number), flushes at the end
and returns the committed labels with what the stream measured (revision rate, commit
latency in stamp time).
"""

from __future__ import annotations

import sys
import threading
from dataclasses import dataclass

import numpy as np

from mlkm_core.csvio import CsvDetections


class Progress:
    """tqdm bars on stderr, or nothing (no TTY and no --progress)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled

    def bar(self, desc: str, total: float | None = None, unit: str = 'it', scale: bool = False):
        if not self.enabled:
            return None
        from tqdm import tqdm

        return tqdm(
            total=total,
            bar_format=None if total is not None else '{desc}: {elapsed} elapsed',
            desc=desc,
            unit=unit,
            unit_scale=scale,
            file=sys.stderr,
            dynamic_ncols=True,
            leave=False,
        )


def absolute(bar):
    """progress(n) callback setting an absolute position on ``bar``."""
    if bar is None:
        return None

    def update(n: int) -> None:
        bar.update(n - bar.n)

    return update


def run_batch(associator, data: CsvDetections, n_targets: int, progress: Progress):
    """Labels of the valid detections, with a per-segment bar where the method supports it."""
    from mlkm_core.associators import Associator

    layout, dets = data.layout, data.detections
    incremental = type(associator).session is not Associator.session
    if progress.enabled and incremental:
        from mlkm_core.types import segments

        segs = list(segments(layout.n_sensors, associator.config.segment_size))
        bar = progress.bar(f'associating ({associator.name})', total=len(segs), unit='segment')
        session = associator.session(layout, n_targets)
        order, labels = [], np.zeros(0, np.int64)
        for seg in segs:
            idx = np.flatnonzero(np.isin(dets.sensor_index, seg))
            order.append(idx)
            labels = session.add_segment(dets.subset(idx))
            bar.update()
        bar.close()
        out = np.full(len(dets), -1, np.int64)
        out[np.concatenate(order)] = labels
        return out
    bar = progress.bar(f'associating ({associator.name})', unit='s')
    if bar is None:
        return associator.associate(layout, dets, n_targets)
    done = threading.Event()

    def tick() -> None:  # the method reports nothing: show the elapsed time
        while not done.wait(1.0):
            bar.refresh()

    ticker = threading.Thread(target=tick, daemon=True)
    ticker.start()
    try:
        return associator.associate(layout, dets, n_targets)
    finally:
        done.set()
        ticker.join()
        bar.close()


@dataclass(frozen=True)
class StreamResult:
    labels: np.ndarray  # committed track of each valid detection, -1 = unassigned
    stats: dict  # the tracker's counters (StreamTracker.stats())
    # [s] newest stamp at each detection's commit minus its stamp; NaN if the final flush
    # committed it
    latency: np.ndarray


def run_stream(
    data: CsvDetections,
    config,
    entries: tuple[float, ...] = (),
    exits: tuple[float, ...] = (),
    progress: Progress | None = None,
) -> StreamResult:
    """Push the valid detections in stamp order (ties by station, then row) and flush."""
    from mlkm_core.streaming import StreamTracker

    d = data.detections
    tracker = StreamTracker(data.layout, config, entries, exits)
    row_of = np.flatnonzero(data.row_detection >= 0)  # detection -> data row (the key)
    det_of = {int(r): i for i, r in enumerate(row_of)}
    order = np.lexsort((row_of, d.sensor_index, d.stamp))
    lane = d.lane if d.lane is not None else np.full(len(d), -1, np.int64)
    length = d.length if d.length is not None else np.full(len(d), np.nan)
    labels = np.full(len(d), -1, np.int64)
    latency = np.zeros(len(d))
    seen = np.zeros(len(d), bool)
    bar = progress.bar('streaming', total=len(d), unit='det', scale=True) if progress else None

    def take(update, newest: float) -> None:
        for key, track in update.committed.tolist():
            i = det_of[key]
            labels[i], latency[i], seen[i] = track, newest - d.stamp[i], True

    newest = -np.inf
    for n, i in enumerate(order.tolist()):
        newest = max(newest, float(d.stamp[i]))
        update = tracker.push(
            int(row_of[i]),
            int(d.sensor_index[i]),
            float(d.stamp[i]),
            float(d.velocity[i]),
            int(lane[i]),
            float(length[i]),
        )
        take(update, newest)
        if bar is not None and n % 1024 == 0:
            bar.update(n - bar.n)
    take(tracker.flush(), np.nan)
    if bar is not None:
        bar.close()
    if not seen.all():
        raise RuntimeError(f'{int((~seen).sum())} detections were never committed')
    return StreamResult(labels, tracker.stats(), latency)
