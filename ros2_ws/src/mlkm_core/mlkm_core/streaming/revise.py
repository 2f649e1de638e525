"""Applying a window's solution to the tracks, commits and the ends of tracks
(``mlkm_core.streaming``, steps 3 to 5)."""

from __future__ import annotations

import bisect
from collections import Counter

import numpy as np

from mlkm_core.streaming.book import Det, TrackBook, canon


class Revisions(TrackBook):
    """The tracker's changes at a solved boundary; ``StreamTracker`` provides ``layout``,
    ``config``, ``_params``, ``_before_exit``, ``_stats``, ``_history``, ``_context`` and
    ``_ended``."""

    def _apply(self, window: list[Det], own: np.ndarray, groups: list[np.ndarray]) -> None:
        """Move the window's detections to the tracks of the solve."""
        target = {d.key: int(t) for d, t in zip(window, own, strict=True) if t >= 0}
        claimed = set(target.values())
        groups = sorted(groups, key=lambda g: min((window[i].stamp, window[i].sensor) for i in g))
        for g in groups:
            votes = Counter(
                window[i].track
                for i in g
                if window[i].track >= 0
                and not self._n_committed.get(window[i].track, 1)
                and window[i].track not in claimed
            )
            if votes:
                tid = min(votes, key=lambda t: (-votes[t], t))
            else:
                tid = self._new_track()
            claimed.add(tid)
            for i in g:
                target[window[i].key] = tid
        touched = set()
        for d in window:
            touched.add(d.track)
            self._move(d, target[d.key])
            touched.add(d.track)
        for tid in touched:
            self._retail(tid)

    def _commit(self, due: list[Det], window: set[int]) -> None:
        """Commit ``due`` (canonical order): a detection whose track has another detection
        committed or in the ``window`` keeps it for good, one alone is a false alarm (-1)."""
        touched = set()
        for d in due:
            tid = d.track
            members = [
                m
                for m in (self._dets[k] for k in self._tracks[tid])
                if m.key not in self._pending or m.key in window
            ]
            self._pending.discard(d.key)
            self._stats['committed'] += 1
            before = [m for m in members if (m.sensor, m.stamp) < (d.sensor, d.stamp)]
            link = max(before, key=lambda m: (m.sensor, m.stamp)).key if before else -1
            if len(members) >= 2:
                label = tid
                self._n_committed[tid] += 1
                self._stats['assigned'] += 1
            else:
                label = -1
                self._move(d, -1)
                del self._dets[d.key]
                touched.add(tid)
                self._unassigned.append(d.key)
                self._stats['false_alarms'] += 1
                self._ended.add_alone(d.sensor, d.stamp, d.velocity)
            if (link if label >= 0 else -1) != d.first:  # the link first published changed
                self._stats['revised'] += 1
            self._committed.append((d.key, label))
            self._history.append((d.sensor, d.stamp, d.velocity))
        for tid in touched:
            self._retail(tid)

    def _due(self, tail: Det) -> float:
        """Stamp after which a track ending at ``tail`` is over: its passage at the next
        station (before an off-ramp) or 1 + max_skip stations on is beyond the gate."""
        span = 1 if self._before_exit[tail.sensor] else 1 + self._params.max_skip
        to = min(tail.sensor + span, self.layout.n_sensors - 1)
        return self._link_cost().due((tail.sensor, tail.stamp, tail.velocity), to)

    def _finalize(self, bound: float, everything: bool) -> None:
        """FINAL: a track whose detections below the boundary are all committed and that
        passed the last station, left at an exit or is overdue (``_due``)."""
        last_s = self.layout.n_sensors - 1
        for tid in list(self._tracks):
            members = [self._dets[k] for k in self._tracks[tid]]
            if not everything:
                if not self._n_committed[tid] or any(
                    d.key in self._pending and d.stamp < bound for d in members
                ):
                    continue
                done = [d for d in members if d.key not in self._pending]
                tail = max(done, key=lambda d: (d.sensor, d.stamp))
                if tail.sensor != last_s and bound <= self._due(tail):
                    continue
            later = [d for d in members if d.key in self._pending]
            done = sorted(
                (d for d in members if d.key not in self._pending), key=lambda d: (d.stamp, d.key)
            )
            if later:  # linked at once to a track that is over: they start their own
                new = self._new_track()
                for d in later:
                    self._move(d, new)
                self._retail(new)
            self._drop_track(tid, np.array([d.key for d in done], np.int64))
            for d in done:
                del self._dets[d.key]
            if len(done) >= 3:
                self._remember(done)
            self._ended.add_track([(d.sensor, d.stamp, d.velocity) for d in done])
            self._stats['final_tracks'] += 1

    def _remember(self, done: list[Det]) -> None:
        """Keep an ended track's detections as context: of all ended tracks, those of the
        latest ends (by stamp, then canonical order), so the context is a function of which
        tracks ended, not of the order they were finalised in."""
        size = self.config.context_size
        end = max(d.stamp for d in done)
        for d in done:
            bisect.insort(self._context, (end, canon(d), d), key=lambda e: e[:2])
        del self._context[: max(0, len(self._context) - size)]
