"""``assignment``: the classical baseline, sequential sensor-to-sensor optimal assignment.

What a tracking engineer would build first (the idea of Stone Soup's ``GNNWith2DAssignment``,
with the road as the scan axis): walk the sensors in road order; between the tracks (each
represented by its last detection) and the detections of the next sensor, solve a gated
linear assignment (``scipy.optimize.linear_sum_assignment``, per connected component of the
time-gated candidate graph) with dummy rows and columns:

* cost of a link = Gaussian NLL of the travel-time residual predicted from the speeds at both
  ends, e_t = t2 - t1 - dx (1/v1 + 1/v2) / 2, and of the slowness change, each divided by its
  expected variance (derived from the simulator's model, see ``motion``); gate 6 sigma;
* a track left unmatched is a miss: it pays -log p_miss and is carried forward to the next
  sensors (at most 3 in a row) with the larger variance of the longer gap;
* a detection left unmatched starts a new track (cost -log of the false-alarm density);
* a track that ends with a single detection is a false alarm: UNASSIGNED (-1);
* where the data show them, the cost also carries: abrupt speed changes (a two-component
  mixture, ``motion``), an extra travel time per gap between sensors, with its spread in
  stop-and-go traffic (road works, a queue: ``delays``), and the cues of ``model`` (for loop
  detectors the lane, the vehicle length and the order of passage within a lane in queues;
  two neighbours of a lane whose links the pass crossed in a queue are given
  back their order, ``laneorder.restore_order``);
* a lane change on top of a station, reported by both lanes' loops, keeps one track
  (``linking.merge_double_reports``);
* a track the pass ends where no target can leave is joined to one it starts a few sensors
  downstream where none can enter, when the link costs less than the two ends do under the
  whole-track model (``linking.join_fragments``; the entries and exits are
  ``AssociatorConfig.entries`` / ``exits``, none on a closed road).

The parameters are not given to the method: they are estimated from the data (pass 1 with
generic values, then the moments and the maximum likelihood of its tracks, ``calibration``),
the same estimates ``multiframe`` uses, so the two differ only in the evidence they use.
"""

from __future__ import annotations

import numpy as np

from mlkm_core.associators.base import register
from mlkm_core.associators.linking import link
from mlkm_core.associators.repair import repaired
from mlkm_core.associators.tracking import TrackingAssociator
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Detections, Layout


@register
class AssignmentAssociator(TrackingAssociator):
    name = 'assignment'

    def track(
        self, layout: Layout, d: Detections, n_targets: int, p: MotionParams, given: bool
    ) -> np.ndarray:
        return repaired(layout, d, link(layout, d, p, 'pairwise'), p)
