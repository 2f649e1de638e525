"""``multiframe``: assignment with evidence from many sensors at once (the best method).

Pairwise sequential assignment is already optimal for pairwise costs, so the gain has to come
from higher-order evidence. Two sources:

1. *Kalman tracks over the road* (``kalman.KalmanModel``, run by ``linking.link``). Each track
   is a Kalman filter on (passage time, slowness, cruise slowness) with the exact
   Ornstein-Uhlenbeck-in-distance transition of the traffic model. The cruise speed, to which
   a target's speed reverts, is learnt from all its past detections, and noisy stamps and
   speeds are averaged over them; each sensor step is the same gated optimal assignment with
   dummies as ``assignment``, with the Kalman innovation NLL as the cost.
2. *Multi-frame refinement* (``search.refine``, an N-scan-style local search). After the
   forward pass, moves that exchange two tracks' detections at 1, 2, 3 or 5 consecutive
   sensors, or their whole tails (2-opt, which also stitches a track lost after misses onto
   the track that was born from its detections), are scored by the Kalman marginal
   likelihood of both tracks over the 6 sensors before and the 6 sensors from the exchange on,
   i.e. with look-ahead as well as history; improving moves are applied greedily until none
   is left. It starts from the Kalman pass and, for inputs of up to ``DUAL_START_MAX``
   detections that it calibrates on itself, also from the pairwise pass; the more likely
   result (Kalman model) is kept.

The model parameters are estimated from the data (``calibration.estimate_params``), lane and
length included when reported. On an open road (``AssociatorConfig.entries`` / ``exits``) a
track that starts after an entry or ends before an exit pays only for the sensors it could have
passed; tracks that end or start where no target can leave or enter are joined after the search
where the whole-track cost favours it (``linking.join_fragments``). The local search scores at
most ``AssociatorConfig.search_budget`` candidates per starting point. The result is the
pairwise assignment's when the Kalman model predicts the calibrated pairwise tracks clearly
worse than the pairwise model (``kalman_fits``: stop-and-go traffic, where its likelihood would
steer the search wrong, and where the search used to cost minutes) or when neither starting
point can be scored (the likelihood is not finite); a cut-short search and both fallbacks issue
a ``DegradedResultWarning``.

Why this and not a min-cost flow or a full multi-dimensional assignment: the flow needs
pairwise (Markov) edge costs, which cannot carry the learnt cruise speed, and the S-D
assignment is NP-hard; the forward Kalman pass removes part of the pairwise errors in clutter
and the local search most of the rest (docs/benchmarks.md), at a cost linear in the number of
detections (gating keeps every assignment block and the candidate set small).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np

from mlkm_core.associators.base import DegradedResultWarning, register
from mlkm_core.associators.likelihood import sequence_nll, total_nll, track_sequences
from mlkm_core.associators.linking import link, relabel
from mlkm_core.associators.search import refine
from mlkm_core.associators.tracking import TrackingAssociator, repaired
from mlkm_core.model.motion import MotionParams, PairwiseModel
from mlkm_core.types import Detections, Layout, link_pairs

#: NLL per link [nats] by which the Kalman model may trail the pairwise model on the pairwise
#: model's own tracks (which favour it) and still be used: in free flow it trails by less and
#: its search gains; in stop-and-go traffic it mostly trails by more, and its likelihood would
#: steer the search wrong
FIT_MARGIN = 0.2
#: above this many detections the search starts from the Kalman pass only (cost; the second
#: start matters where few detections make the self-calibration noisy)
DUAL_START_MAX = 5000


def kalman_fits(layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams) -> bool:
    """Whether the Kalman model predicts the links of ``labels`` better than the pairwise model.

    Both give the density of a track's next detection (stamp, slowness) given its earlier ones,
    so their summed log-likelihoods over the same links (capped as in ``sequence_nll``, lane and
    length left out: they are the same in both) are comparable, up to ``FIT_MARGIN`` per link.
    The Kalman model conditions on the whole history and must win when its structure (a cruise
    speed the target reverts to) holds; where it does not (stop-and-go traffic), its likelihood
    would steer the local search to wrong exchanges.
    """
    p = replace(params, cues=None)
    a, b = link_pairs(d, labels)
    if a.size < 10:
        return True
    m = PairwiseModel(p)
    m.grow(a.size)
    rows = np.arange(a.size)
    x = layout.positions
    u = 1.0 / d.velocity
    m.start(rows, x[d.sensor_index[a]], d.stamp[a], u[a])
    nll, d2 = m.cost(m.predict(rows, x[d.sensor_index[b]]), d.stamp[b], u[b])
    pairwise = float(np.sum(nll - 0.5 * np.maximum(d2 - 4 * p.gate, 0.0)))
    seqs = track_sequences(d, labels, min_len=2)
    none = np.zeros(seqs.shape[0], bool)
    kalman = float(sequence_nll(layout, d, seqs, p, none, none).sum())
    skipped = float((d.sensor_index[b] - d.sensor_index[a] - 1).sum()) * p.miss_cost
    return bool(kalman - skipped < pairwise + FIT_MARGIN * a.size)


@register
class MultiFrameAssociator(TrackingAssociator):
    name = 'multiframe'

    def track(
        self, layout: Layout, d: Detections, n_targets: int, params: MotionParams, given: bool
    ) -> np.ndarray:
        budget = self.config.search_budget
        with np.errstate(all='ignore'):
            pairwise = repaired(layout, d, link(layout, d, params, 'pairwise'), params)
            fits = kalman_fits(layout, d, relabel(pairwise), params)
        if not fits:
            warnings.warn(
                'multiframe: the Kalman model predicts the tracks worse than the pairwise model '
                '(e.g. stop-and-go traffic); returning the pairwise assignment',
                DegradedResultWarning,
                stacklevel=3,
            )
            return pairwise
        # local search from two starting points (the Kalman and the pairwise forward pass);
        # keep the more likely result under the Kalman model
        best, best_nll = None, math.inf
        # the second start guards against a noisy self-calibration on few detections; a model
        # calibrated elsewhere (``motion``, the stream's carried model) does not need it
        dual = not given and len(d) <= DUAL_START_MAX
        starts = ('kalman', 'pairwise') if dual else ('kalman',)
        with np.errstate(all='ignore'):  # a non-finite score only disqualifies a start
            for model in starts:
                start = pairwise if model == 'pairwise' else link(layout, d, params, model)
                result = refine(layout, d, start, params, budget=budget)
                if result.exhausted:
                    warnings.warn(
                        f'multiframe: the local search from the {model} pass stopped at its '
                        f'budget of {budget} candidates; the result is the best found within it',
                        DegradedResultWarning,
                        stacklevel=3,
                    )
                nll = total_nll(layout, d, result.labels, params)
                if math.isfinite(nll) and nll < best_nll:
                    best, best_nll = result.labels, nll
        if best is None:
            warnings.warn(
                'multiframe: no starting point has a finite likelihood under the calibrated '
                'Kalman model (e.g. near-zero speeds); returning the pairwise assignment',
                DegradedResultWarning,
                stacklevel=3,
            )
            best = pairwise
        return best
