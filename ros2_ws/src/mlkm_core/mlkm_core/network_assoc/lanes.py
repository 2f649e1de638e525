"""The lane as a cue across a hop, learned from the data being associated.

On one road a lane index is a place across the carriageway, and the lane cue of
``model.lane`` prices a change of it. Across a junction it is not: lane 0 of an acceleration
lane becomes lane 0 of the freeway after the merge, the through lanes move one to the left,
a connector of one lane feeds the rightmost lane of the next link. The layout gives no such
mapping, but the data shows it: on each hop, the links of a pass say how the lane at the
far station follows the lane at the near one.

Per hop, from the links of a pass that cross it and report both lanes, the table
``log P(lane_b | lane_a, hop) - log P(lane_b)``: what the near lane and the way taken say
about the far lane, a log-likelihood ratio against the far station's lane shares over all
its detections (what a track that starts there is priced with: nothing). It holds both the
lane's continuation (a through lane keeps its place) and the source at a merge (the
vehicles of a one-lane connector arrive in the lanes next to it, not across the
carriageway). A link's lane cost is minus its entry. Where the lanes tell nothing the entries
are 0 and the cue weighs nothing (a cue that carries no information must not move the
links). The estimates shrink towards the coarser ones: ``PSEUDO`` counts of the hop's far-lane
shares per near lane, and of the station's shares in the hop's, so that a hop seen by few
links stays near 0. A detection without a lane, or a lane the table has not seen, costs
nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mlkm_core.types import UNKNOWN_LANE, Detections

#: pseudo-counts per near lane, spread over the far lanes by the hop's far-lane shares
PSEUDO = 10.0
#: fewest links with both lanes known a hop's table is learned from
MIN_LINKS = 8


@dataclass(frozen=True)
class HopLanes:
    """Per hop index: the table of log-likelihood ratios [nats], rows the near lane, columns
    the far lane (module docstring)."""

    tables: dict[int, np.ndarray] = field(default_factory=dict)

    def cost(self, hop: int, lane_a: np.ndarray, lane_b: np.ndarray) -> np.ndarray:
        """The lane cost [nats] of links across ``hop`` from lanes ``lane_a`` to ``lane_b``."""
        out = np.zeros(np.asarray(lane_a).shape)
        table = self.tables.get(hop)
        if table is None:
            return out
        la, lb = np.asarray(lane_a), np.asarray(lane_b)
        ok = (la >= 0) & (lb >= 0) & (la < table.shape[0]) & (lb < table.shape[1])
        out[ok] = -table[la[ok], lb[ok]]
        return out


def fit_lanes(d: Detections, a: np.ndarray, b: np.ndarray, hop: np.ndarray) -> HopLanes | None:
    """The tables of the links ``a[k] -> b[k]`` across hops ``hop[k]``; None when the
    detections report no lane."""
    if d.lane is None or not np.any(d.lane != UNKNOWN_LANE):
        return None
    la, lb = d.lane[a], d.lane[b]
    known = (la >= 0) & (lb >= 0)
    tables = {}
    for h in np.unique(hop[known]):
        sel = known & (hop == h)
        if sel.sum() < MIN_LINKS:
            continue
        x, y = la[sel], lb[sel]
        at = d.lane[(d.sensor_index == d.sensor_index[b[sel][0]]) & (d.lane >= 0)]
        width = int(max(y.max(), at.max())) + 1
        station = np.bincount(at, minlength=width) / at.size
        counts = np.zeros((int(x.max()) + 1, width))
        np.add.at(counts, (x, y), 1.0)
        way = (counts.sum(axis=0) + PSEUDO * station) / (counts.sum() + PSEUDO)
        conditional = (counts + PSEUDO * way) / (counts.sum(axis=1, keepdims=True) + PSEUDO)
        table = np.zeros_like(conditional)
        seen = station > 0
        table[:, seen] = np.log(conditional[:, seen]) - np.log(station[seen])
        tables[int(h)] = table
    return HopLanes(tables)
