"""The association node's stream mode: an open road without episodes.

Every detection is checked as in episodes mode (the physical bounds, a known sensor at its
position, a lane the station has, no duplicate; the same rejection reasons in
/diagnostics), numbered, and queued at once to the tracker process
(:mod:`mlkm_assoc.stream_worker`), which pushes it into the core's ``StreamTracker`` and
answers with the tracks it changed. A publisher thread publishes each answer on /mlkm/tracks
(TrackArray MODE_STREAM) and keeps the statistics, all in ring buffers.

Detections are checked and numbered by :class:`~mlkm_assoc.stream_ingest.StreamIngest`.
A road that falls quiet (no detection for ``quiet_flush`` seconds of wall time, by default
the ``lag``) is flushed: every link is committed and every track becomes FINAL. A new layout
flushes the old road too. Detections that arrive before the layout are held (up to
``max_buffered``) and checked once it is known.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from mlkm_assoc.stream_ingest import StreamIngest
from mlkm_assoc.stream_state import Answer, TrackerSettings
from mlkm_assoc.stream_worker import TrackerProcess
from mlkm_assoc.validation import NS_PER_S
from mlkm_core.bounds import Bounds
from mlkm_core.types import Layout

#: Samples kept for the latency and solve-time statistics (the most recent ones) [-].
STATS_WINDOW = 10_000
#: Longest time a thread of the node holds the GIL while another one waits for it [s].
SWITCH_INTERVAL = 0.001
#: Parts of a detection's latency: queued from the node to the tracker process, held in the
#: reorder buffer, in the tracker until its answer is sent, from then to the publication.
LATENCY_PARTS = ('queue', 'hold', 'tracker', 'publish')


@dataclass(frozen=True)
class StreamSettings:
    """Stream mode's settings: the tracker's and the node's own bound on held detections."""

    method: str  # associator of the tracker
    lag: float  # [s] stamp time a link stays revisable
    segment_size: int
    seed: int
    max_buffered: int  # detections held before the layout, or queued for the tracker [-]
    max_uncommitted: int = 0  # the tracker's backlog bound (StreamConfig), 0 = none [-]
    quiet_flush: float = 0.0  # [s] wall time without detections before a flush; 0 = the lag

    @property
    def quiet_after(self) -> float:
        """[s] of wall time a road stays quiet before it is flushed."""
        return self.quiet_flush if self.quiet_flush > 0 else self.lag

    def tracker(self) -> TrackerSettings:
        """The settings the tracker process builds its trackers from."""
        return TrackerSettings(**{f.name: getattr(self, f.name) for f in fields(TrackerSettings)})


