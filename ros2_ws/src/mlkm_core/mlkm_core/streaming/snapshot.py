"""Snapshots of the stream tracker's windows: what a window solve gets (mechanism, step 2, in
``mlkm_core.streaming``), a function of the committed state and of the detections stamped
before the window's boundary, so that it can be solved beside the stream."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mlkm_core.streaming.book import Det, as_detections, canon
from mlkm_core.streaming.links import ImmediateLinks
from mlkm_core.streaming.solve import WindowProblem

#: methods that calibrate their motion model on their input (``Associator.calibrates``): their
#: calibrating windows get the detections of recently ended tracks as context (the K-means
#: methods would cluster the context too), the windows in between the model carried over, and
#: the immediate link uses the same model
CONTEXT_METHODS = ('assignment', 'multiframe', 'mlkm_robust')
#: ``anchor_track`` of a context row in a window solve
CONTEXT = -2


@dataclass
class PreparedWindow:
    """A boundary's window, snapshotted for its solve, and what applying the solution needs."""

    k: int | None  # boundary index; None: a flush's window (everything)
    bound: float  # [s]
    cutoff: float  # [s] detections before it are committed by this solve
    window: list[Det]
    problem: WindowProblem | None = None  # None: an empty window (only ends tracks)
    anchor_track: np.ndarray | None = None
    last: np.ndarray | None = None
    occupied: dict | None = None
    n_anchors: int = 0


class WindowSnapshots(ImmediateLinks):
    """Snapshot a boundary's window with its anchors and context (``_prepare``)."""

    def _anchors(self) -> list[tuple[Det, int, bool]]:
        """(detection, track, is the track's last) of each open track's last committed ones."""
        out = []
        depth = self.config.anchor_depth
        for tid, members in self._tracks.items():
            if not self._n_committed[tid]:
                continue
            done = sorted(
                (self._dets[k] for k in members if k not in self._pending),
                key=lambda d: (d.sensor, d.stamp),
            )[-depth:]
            out += [(d, tid, i == len(done) - 1) for i, d in enumerate(done)]
        return out

    def _prepare(self, k: int | None) -> PreparedWindow:
        """Snapshot the window below boundary k (None: everything, at a flush) with its
        anchors and context: the problem of its solve, a function of the committed state and
        of the detections stamped before the boundary."""
        c = self.config
        final = k is None
        bound = math.inf if final else k * c.solve_interval
        cutoff = math.inf if final else bound - self.lag
        window = sorted(
            (self._dets[key] for key in self._pending if self._dets[key].stamp < bound),
            key=canon,
        )
        self._solved = True
        if not final:
            self._late_before = max(self._late_before, cutoff)
        prepared = PreparedWindow(k, bound, cutoff, window)
        if not window:
            return prepared
        anchors = sorted(self._anchors(), key=lambda a: canon(a[0]))
        calibrates = c.method in CONTEXT_METHODS
        carry = (
            calibrates
            and not final
            and self._model is not None
            and self._model.reusable
            and self._calibrated_rows >= c.context_size
            and k - self._calibrated_at < c.calibration_every
        )
        context = [e[2] for e in self._context] if calibrates and not carry else []
        anchors = [(d, CONTEXT, False) for d in context] + anchors
        rows = [a[0] for a in anchors] + window
        calibration = None
        if (
            not calibrates
            and not final
            and (self._calibrated_at is None or k - self._calibrated_at >= c.calibration_every)
        ):
            calibration = np.array(
                list(self._history) + [(d.sensor, d.stamp, d.velocity) for d in window], float
            ).reshape(-1, 3)
        prepared.problem = WindowProblem(
            c.method,
            c.associator_config(),
            self.layout,
            as_detections(rows),
            calibration,
            self._model if carry else None,
            self._evidence,
            self._ended.rates(self._params) if calibrates else None,
            final and not anchors and not self._stats['committed'],
        )
        prepared.n_anchors = len(anchors)
        prepared.anchor_track = np.array([a[1] for a in anchors] + [-1] * len(window), np.int64)
        prepared.last = np.array([a[2] for a in anchors] + [False] * len(window), bool)
        prepared.occupied = {
            tid: {self._dets[k].sensor for k in self._tracks[tid] if k not in self._pending}
            for tid in set(prepared.anchor_track[: len(anchors)].tolist()) - {CONTEXT}
        }
        return prepared
