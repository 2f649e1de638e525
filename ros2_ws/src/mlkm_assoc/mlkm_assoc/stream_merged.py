"""The tracker updates of one batch of stream mode folded into one (ROS-free)."""

from __future__ import annotations

import math

import numpy as np


class MergedUpdate:
    """The updates of one batch folded into one: the latest state of each changed track,
    under its published id (``track_id`` of the core's number)."""

    def __init__(self, track_id) -> None:
        self._track_id = track_id  # the tracker's track number -> its published id
        self.tracks: dict[int, tuple[int, np.ndarray]] = {}
        self.in_tracks: set[int] = set()
        self.unassigned: dict[int, None] = {}
        self.committed: list[tuple[int, int]] = []
        self.committed_until = -math.inf

    def add(self, update) -> None:
        for t in update.tracks:
            keys = np.asarray(t.keys, np.int64)
            self.tracks[self._track_id(int(t.track_id))] = (int(t.status), keys)
            self.in_tracks.update(keys.tolist())
        for k in np.asarray(update.unassigned, np.int64).tolist():
            self.unassigned[k] = None
            self.in_tracks.discard(k)
        rows = np.asarray(update.committed, np.int64).reshape(-1, 2)
        self.committed.extend(
            (int(a), self._track_id(int(b)) if b >= 0 else -1) for a, b in rows.tolist()
        )
        self.committed_until = max(self.committed_until, float(update.committed_until))
