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
length included when reported. In a stream, which model the search scores with is decided on
the links of every window so far, not on each window alone (``settled``), and a window
decided for the pairwise model searches from the pairwise pass that decision was made on. On
an open road (``AssociatorConfig.entries`` / ``exits``) a track that starts after an entry or
ends before an exit pays only for the sensors it could have passed; tracks that end or start
where no target can leave or enter are joined after the search where the whole-track cost
favours it (``linking.join_fragments``). The local search scores at most
``AssociatorConfig.search_budget`` candidates per starting point.

Where vehicles keep no speed of their own (stop-and-go traffic: a vehicle's deviations from the
traffic around it are uncorrelated from one station gap to the next, on NGSIM I-80 r = -0.2 to
0.13), the Kalman model predicts the links of the calibrated pairwise pass clearly worse than
the pairwise model (``kalman_fits``), and its likelihood would steer the search wrong. The
search then runs from the pairwise pass under the pairwise model's Markov chain
(``likelihood.sequence_nll(model='pairwise')``: each link scored from the detection before it
alone), which still exchanges tails, mends tracks broken by misses and re-decides the links
around them. The result is the pairwise assignment's only when no starting point can be
scored (the likelihood is not finite); that fallback and a cut-short search issue a
``DegradedResultWarning``.

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
from mlkm_core.associators.likelihood import total_nll
from mlkm_core.associators.linking import link, relabel
from mlkm_core.associators.pairwise_fit import kalman_evidence, kalman_lead, lead_per_link
from mlkm_core.associators.repair import repaired
from mlkm_core.associators.search import refine
from mlkm_core.associators.tracking import TrackingAssociator
from mlkm_core.model.motion import MotionParams
from mlkm_core.progress import stage
from mlkm_core.types import Detections, Layout

#: NLL per link [nats] by which the Kalman model may trail the pairwise model on the pairwise
#: model's own tracks (which favour it) and still be used: in free flow it trails by less and
#: its search gains; in stop-and-go traffic it mostly trails by more, and its likelihood would
#: steer the search wrong
FIT_MARGIN = 0.2
#: above this many detections the search starts from the Kalman pass only (cost; the second
#: start matters where few detections make the self-calibration noisy)
DUAL_START_MAX = 5000
#: shares of ``track``'s time (``mlkm_core.progress``; measured on 10^5 simulated detections
#: with clutter): the pairwise pass with its check, then per start its Kalman pass [-]
PAIRWISE_SHARE = 0.16
KALMAN_PASS_SHARE = 0.17


def kalman_fits(layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams) -> bool:
    """Whether the Kalman model predicts the links of ``labels`` at most ``FIT_MARGIN`` per link
    worse than the pairwise model (``pairwise_fit.kalman_lead``). On the pairwise model's own
    tracks, which favour it, the Kalman model may trail a little and still be the better
    model; where its structure (a cruise speed the target reverts to) does not hold
    (stop-and-go traffic), its likelihood would steer the local search to wrong exchanges.
    """
    return bool(kalman_lead(layout, d, labels, params) < FIT_MARGIN)


