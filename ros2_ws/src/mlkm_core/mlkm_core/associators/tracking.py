"""What the three tracking methods (``assignment``, ``multiframe``, ``mlkm_robust``) share.

Each reads the detections in canonical order, calibrates the link model on them (or takes
one calibrated elsewhere: the stream tracker's carried model), puts it on the declared road
(entries and exits), builds its tracks, and finishes them the same way (``finish_tracks``).
A method implements ``track`` only.
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import replace
from typing import ClassVar

import numpy as np

from mlkm_core.associators.base import Associator, canonical_order
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.associators.linking import finish_tracks
from mlkm_core.model.motion import MotionParams
from mlkm_core.progress import stage
from mlkm_core.types import Detections, Layout


class TrackingAssociator(Associator):
    """Calibrate, track (``track``), finish; labels in the caller's order."""

    calibrates = True
    #: fractions of the time at which calibration and ``track`` end (``mlkm_core.progress``;
    #: measured for assignment on 10^5 and 3·10^5 simulated detections with clutter)
    progress_shares: ClassVar[tuple[float, float]] = (0.75, 0.97)

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
        calibrated, tracked = self.progress_shares
        with stage(0.0, calibrated):
            openings = MotionParams.road_openings(
                layout.positions, self.config.entries, self.config.exits
            )
            p = motion if motion is not None else estimate_params(layout, d, openings)
        if not _same_openings(p.open_road, openings):
            p = replace(p, open_road=openings)  # a given model keeps its identity otherwise
        with stage(calibrated, tracked):
            raw = self.track(layout, d, n_targets, p, motion is not None)
        with stage(tracked, 1.0):
            out[order] = finish_tracks(layout, d, raw, p)
        return out

    @abstractmethod
    def track(
        self, layout: Layout, d: Detections, n_targets: int, p: MotionParams, given: bool
    ) -> np.ndarray:
        """Raw track ids of ``d`` (canonical order) under the calibrated model ``p``;
        ``given``: the caller gave the model (else ``p`` was calibrated on ``d``)."""


def _same_openings(a, b) -> bool:
    """Whether two ``MotionParams.open_road`` values are equal (None: a closed road)."""
    if a is None or b is None:
        return a is b
    return all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
