"""What a junction does to a vehicle: which way it turns, and how long it may wait there.

Both are estimated from the links of a pass over the data being associated, per connection
``(from link, to link)`` of the network:

* **Turn shares.** P(the vehicle continues on link b | it reached the end of link a), from the
  links that cross each connection, with one pseudo-count per connection (a connection no
  link crossed keeps a share, and a junction seen by few links stays near uniform). A hop's
  turn cost is -log of the product of the shares of the connections it crosses.
* **Time lost at the junction.** A layout gives the links' lengths, not the way through the
  junction box between them (a few metres to tens of metres), nor the slowing for a turn, the
  wait at a red light or at a yielding merge, which differ from vehicle to vehicle: the mean
  and the variance of the excess travel time (over the motion model's prediction) of the
  links that cross the connection, and no other, are added to the travel time's. Their
  central ``signals.KEPT`` share counts (a first pass's few wrong links are not waits). One
  Gaussian, not a mixture of "through on green" and "held at red": its cost is convex in the travel
  time, so among vehicles held in one queue the matching keeps their order (first in, first
  out), which a mixture, flat over the red phase, would leave to chance. A hop with links
  enough gets its own time lost, which also holds a queue reaching back over a station inside
  a link. Where a junction shows a fixed-time signal (``signals``), each link's wait for its
  green and its queue's release are taken off first, and the Gaussian holds what is left.

Before anything is fitted (the first pass), every connection has equal shares and a generous
time lost (``GENERIC_LOSS``), so that no vehicle held at a red light is cut out of the links
the fit learns from; where the pairs of detections across a junction show its time lost
without links and no waiters beside it, the first pass takes that one (``pair_lags``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mlkm_core.network import RoadNetwork
from mlkm_core.network_assoc.signals import Signals, central

#: fewest links across a connection to fit its time lost from
MIN_LINKS = 8
#: (mean [s], variance [s^2]) of the time lost at every connection before the fit: a wait
#: uniform on [0, 90 s] half of the time
GENERIC_LOSS = (22.5, 0.5 * 90.0**2 / 3 - 22.5**2)


@dataclass(frozen=True)
class JunctionModel:
    """Turn shares and waits per connection (module docstring)."""

    shares: dict[tuple[int, int], float] = field(default_factory=dict)
    offsets: dict[tuple[int, int], float] = field(default_factory=dict)  # mean [s]
    spreads: dict[tuple[int, int], float] = field(default_factory=dict)  # variance [s^2]
    #: per hop (index into ``hops.Hops``) with links enough: (mean [s], variance [s^2]) of its
    #: own time lost, which also holds a queue that reaches back over a station
    hops: dict[int, tuple[float, float]] = field(default_factory=dict)
    #: the fixed-time signals learned from the links (``signals``): each link's wait for its
    #: green, taken off before the Gaussians above; None where none shows
    signals: Signals | None = None

    def lost(self, hop: int, turns: tuple[tuple[int, int], ...]) -> tuple[float, float]:
        """(mean [s], variance [s^2]) of the time lost on hop ``hop``: its own where fitted,
        else that of the junctions it crosses."""
        return self.hops[hop] if hop in self.hops else self.offset(turns)

    def turn_cost(self, turns: tuple[tuple[int, int], ...]) -> float:
        """-log P(the turns), [nats]."""
        return -sum(math.log(self.shares.get(c, 1.0)) for c in turns)

    def offset(self, turns: tuple[tuple[int, int], ...]) -> tuple[float, float]:
        """(mean [s], variance [s^2]) of the time lost at the junctions of a hop."""
        return (sum(self.offsets.get(c, 0.0) for c in turns),
                sum(self.spreads.get(c, 0.0) for c in turns))  # fmt: skip


def generic_junctions(net: RoadNetwork) -> JunctionModel:
    """Equal shares and the generic time lost at every connection."""
    out = net.link_successors
    shares = {(a, b): 1.0 / len(out[a]) for a, b in net.connections}
    mean, var = GENERIC_LOSS
    return JunctionModel(shares, dict.fromkeys(net.connections, mean),
                         dict.fromkeys(net.connections, var))  # fmt: skip


def fit_junctions(
    net: RoadNetwork,
    turns: list[tuple[tuple[int, int], ...]],
    excess: np.ndarray,
    sd: np.ndarray,
    hop: np.ndarray,
    signals: Signals | None = None,
) -> JunctionModel:
    """The junction model of the links of a pass: ``turns[k]`` the connections link k
    crossed, ``excess`` its travel-time residual [s] under the motion model without
    junctions (its wait at ``signals`` taken off), ``sd`` that model's standard deviation of
    it [s], ``hop`` the hop it took."""
    counts = dict.fromkeys(net.connections, 1.0)
    for crossed in turns:
        for c in crossed:
            counts[c] += 1.0
    out_total: dict[int, float] = {}
    for (a, _), n in counts.items():
        out_total[a] = out_total.get(a, 0.0) + n
    shares = {c: n / out_total[c[0]] for c, n in counts.items()}
    alone: dict[tuple[int, int], list[int]] = {c: [] for c in net.connections}
    for k, crossed in enumerate(turns):
        if len(crossed) == 1:
            alone[crossed[0]].append(k)
    offsets, spreads = {}, {}
    for c, ks in alone.items():
        if len(ks) >= MIN_LINKS:
            offsets[c], spreads[c] = _loss(excess[ks], sd[ks])
    per_hop = {}
    for h in np.unique(hop):
        ks = np.flatnonzero(hop == h)
        if ks.size >= MIN_LINKS:
            per_hop[int(h)] = _loss(excess[ks], sd[ks])
    return JunctionModel(shares, offsets, spreads, per_hop, signals)


def _loss(excess: np.ndarray, sd: np.ndarray) -> tuple[float, float]:
    """(mean, variance beyond the motion model's) of the central ``signals.KEPT`` of ``excess``."""
    mid = central(excess)
    return float(mid.mean()), max(float(mid.var()) - float(np.median(sd**2)), 0.0)
