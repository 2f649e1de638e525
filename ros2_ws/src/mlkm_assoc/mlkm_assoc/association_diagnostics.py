"""The association node's /diagnostics: the statistics of its published updates (solve
times, latencies, solver errors) and the status judged on a recent window of its inputs.

ROS-free apart from the status levels: the node feeds each published update to
:meth:`AssociationDiagnostics.published` from its publishing thread and asks for the values
and the level from the executor thread.
"""

from __future__ import annotations

import statistics
from collections import deque

from diagnostic_msgs.msg import DiagnosticStatus

from mlkm_assoc.assembly import REJECT_REASONS, Assembler, AssociationConfig
from mlkm_assoc.encoding import Update

#: Samples kept for the solve-time and latency statistics (the most recent ones) [-].
STATS_WINDOW = 1000
#: Refusals of inputs other than detections, counted with the detections' reasons.
MESSAGE_REASONS = ('invalid_layout', 'invalid_episode')


class AssociationDiagnostics:
    """Counts what the node published and turns it, with the assembler's counters, into the
    diagnostics values and their level."""

    def __init__(self, window: float, warn_fraction: float) -> None:
        #: The level judges the inputs of this recent period [s].
        self.window = window
        #: WARN above this fraction of rejected detections within ``window`` [-].
        self.warn_fraction = warn_fraction
        self._solve_times: deque[float] = deque(maxlen=STATS_WINDOW)
        # segment complete -> its tracks published [s]; of which waiting for the solver
        # (earlier segments) and neither waiting nor solving
        self._latencies: deque[float] = deque(maxlen=STATS_WINDOW)
        self._waits: deque[float] = deque(maxlen=STATS_WINDOW)
        self._overheads: deque[float] = deque(maxlen=STATS_WINDOW)
        self.solver_errors: int = 0
        self.last_error: str = ''
        # (monotonic time, received, rejected, solver errors) at each diagnostics publication,
        # the oldest one just before the diagnostics window
        self._history: deque[tuple[float, int, int, int]] = deque(maxlen=10_000)
        self.tracks_published: int = 0
        self.finals_published: int = 0

    def published(self, update: Update, latency: float) -> None:
        """Count one published update, ``latency`` [s] after its segment was complete."""
        self.tracks_published += 1
        if update.error:
            self.solver_errors += 1
            self.last_error = update.error
        if not update.final:
            self._solve_times.append(update.solve_time)
            if not update.forced:
                self._latencies.append(latency)
                wait = update.started_at - update.completed_at
                self._waits.append(wait)
                self._overheads.append(latency - wait - update.solve_time)
        else:
            self.finals_published += 1

    def values(
        self, config: AssociationConfig, a: Assembler, incompatible: int
    ) -> dict[str, object]:
        """The diagnostics values of the assembler ``a`` and of the published updates;
        ``incompatible``: the detection publishers whose QoS cannot match."""
        values: dict[str, object] = {
            'method': config.method,
            'segment_size': config.segment_size,
            'sensors': 0 if a.layout is None else a.layout.n_sensors,
            'received': a.received,
            'accepted': a.accepted,
            'rejected': sum(a.rejected.values()),
        }
        for reason in (*REJECT_REASONS, *MESSAGE_REASONS):
            values[f'rejected.{reason}'] = a.rejected.get(reason, 0)
        for reason, count in sorted(a.handled.items()):
            values[f'handled.{reason}'] = count
        values.update(a.buffer_sizes())
        values['segments_done'] = a.segments_done
        values['episodes_final'] = a.episodes_final
        values['episodes_unseen'] = a.episodes_unseen
        values['missing_detections'] = a.missing
        values['runs'] = a.runs
        values['episodes_remembered'] = a.remembered_episodes()
        values['track_updates_published'] = self.tracks_published
        values['episodes_published'] = self.finals_published
        values['solver_errors'] = self.solver_errors
        values['incompatible_publishers'] = incompatible
        values['solver_error_last'] = self.last_error
        solve = list(self._solve_times)
        values['solve_time_last'] = f'{solve[-1]:.6f}' if solve else ''
        values['solve_time_mean'] = f'{statistics.fmean(solve):.6f}' if solve else ''
        values['solve_time_max'] = f'{max(solve):.6f}' if solve else ''
        lat = list(self._latencies)
        _put_quantiles(values, 'latency', lat)
        values['latency_count'] = len(lat)
        _put_quantiles(values, 'queue_wait', list(self._waits))
        _put_quantiles(values, 'overhead', list(self._overheads))
        values['first_receive'] = '' if a.first_rx is None else f'{a.first_rx:.6f}'
        values['last_receive'] = '' if a.last_rx is None else f'{a.last_rx:.6f}'
        if a.first_rx is not None and a.last_rx is not None and a.last_rx > a.first_rx:
            values['ingest_rate'] = f'{(a.received - 1) / (a.last_rx - a.first_rx):.1f}'
        else:
            values['ingest_rate'] = ''
        return values

    def level(self, values: dict[str, object], now: float) -> tuple[int, str]:
        """(level, reason) judged on the last ``window`` seconds: ERROR after a solver
        error, WARN while stream mode commits without window solves (overloaded) or when too
        large a fraction of the detections was rejected."""
        sample = (now, int(values['received']), int(values['rejected']), self.solver_errors)
        history = self._history
        history.append(sample)
        while len(history) > 2 and history[1][0] <= now - self.window:
            history.popleft()
        t0, received0, rejected0, errors0 = history[0]
        if t0 > now - self.window:  # no sample before the window: since start-up
            received0 = rejected0 = errors0 = 0
        if self.solver_errors > errors0:
            return DiagnosticStatus.ERROR[0], f'solver error: {self.last_error}'
        if int(values.get('stream.tracker.overloaded', 0)):
            return (
                DiagnosticStatus.WARN[0],
                'stream: the window solves cannot keep up, links are committed as first made '
                f'({values["stream.tracker.skipped_solves"]} solves skipped, '
                f'{values["stream.tracker.forced_commits"]} detections committed so)',
            )
        received, rejected = sample[1] - received0, sample[2] - rejected0
        if rejected and rejected > self.warn_fraction * max(received, 1):
            return (
                DiagnosticStatus.WARN[0],
                f'{rejected} of {received} detections rejected in the last {self.window:g} s',
            )
        return DiagnosticStatus.OK[0], ''


def _put_quantiles(values: dict[str, object], name: str, samples: list[float]) -> None:
    """``<name>_p50`` and ``<name>_p95`` of ``samples`` ('' when there are none)."""
    for label, q in (('p50', 0.5), ('p95', 0.95)):
        values[f'{name}_{label}'] = f'{_quantile(samples, q):.6f}' if samples else ''


def _quantile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    pos = q * (len(ordered) - 1)
    lo = int(pos)
    hi = min(lo + 1, len(ordered) - 1)
    return ordered[lo] + (ordered[hi] - ordered[lo]) * (pos - lo)
