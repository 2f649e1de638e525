"""One-road tracking methods on a road network: the method on each link, the network model
across the junctions.

A network has no one road to run ``multiframe`` or ``mlkm_robust`` on, but each of its links
is one: its stations stand in a row along it, every vehicle enters at its start (or at an
entry inside it) and leaves at its end (or an exit inside it). So:

1. **On each link** the one-road method associates the link's detections into link-tracks
   (``gmlkm.link_tracks``, which G-MLKM runs with MLKM): ``multiframe``'s Kalman tracks and
   multi-frame search, or ``mlkm_robust``'s layers, with everything they fit from the
   link's data. A detection the method leaves alone is a link-track of its own.
2. **Across junctions** a link-track's last detection (its tail) is joined to the first
   detection (its head) of at most one link-track on another link, by one min-cost matching
   under the network ``assignment``'s model (``fit.calibrate_and_link``: motion per hop,
   turn shares, time lost at junctions, lane and length cues, all fitted to the data being
   associated), with the same costs of starting and ending a track there. Where G-MLKM
   joins greedily by nearest neighbour in raw (v, t), this joins optimally with the fitted
   model; the links within a link are the one-road method's, never changed.

A track of one detection is left unassigned (-1), as by every tracking method.
"""

from __future__ import annotations

import numpy as np

from mlkm_core.associators.linking import match_sparse, relabel
from mlkm_core.network import RoadNetwork
from mlkm_core.network_assoc.fit import calibrate_and_link
from mlkm_core.network_assoc.gmlkm import link_tracks, number_tracks
from mlkm_core.network_assoc.hops import Hops
from mlkm_core.network_assoc.linking import candidates, link_weights
from mlkm_core.types import Detections


def per_link_associate(
    net: RoadNetwork, hops: Hops, d: Detections, method: str, seed: int = 0
) -> np.ndarray:
    """One label per detection (module docstring): ``method`` (a one-road method) on each
    link, the network model's matching across the junctions."""
    piece = link_tracks(net, d, seed, method)
    _, model = calibrate_and_link(net, hops, d)
    joins = model_joins(net, hops, d, piece, model)
    return relabel(number_tracks(d, piece, joins))  # a track of one detection: unassigned


def model_joins(net: RoadNetwork, hops: Hops, d: Detections, piece: np.ndarray, model):
    """The (tail link-track, head link-track) joins across junctions: the candidate links of
    the network model from a link-track's last detection to another link's link-track's
    first one, matched at least cost where a join beats ending the one and starting the
    other."""
    order = np.lexsort((np.arange(len(d)), d.stamp, piece))
    p = piece[order]
    first = np.flatnonzero(np.r_[True, p[1:] != p[:-1]])
    last = np.r_[first[1:] - 1, p.size - 1]
    head, tail = order[first], order[last]  # per link-track, by stamp
    is_head = np.full(len(d), -1, np.int64)
    is_tail = np.full(len(d), -1, np.int64)
    is_head[head] = piece[head]
    is_tail[tail] = piece[tail]
    m = model
    i, j, cost, _ = candidates(hops, d, m.motion, m.junctions, m.cue(d), m.lanes, m.per_hop)
    link = net.station_links[d.sensor_index]
    keep = (is_tail[i] >= 0) & (is_head[j] >= 0) & (link[i] != link[j])
    i, j, cost = i[keep], j[keep], cost[keep]
    weight = link_weights(hops, m.motion, d, i, j, cost)
    n = int(piece.max()) + 1
    rows, cols = match_sparse(is_tail[i], is_head[j], weight, n, n)
    return list(zip(rows.tolist(), cols.tolist()))
