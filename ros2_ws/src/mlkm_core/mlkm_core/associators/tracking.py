"""What the three tracking methods (``assignment``, ``multiframe``, ``mlkm_robust``) share.

Each reads the detections in canonical order, calibrates the link model on them (or takes
one calibrated elsewhere: the stream tracker's carried model), puts it on the declared road
(entries and exits), builds its tracks, and finishes them the same way (``finish_tracks``).
A method implements ``track`` only.
"""

from __future__ import annotations

from abc import abstractmethod

import numpy as np

from mlkm_core.associators.base import Associator, canonical_order
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.associators.laneorder import restore_order
from mlkm_core.associators.linking import finish_tracks
from mlkm_core.associators.merges import mend_merges
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Detections, Layout


def repaired(layout: Layout, d: Detections, labels: np.ndarray, p: MotionParams) -> np.ndarray:
    """Tracks of a pass with the links at merges re-decided under their own laws
    (``merges.mend_merges``) and crossed neighbours in queues put back in order
    (``laneorder.restore_order``)."""
    return restore_order(layout, d, mend_merges(layout, d, labels, p), p)


class TrackingAssociator(Associator):
    """Calibrate, track (``track``), finish; labels in the caller's order."""

    calibrates = True

    def associate(
        self,
        layout: Layout,
        detections: Detections,
        n_targets: int,
        motion: MotionParams | None = None,
    ) -> np.ndarray:
        order = canonical_order(detections)
        d = detections.subset(order)
        out = np.full(len(d), -1, dtype=np.int64)
        if len(d) == 0:
            return out
        p = motion if motion is not None else estimate_params(layout, d)
        p = p.on_road(layout.positions, self.config.entries, self.config.exits)
        raw = self.track(layout, d, n_targets, p, motion is not None)
        out[order] = finish_tracks(layout, d, raw, p)
        return out

    @abstractmethod
    def track(
        self, layout: Layout, d: Detections, n_targets: int, p: MotionParams, given: bool
    ) -> np.ndarray:
        """Raw track ids of ``d`` (canonical order) under the calibrated model ``p``;
        ``given``: the caller gave the model (else ``p`` was calibrated on ``d``)."""
