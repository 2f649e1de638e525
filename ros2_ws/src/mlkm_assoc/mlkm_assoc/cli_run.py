"""Running an associator over a CSV's detections for ``mlkm associate``: batch or stream.

``run_batch`` calls the method once on every valid detection (segment by segment where the
method has a session, to show progress). With ``--progress`` a method without a session
reports the fraction it has done through ``mlkm_core.progress``; the bar shows it with the
time left at the average pace so far (only the elapsed time for a method that reports
nothing: the K-means baselines and the DNN). ``run_stream`` pushes the detections in stamp order
through ``mlkm_core.streaming.StreamTracker`` (key = the data row number), flushes at the end
and returns the committed labels with what the stream measured (revision rate, commit
latency in stamp time).
"""

from __future__ import annotations

import sys
import threading
import time
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
    if not progress.enabled:
        return associator.associate(layout, dets, n_targets)
    from mlkm_core.progress import reporting

    bar = FractionBar(f'associating ({associator.name})')
    done = threading.Event()

    def tick() -> None:  # the elapsed time moves between the method's reports
        while not done.wait(1.0):
            bar.show()

    ticker = threading.Thread(target=tick, daemon=True)
    ticker.start()
    try:
        with reporting(bar.update):
            return associator.associate(layout, dets, n_targets)
    finally:
        done.set()
        ticker.join()
        bar.close()


def clock(seconds: float) -> str:
    """``mm:ss``, or ``h:mm:ss`` from an hour on."""
    s = max(int(round(seconds)), 0)
    h, m = divmod(s, 3600)
    m, s = divmod(m, 60)
    return f'{h}:{m:02d}:{s:02d}' if h else f'{m:02d}:{s:02d}'


def remaining(fraction: float, elapsed: float) -> float | None:
    """Seconds left if the rest goes at the average pace so far [s]; None before any
    progress (nothing to extrapolate from)."""
    if fraction <= 0:
        return None
    return elapsed * (1.0 - min(fraction, 1.0)) / fraction


def fraction_line(desc: str, fraction: float | None, elapsed: float, width: int = 20) -> str:
    """One line of a bar: the fraction done, the elapsed time and the time left; only the
    elapsed time while the method has reported nothing (``fraction`` None or 0)."""
    if not fraction:
        return f'{desc}: {clock(elapsed)} elapsed'
    fraction = min(fraction, 1.0)
    filled = int(fraction * width)
    left = remaining(fraction, elapsed)
    return (
        f'{desc}: {100 * fraction:3.0f}%|{"#" * filled}{" " * (width - filled)}| '
        f'{clock(elapsed)} elapsed, {clock(left)} left'
    )


class FractionBar:
    """A bar on stderr driven by the fraction done (``mlkm_core.progress``), redrawn in place;
    ``now`` (the clock) and ``file`` are there for the tests."""

    def __init__(self, desc: str, file=None, now=time.monotonic) -> None:
        self.desc = desc
        self.file = file or sys.stderr
        self.now = now
        self.start = now()
        self.fraction = 0.0
        self.width = 0  # of the last line drawn, to clear it
        self._lock = threading.Lock()
        self.show()

    def update(self, fraction: float) -> None:
        self.fraction = fraction
        self.show()

    def show(self) -> None:
        with self._lock:
            line = fraction_line(self.desc, self.fraction, self.now() - self.start)
            self.file.write('\r' + line.ljust(self.width))
            self.file.flush()
            self.width = len(line)

    def close(self) -> None:
        with self._lock:  # leave no bar behind, as the tqdm bars (leave=False)
            self.file.write('\r' + ' ' * self.width + '\r')
            self.file.flush()


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
    network=None,
) -> StreamResult:
    """Push the valid detections in stamp order (ties by station, then row) and flush; on a
    road network (``network``, ``config`` a ``NetworkStreamConfig``) through its stream."""
    from mlkm_core.network_assoc.stream import NetworkStreamTracker
    from mlkm_core.streaming import StreamTracker

    d = data.detections
    if network is not None:
        tracker = NetworkStreamTracker(network, config)
    else:
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
