"""Where the stream's vehicles enter and leave mid-road: the rates from its ended tracks.

Batch prices a track that begins or ends mid-road by the entry and exit rates it estimates on
the tracks of a pass (``associators.entries``): where vehicles are observed over only part of
the road, a track beginning at the third station is then as cheap as the data say, not the
cost of the stations it would have missed. A stream window cannot estimate them: it cuts
the vehicles in transit at both its ends, so its own tracks begin and end mid-road whether or
not their vehicles did (``estimate_params(whole_passages=False)`` leaves the rates out), and
a window charges every mid-road end as misses and links the track to a wrong successor
instead (NGSIM I-80, five loops, the open road with lane and length: a car whose observation
ended at the fourth loop took the detection of another 1.2 m longer and a lane away).

The tracks the stream has ended are whole: finalised, each with every detection it will ever
have. ``EndedTracks`` keeps the latest of them (whole tracks, at most ``ENDED_SIZE``
detections) with the detections committed alone among them, and estimates the rates on
those as batch does on a pass; every window solve then prices the tracks it begins and ends
with them. A track whose vehicle may have passed the first station before the stream
began (its first detection, carried back to the first station at the speed measured there,
lies before the stream's first stamp) is left out, since where it begins is where the
stream began, not where its vehicle entered; likewise a detection alone.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from mlkm_core.associators.entries import estimate_entries
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Detections, Layout

#: most detections of ended tracks the rates are estimated on (the latest whole tracks)
ENDED_SIZE = 3000


class EndedTracks:
    """The stream's latest ended tracks, whole, and the entry and exit rates they show."""

    def __init__(self, layout: Layout, size: int = ENDED_SIZE) -> None:
        self.layout = layout
        self.size = size
        self.first_stamp = math.inf  # [s] of the stream's first detection
        self._tracks: deque[np.ndarray] = deque()  # (n, 3) rows (sensor, stamp, speed) each
        self._alone: deque[np.ndarray] = deque()  # (3,) rows of detections committed alone
        self._rows = 0
        self._version = 0
        # the rates of the tracks kept at a version, estimated under the gate of their call
        self._cached: tuple[int, tuple[np.ndarray | None, np.ndarray | None]] | None = None

    def begin(self, stamp: float) -> None:
        """A detection stamped ``stamp`` [s] was pushed."""
        self.first_stamp = min(self.first_stamp, stamp)

    def _whole(self, sensor: int, stamp: float, velocity: float) -> bool:
        """Whether a vehicle first seen so began after the stream: carried back to the first
        station at its speed, it passed there after the stream's first stamp."""
        pos = self.layout.positions
        back = (pos[sensor] - pos[0]) / velocity
        return stamp - back >= self.first_stamp

    def add_track(self, rows: list[tuple[int, float, float]]) -> None:
        """An ended track's (sensor, stamp, speed [m/s]) rows, in stamp order."""
        if len(rows) < 2 or not self._whole(*rows[0]):
            return
        self._tracks.append(np.array(rows, float))
        self._rows += len(rows)
        self._version += 1
        while self._rows > self.size and len(self._tracks) > 1:
            self._rows -= len(self._tracks.popleft())

    def add_alone(self, sensor: int, stamp: float, velocity: float) -> None:
        """A detection committed alone (a false alarm, or a vehicle seen once)."""
        if not self._whole(sensor, stamp, velocity):
            return
        self._alone.append(np.array([sensor, stamp, velocity], float))
        self._version += 1
        if self._tracks:  # those before the oldest track kept are out of its span
            start = float(self._tracks[0][0, 1])
            while self._alone and self._alone[0][1] < start:
                self._alone.popleft()

    def rates(self, params: MotionParams) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(entry rate, exit rate) per station (``MotionParams.entry_rate``; None: none shown),
        estimated on the kept tracks under ``params``' gate when they last changed."""
        if self._cached is not None and self._cached[0] == self._version:
            return self._cached[1]
        out: tuple[np.ndarray | None, np.ndarray | None] = (None, None)
        if self._tracks:
            parts = [*self._tracks, *(a[None, :] for a in self._alone)]
            rows = np.concatenate(parts)
            labels = np.concatenate(
                [np.full(len(t), k, np.int64) for k, t in enumerate(self._tracks)]
                + [np.full(len(self._alone), -1, np.int64)]
            )
            d = Detections(rows[:, 0].astype(np.int64), rows[:, 1], rows[:, 2])
            p = estimate_entries(self.layout, d, labels, params)
            out = (p.entry_rate, p.exit_rate)
        self._cached = (self._version, out)
        return out