@register
class MultiFrameAssociator(TrackingAssociator):
    name = 'multiframe'
    progress_shares = (0.33, 0.94)
    #: (model returned, window, its pairwise pass) of the last ``settled`` call
    _settled_pass: tuple[MotionParams, Detections, np.ndarray] | None = None

    def settled(
        self,
        layout: Layout,
        d: Detections,
        params: MotionParams,
        evidence: tuple[float, float] | None,
    ) -> tuple[MotionParams, tuple[float, float] | None]:
        """``params`` with ``kalman_fits`` decided on the lead of the Kalman model over the
        links of the pairwise pass of every window so far (``evidence``: summed lead, links)
        and of ``d``; and ``d``'s. Whether vehicles keep a cruise speed of their own is a
        property of the traffic: decided on each window's few hundred detections alone it
        flips from window to window in stop-and-go traffic, and the links made under one model
        are undone under the other (NGSIM I-80, 20 loops, time and speed: the Kalman model in
        8 of 26 windows where the whole input rejects it, the stream 1.5 points below batch;
        decided on the evidence so far, in none after the fifth, 0.5 below)."""
        p = params.on_road(layout.positions, self.config.entries, self.config.exits)
        pairwise = self._pairwise(layout, d, p)
        with np.errstate(all='ignore'):
            own = kalman_evidence(layout, d, relabel(pairwise), p)
        if not all(math.isfinite(v) for v in own):
            return params, None  # a window whose links cannot be scored: no evidence
        total = own if evidence is None else (own[0] + evidence[0], own[1] + evidence[1])
        out = replace(p, kalman_fits=bool(lead_per_link(total) < FIT_MARGIN))
        # ``track`` under the pairwise model starts from this very pass
        self._settled_pass = (out, d, pairwise)
        return out, own

    def _reused_pass(self, d: Detections, params: MotionParams) -> np.ndarray | None:
        """The pairwise pass that ``settled`` last made, if it made it for ``params`` (the
        same object) and detections equal to ``d``; else None."""
        last = self._settled_pass
        if last is None or last[0] is not params:
            return None
        seen = last[1]
        fields = ('sensor_index', 'stamp', 'velocity')
        same = all(np.array_equal(getattr(seen, f), getattr(d, f)) for f in fields)
        return last[2].copy() if same else None

    @staticmethod
    def _pairwise(layout: Layout, d: Detections, params: MotionParams) -> np.ndarray:
        """The repaired pairwise pass."""
        with np.errstate(all='ignore'):
            return repaired(layout, d, link(layout, d, params, 'pairwise'), params)

    def _pairwise_pass(
        self, layout: Layout, d: Detections, params: MotionParams
    ) -> tuple[np.ndarray, bool]:
        """The repaired pairwise pass and whether the Kalman model fits its links (decided
        beforehand where ``params`` carries the decision)."""
        pairwise = self._reused_pass(d, params)
        if pairwise is None:
            pairwise = self._pairwise(layout, d, params)
        fits = params.kalman_fits
        if fits is None:
            with np.errstate(all='ignore'):
                fits = kalman_fits(layout, d, relabel(pairwise), params)
        return pairwise, fits

    def track(
        self, layout: Layout, d: Detections, n_targets: int, params: MotionParams, given: bool
    ) -> np.ndarray:
        budget = self.config.search_budget
        with stage(0.0, PAIRWISE_SHARE):
            if given and params.kalman_fits:
                # decided beforehand, and the search starts from the Kalman pass alone: the
                # pairwise pass only as the answer of last resort
                pairwise, fits = None, True
            else:
                pairwise, fits = self._pairwise_pass(layout, d, params)
        # the model the search scores with: the Kalman model where targets keep a speed of
        # their own; where it predicts the links clearly worse, the Markov chain of the
        # pairwise model (stop-and-go traffic: a target's deviations from the traffic around
        # it do not persist from one station gap to the next)
        if fits:
            # the second start guards against a noisy self-calibration on few detections; a
            # model calibrated elsewhere (``motion``, the stream's carried model) does not
            # need it
            dual = not given and len(d) <= DUAL_START_MAX
            runs = [('kalman', 'kalman')] + ([('pairwise', 'kalman')] if dual else [])
        else:
            runs = [('pairwise', 'pairwise')]
        best, best_nll = None, math.inf
        share = (1.0 - PAIRWISE_SHARE) / len(runs)
        with np.errstate(all='ignore'):  # a non-finite score only disqualifies a start
            for k, (start_model, model) in enumerate(runs):
                begin = PAIRWISE_SHARE + k * share
                with stage(begin, begin + KALMAN_PASS_SHARE * share):
                    start = (
                        pairwise
                        if start_model == 'pairwise'
                        else link(layout, d, params, start_model)
                    )
                with stage(begin + KALMAN_PASS_SHARE * share, begin + share):
                    result = refine(layout, d, start, params, budget=budget, model=model)
                if result.exhausted:
                    warnings.warn(
                        f'multiframe: the local search from the {start_model} pass stopped at '
                        f'its budget of {budget} candidates; the result is the best found '
                        'within it',
                        DegradedResultWarning,
                        stacklevel=3,
                    )
                nll = total_nll(layout, d, result.labels, params, model)
                if math.isfinite(nll) and nll < best_nll:
                    best, best_nll = result.labels, nll
        if best is None:
            warnings.warn(
                'multiframe: no starting point has a finite likelihood under the calibrated '
                'models (e.g. near-zero speeds); returning the pairwise assignment',
                DegradedResultWarning,
                stacklevel=3,
            )
            best = pairwise if pairwise is not None else self._pairwise(layout, d, params)
        return best
