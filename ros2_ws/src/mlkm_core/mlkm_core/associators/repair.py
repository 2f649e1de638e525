"""The repairs every pairwise pass gets before its tracks are used (``repaired``)."""

from __future__ import annotations

import numpy as np

from mlkm_core.associators.laneorder import restore_order
from mlkm_core.associators.merges import mend_merges
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Detections, Layout


def repaired(layout: Layout, d: Detections, labels: np.ndarray, p: MotionParams) -> np.ndarray:
    """Tracks of a pass with the links at merges re-decided under their own laws
    (``merges.mend_merges``) and crossed neighbours in queues put back in order
    (``laneorder.restore_order``)."""
    return restore_order(layout, d, mend_merges(layout, d, labels, p), p)
