"""Each hop with links enough gets a motion fit of its own (``network_assoc.fit``): on a
hand-made junction where every vehicle changes its speed by several m/s (an acceleration
lane, a merge), the motion fitted on the steady hops before it expects almost no change, and
links the vehicles by speed instead of by time; the hop's own fit links them by time."""

from __future__ import annotations

import numpy as np

from mlkm_core.metrics import score
from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_core.network_assoc import MAX_SKIP, network_hops
from mlkm_core.network_assoc.fit import calibrate_and_link
from mlkm_core.network_assoc.linking import solve
from mlkm_core.types import Detections

NET = RoadNetwork(
    links=(RoadLink(0, 'in', 1000.0), RoadLink(1, 'out', 800.0)),
    connections=((0, 1),),
    station_ids=np.array([0, 1, 2]),
    station_names=('s0', 's1', 's2'),
    station_links=np.array([0, 0, 1]),
    station_offsets=np.array([200.0, 800.0, 300.0]),
)


def speed_change_at_the_junction(n: int, seed: int) -> Detections:
    """``n`` vehicles 1-3 s apart at about 25 m/s on link 0; beyond the junction each one
    changes its speed by N(0, 5 m/s)."""
    rng = np.random.default_rng(seed)
    rows, t = [], 0.0
    for k in range(n):
        t += rng.uniform(1.0, 3.0)
        v = 25.0 + rng.normal(0, 1.0)
        t1 = t + 600.0 / v + rng.normal(0, 0.05)
        v2 = v + rng.normal(0, 5.0)
        t2 = t1 + 500.0 / ((v + v2) / 2) + rng.normal(0, 0.05)
        rows += [(0, t, v + rng.normal(0, 0.1), k), (1, t1, v + rng.normal(0, 0.1), k),
                 (2, t2, v2, k)]  # fmt: skip
    s, tt, vv, kk = (np.array(c) for c in zip(*rows, strict=True))
    return Detections(s.astype(np.int64), tt, vv, kk.astype(np.int64))


def test_the_hop_across_the_junction_links_with_its_own_motion_fit():
    d = speed_change_at_the_junction(150, seed=1)
    hops = network_hops(NET, MAX_SKIP)
    labels, model = calibrate_and_link(NET, hops, d)
    junction = next(h for h in range(hops.size) if hops.turns[h] and hops.skipped[h] == 0)
    plain = next(h for h in range(hops.size) if not hops.turns[h] and hops.skipped[h] == 0)
    assert set(model.per_hop) == {junction, plain}
    # the speed changes the junction's fit expects are far wider than the steady hop's
    wide, steady = model.per_hop[junction], model.per_hop[plain]
    assert wide.sigma**2 / wide.length + wide.jump_rate * wide.jump_sigma**2 > 10 * (
        steady.sigma**2 / steady.length + steady.jump_rate * steady.jump_sigma**2
    )
    assert score(d, labels).accuracy > 0.9
    # the same model without the hops' own fits: the junction is linked by speed
    without, _ = solve(hops, d, model.motion, model.junctions, model.cue(d), model.lanes)
    assert score(d, without).accuracy < 0.8
