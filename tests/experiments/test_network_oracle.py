"""``python -m mlkm_experiments.network_oracle``: the true links of a hand-made diverge, each
with the hop between its stations."""

from __future__ import annotations

import numpy as np

from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_core.network_assoc import network_hops
from mlkm_core.types import Detections
from mlkm_experiments.network_oracle import true_links


def test_the_true_links_and_their_hops_on_a_diverge():
    net = RoadNetwork(
        links=(RoadLink(0, 'l0', 1000.0), RoadLink(1, 'l1', 600.0), RoadLink(2, 'l2', 600.0)),
        connections=((0, 1), (0, 2)),
        station_ids=np.arange(4),
        station_names=('s0', 's1', 's2', 's3'),
        station_links=np.array([0, 0, 1, 2]),
        station_offsets=np.array([300.0, 800.0, 200.0, 300.0]),
    )
    hops = network_hops(net, 2)
    # vehicle 0: stations 0, 1, 2; vehicle 1: station 0, then 3 (station 1 missed); rows mixed
    d = Detections(
        np.array([3, 0, 1, 0, 2]),
        np.array([42.0, 0.0, 25.0, 2.0, 45.0]),
        np.full(5, 20.0),
        np.array([1, 0, 0, 1, 0]),
    )
    links = true_links(hops, d)
    got = {
        (int(a), int(b)): (int(hops.src[h]), int(hops.dst[h]), int(hops.skipped[h]))
        for a, b, h in zip(links.a, links.b, links.hop, strict=True)
    }
    assert got == {(1, 2): (0, 1, 0), (2, 4): (1, 2, 0), (3, 0): (0, 3, 1)}
