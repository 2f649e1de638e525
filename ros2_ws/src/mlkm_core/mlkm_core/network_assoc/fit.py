"""The network model fitted to the data being associated: motion, turns, time lost at junctions.

Pass 1 links with generic parameters (``MotionParams()``, equal turn shares) and, per
junction, the time lost at the peak of every pair of detections across it where one stands
out clearly (``pair_lags``), else a generous generic one. From its links: the pairwise
model's own maximum-likelihood fit of the motion (``pairwise_fit.fit_links``, on the links
that cross no junction where there are enough of them, so that red lights do not pass for
speed scatter) and, for each hop with as
many links as that fit needs, a motion fit of its own (an acceleration lane or a merge
changes speeds far more than the road before it), the fixed-time signals where a junction
shows one (``signals.fit_signals``: cycle, greens, queues), then the turn shares and the time
lost per connection (``junctions.fit_junctions``) from the travel-time residuals under that
motion, less each link's wait at its signals.
Pass 2 links with the fitted model; a second round of fitting follows, as the links of pass 1
are those of a cruder model. Where the stations report vehicle lengths that vary more than
their noise, the length cue links with its noise fitted the same way; where they report
lanes, each hop's lane table (``lanes``) is learned from the links of the pass.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from mlkm_core.associators.kalman_fit import FIT_BOUNDS, FIT_FACTORS, JUMP_GRID, penalty_of
from mlkm_core.associators.pairwise_fit import MIN_LINKS, fit_links
from mlkm_core.model.cues import Cue
from mlkm_core.model.length import LengthParams, bind_detections
from mlkm_core.model.length import fit_links as fit_lengths
from mlkm_core.model.motion import MotionParams, trapezoid_residual
from mlkm_core.network import RoadNetwork
from mlkm_core.network_assoc.hops import Hops
from mlkm_core.network_assoc.junctions import JunctionModel, fit_junctions
from mlkm_core.network_assoc.lanes import HopLanes, fit_lanes
from mlkm_core.network_assoc.linking import Links, solve
from mlkm_core.network_assoc.pair_lags import pair_junctions
from mlkm_core.network_assoc.signals import fit_signals, link_waits
from mlkm_core.types import Detections

#: rounds of (fit, link) after pass 1
ROUNDS = 2


@dataclass(frozen=True)
class NetworkModel:
    """What the tracks of a network are linked with."""

    motion: MotionParams
    junctions: JunctionModel
    length: LengthParams | None = None  # the length cue's, None where lengths tell nothing
    lanes: HopLanes | None = None  # the lane cue per hop, None where no lane is reported
    per_hop: dict[int, MotionParams] | None = None  # hops with a motion fit of their own

    def cue(self, d: Detections) -> Cue | None:
        """The length cue bound to ``d`` (None: off)."""
        return None if self.length is None else bind_detections(d, self.length)


def _link_arrays(hops: Hops, d: Detections, links: Links, sel: np.ndarray):
    a, b, h = links.a[sel], links.b[sel], links.hop[sel]
    u = 1.0 / d.velocity
    zero = np.zeros(a.size)
    return zero, d.stamp[a], u[a], hops.distance[h], d.stamp[b], u[b]


def fit_model(
    net: RoadNetwork, hops: Hops, d: Detections, links: Links, base: MotionParams
) -> NetworkModel:
    """The model fitted on the links of a pass (module docstring)."""
    plain = np.array([not hops.turns[h] for h in links.hop], bool)
    sel = plain if plain.sum() >= MIN_LINKS else np.ones(links.a.size, bool)
    arrays = _link_arrays(hops, d, links, sel)
    penalty = 2 * penalty_of(int(links.a.size))
    fit = fit_links(arrays, base, FIT_BOUNDS, FIT_FACTORS, JUMP_GRID, penalty)
    p = base if fit is None else replace(base, **dict(fit))
    per_hop = {}
    e_t, var_t = np.zeros(links.a.size), np.zeros(links.a.size)
    for h in np.unique(links.hop):
        sel = links.hop == h
        if sel.sum() >= MIN_LINKS:
            arrays = _link_arrays(hops, d, links, sel)
            own = fit_links(arrays, p, FIT_BOUNDS, FIT_FACTORS, JUMP_GRID, penalty)
            if own is not None:
                per_hop[int(h)] = replace(p, **dict(own))
        xa, ta, ua, xb, tb, ub = _link_arrays(hops, d, links, sel)
        e_t[sel], var_t[sel] = trapezoid_residual(per_hop.get(int(h), p), xa, xb, ta, tb, ua, ub)
    turns = [hops.turns[h] for h in links.hop]
    lengths = fit_lengths(d, links.a, links.b) if d.length is not None else None
    signals = fit_signals(net, hops, d, links.a, links.b, links.hop, e_t)
    if signals is not None:
        e_t = e_t - link_waits(signals, d, links.a, links.hop)
    junctions = fit_junctions(net, turns, e_t, np.sqrt(var_t), links.hop, signals)
    lanes = fit_lanes(d, links.a, links.b, links.hop)
    return NetworkModel(p, junctions, lengths, lanes, per_hop)


def calibrate_and_link(
    net: RoadNetwork, hops: Hops, d: Detections
) -> tuple[np.ndarray, NetworkModel]:
    """Labels of ``d`` under the model fitted on it, and that model."""
    model = NetworkModel(MotionParams(), pair_junctions(net, hops, d), LengthParams())
    labels, links = solve(hops, d, model.motion, model.junctions, model.cue(d))
    for _ in range(ROUNDS):
        model = fit_model(net, hops, d, links, MotionParams())
        labels, links = solve(
            hops, d, model.motion, model.junctions, model.cue(d), model.lanes, model.per_hop
        )
    return labels, model
