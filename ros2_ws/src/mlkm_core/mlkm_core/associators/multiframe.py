"""``multiframe``: assignment with evidence from many sensors at once (the best method).

Pairwise sequential assignment is already optimal for pairwise costs, so the gain has to come
from higher-order evidence. Two sources, both in ``tracker``:

1. *Kalman tracks over the road.* Each track is a Kalman filter on (passage time, slowness,
   cruise slowness) with the exact Ornstein-Uhlenbeck-in-distance transition of the traffic
   model. The cruise speed, to which a target's speed reverts, is learnt from all its past
   detections, and noisy stamps and speeds are averaged over them; each sensor step is the same
   gated optimal assignment with dummies as ``assignment``, with the Kalman innovation NLL as
   the cost.
2. *Multi-frame refinement (an N-scan-style local search).* After the forward pass, moves that
   exchange two tracks' detections at one or two sensors, or their whole tails (2-opt, which
   also stitches a track lost after misses onto the track that was born from its detections),
   are scored by the Kalman marginal likelihood of both tracks over +-8 sensors around the
   exchange, i.e. with look-ahead as well as history; improving moves are applied greedily
   until none is left. It starts from the Kalman pass and, for inputs of up to 5000
   detections, also from the pairwise pass; the more likely result (Kalman model) is kept.

Why this and not a min-cost flow or a full multi-dimensional assignment: the flow needs
pairwise (Markov) edge costs, which cannot carry the learnt cruise speed, and the S-D
assignment is NP-hard; on seeded data the forward Kalman pass alone removed about a third of
the pairwise errors in clutter and the local search most of the rest, at a cost linear in the
number of detections (gating keeps every assignment block and the candidate set small).
"""

from __future__ import annotations

import numpy as np

from mlkm_core.associators.base import Associator, register
from mlkm_core.associators.linking import relabel
from mlkm_core.associators.tracker import canonical, estimate_params, link, refine, total_nll
from mlkm_core.types import Detections, Layout

#: above this many detections the search starts from the Kalman pass only (cost; the second
#: start matters where few detections make the self-calibration noisy)
DUAL_START_MAX = 5000


@register
class MultiFrameAssociator(Associator):
    name = 'multiframe'

    def associate(self, layout: Layout, detections: Detections, n_targets: int) -> np.ndarray:
        order = canonical(detections)
        d = detections.subset(order)
        out = np.full(len(d), -1, dtype=np.int64)
        if len(d):
            params, _ = estimate_params(layout, d)
            # local search from two starting points (the Kalman and the pairwise forward
            # pass); keep the more likely result under the Kalman model
            best, best_nll = None, np.inf
            starts = ('kalman', 'pairwise') if len(d) <= DUAL_START_MAX else ('kalman',)
            for model in starts:
                lab = refine(layout, d, link(layout, d, params, model), params)
                nll = total_nll(layout, d, lab, params)
                if nll < best_nll:
                    best, best_nll = lab, nll
            out[order] = relabel(best)
        return out