class StreamMode:
    """Stream mode of one node: ingest, the tracker process, the publisher thread.

    ``publish(data)`` publishes a serialized TrackArray; ``log(level, text)`` logs."""

    def __init__(
        self,
        settings: StreamSettings,
        bounds: Bounds,
        publish: Callable[[bytes], None],
        log: Callable[[str, str], None],
        on_reject: Callable[[str, str], None] | None = None,
        publish_handoff: Callable[[bytes], None] | None = None,
    ) -> None:
        """``publish_handoff`` publishes a serialized TrackHandoff (a shard's)."""
        self.settings = settings
        self._publish_handoff = publish_handoff
        # the executor thread takes the GIL for every detection; the queue's feeder thread and
        # the publisher thread must get it within a millisecond, not the default 5 ms
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL))
        self._publish = publish
        self._log = log
        self.ready_after: float | None = None  # [s] from here to the tracker process ready
        self._process = TrackerProcess(
            settings.tracker(),
            max_queued=settings.max_buffered,
            on_ready=self._on_ready,
        )
        self.ingest = StreamIngest(bounds, settings.max_buffered, self._process.put, on_reject)
        self._lock = threading.Lock()
        self.latencies: deque[float] = deque(maxlen=STATS_WINDOW)  # arrival -> published [s]
        # the latency's parts [s]: queued to the tracker process, held by its reorder buffer,
        # in the tracker until the answer was sent, from then to its publication
        self.latency_parts: dict[str, deque[float]] = {
            part: deque(maxlen=STATS_WINDOW) for part in LATENCY_PARTS
        }
        self.solve_times: deque[float] = deque(maxlen=STATS_WINDOW)  # tracker per batch [s]
        self.last: Answer | None = None
        self.published = 0
        self.errors = 0
        self.last_error = ''
        self._flushed_at: float | None = None  # last_rx at the last flush
        self._thread = threading.Thread(target=self._work, name='stream_publisher', daemon=True)
        self._thread.start()

    # --- inputs (executor thread) ---------------------------------------------------------
    def set_layout(self, layout: Layout, lane_counts, entries, exits, shard=None) -> None:
        self.ingest.set_layout(layout, lane_counts, entries, exits, shard)
        self._log('info', f'stream mode: {layout.n_sensors} sensors, lag {self.settings.lag:g} s')

    def add(self, *args) -> None:
        self.ingest.add(*args)

    def handoff(self, offers: list, upstream_until: float) -> None:
        """Offers of the upstream shard [(track id, detection join key)] and its commit time
        [s], for the tracker process (never refused)."""
        self._process.put(('handoff', offers, upstream_until))

    def wait_ready(self, timeout: float) -> bool:
        """Wait until the tracker process has warmed up (its imports, the first solve); False
        if it did not within ``timeout`` seconds."""
        return self._process.wait_ready(timeout)

    def _on_ready(self, seconds: float) -> None:
        self.ready_after = seconds
        how = 'forked at start-up' if self._process.forked else 'spawned'
        self._log('info', f'stream mode: tracker ready after {seconds:.2f} s ({how})')

    def clock(self, now: float) -> None:
        """The node's clock for the reorder buffer while no detection arrives (called by a
        fast timer of the node's executor: a stalled executor stops it too)."""
        self._process.put(('tick', now))

    def tick(self, now: float) -> None:
        """Flush a road that has been quiet for ``quiet_after`` seconds of wall time."""
        last = self.ingest.last_rx
        if last is None or last == self._flushed_at or now - last < self.settings.quiet_after:
            return
        self.flush(now)

    def flush(self, now: float) -> None:
        self._flushed_at = self.ingest.last_rx
        self._process.put(('flush', now))

    # --- answers (publisher thread) -------------------------------------------------------
    def _work(self) -> None:
        while True:
            answer = self._process.get()
            if answer is None:
                return
            try:
                self._apply(answer)
            except Exception as exc:  # noqa: BLE001 - shutting down, or a broken context
                self._log('error', f'publishing stream tracks failed: {exc}')

    def _apply(self, answer: Answer) -> None:
        if answer.data is not None:
            self._publish(answer.data)
            self.published += 1
        if answer.handoff is not None and self._publish_handoff is not None:
            self._publish_handoff(answer.handoff)
        now = time.monotonic()
        with self._lock:
            self.latencies.extend(now - t for t in answer.received_at)
            if answer.released_at and len(answer.dequeued_at) == len(answer.received_at):
                parts = self.latency_parts
                sent = answer.sent_at
                for rx, deq, rel in zip(
                    answer.received_at, answer.dequeued_at, answer.released_at, strict=True
                ):
                    parts['queue'].append(deq - rx)
                    parts['hold'].append(rel - deq)
                    parts['tracker'].append(sent - rel)
                    parts['publish'].append(now - sent)
            if answer.received_at:
                self.solve_times.append(answer.solve_time)
            self.last = answer
        if math.isfinite(answer.committed_until):
            self.ingest.committed(int(answer.committed_until * NS_PER_S))
        if answer.error:
            self.errors += 1
            self.last_error = answer.error
            self._log('error', answer.error)
        if answer.flushed:
            self._log(
                'info',
                f'quiet road flushed: {answer.stats.get("tracks_final", 0)} tracks final so far, '
                f'{answer.working_set} detections in the working set',
            )

    # --- diagnostics ----------------------------------------------------------------------
    def diagnostics(self) -> dict[str, object]:
        """Stream values for /diagnostics (counts of the ingest are merged by the node)."""
        with self._lock:
            lat = np.fromiter(self.latencies, float, len(self.latencies))
            parts = {part: np.fromiter(v, float, len(v)) for part, v in self.latency_parts.items()}
            solve = list(self.solve_times)
            last = self.last
        values: dict[str, object] = {
            'stream.lag': self.settings.lag,
            'stream.quiet_flush': self.settings.quiet_after,
            'stream.method': self.settings.method,
            'stream.held_before_layout': self.ingest.held,
            'stream.tracker_ready': self._process.ready,
            'stream.tracker_ready_after': (
                '' if self.ready_after is None else f'{self.ready_after:.3f}'
            ),
            'stream.queued_for_tracker': self._process.queued,
            'stream.track_updates_published': self.published,
            'stream.errors': self.errors,
            'stream.error_last': self.last_error,
        }
        if last is not None:
            values['stream.working_set'] = last.working_set
            values['stream.detections_held'] = last.held
            for key in ('tracks_confirmed', 'tracks_final', 'links_revised', 'pushed'):
                values[f'stream.{key}'] = last.stats.get(key, 0)
            for key, value in sorted(last.stats.items()):
                if key.startswith(('tracker.', 'reorder_', 'handoff_')):
                    values[f'stream.{key}'] = value
            if math.isfinite(last.committed_until):
                values['stream.committed_until'] = f'{last.committed_until:.6f}'
                values['stream.commit_lag'] = f'{last.newest_stamp - last.committed_until:.6f}'
        values['stream.latency_count'] = lat.size
        for q, x in zip((0.5, 0.95, 0.99, 1.0), _quantiles(lat, (0.5, 0.95, 0.99, 1.0))):
            name = 'max' if q == 1.0 else f'p{round(q * 100)}'
            values[f'stream.latency_{name}'] = x
        for part, v in parts.items():
            for q, x in zip((0.5, 0.95), _quantiles(v, (0.5, 0.95))):
                values[f'stream.latency_{part}_p{round(q * 100)}'] = x
        values['stream.solve_time_mean'] = f'{sum(solve) / len(solve):.6f}' if solve else ''
        values['stream.solve_time_max'] = f'{max(solve):.6f}' if solve else ''
        return values

    def close(self) -> None:
        self._process.close()
        if self._thread.is_alive():
            self._thread.join(timeout=10.0)


def _quantiles(values: np.ndarray, qs: tuple[float, ...]) -> list[str]:
    """The quantiles (linear interpolation) as diagnostics strings; '' for no values."""
    if not values.size:
        return [''] * len(qs)
    return [f'{x:.6f}' for x in np.quantile(values, qs)]
