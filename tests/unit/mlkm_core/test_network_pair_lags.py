"""The first pass's time lost at junctions from every pair of detections across them
(``mlkm_core.network_assoc.pair_lags``): the pairs' excess by hand, the peak of a busy
junction where every vehicle loses about the same time, no peak where a red light holds
some of them or where too few pass, and the first pass of a long, busy input that links
more vehicles right with it than with the generic time lost."""

from __future__ import annotations

import numpy as np
import pytest
from test_network_assoc import detections, network

from mlkm_core.metrics import accuracy
from mlkm_core.model.motion import MotionParams
from mlkm_core.network_assoc import network_hops
from mlkm_core.network_assoc.junctions import GENERIC_LOSS, generic_junctions
from mlkm_core.network_assoc.linking import solve
from mlkm_core.network_assoc.pair_lags import pair_excess, pair_junctions, peak_loss

#: link 0 (600 m) into link 1 (600 m); stations 200 m before and 200 m after the junction
JUNCTION = ((0, 600.0), (1, 600.0)), ((0, 1),), ((0, 400.0), (1, 200.0))


def junction():
    links, connections, stations = JUNCTION
    return network(links, connections, stations)


def traffic(n: int, loss, seed: int = 1, headway: float = 2.0):
    """``n`` vehicles at random headways (exponential, mean ``headway`` [s]) and speeds
    (22-28 m/s, kept across the junction); ``loss(t, rng)``: the time [s] one that reaches
    the junction at ``t`` loses there."""
    rng = np.random.default_rng(seed)
    t0 = np.cumsum(rng.exponential(headway, n))
    v = rng.uniform(22.0, 28.0, n)
    rows = []
    for t, speed in zip(t0, v, strict=True):
        at = t + 200.0 / speed
        rows.append([(0, t, speed), (1, at + loss(at, rng) + 200.0 / speed, speed)])
    return detections(rows)


def test_the_pairs_across_a_hop_and_their_excess_by_hand():
    # 400 m at 20 m/s: 20 s predicted; two vehicles 10 s apart, each losing 1 s
    d = detections([[(0, 0.0, 20.0), (1, 21.0, 20.0)], [(0, 10.0, 20.0), (1, 31.0, 20.0)]])
    hops = network_hops(junction(), 1)
    (h,) = np.flatnonzero((hops.src == 0) & (hops.dst == 1))
    excess, pred = pair_excess(hops, d, int(h))
    # 0 -> 21 and 10 -> 31 (one vehicle each), 0 -> 31 and 10 -> 21 (two)
    assert sorted(excess.tolist()) == pytest.approx([-9.0, 1.0, 1.0, 11.0])
    assert pred.tolist() == pytest.approx([20.0] * 4)


def test_a_busy_junction_where_every_vehicle_loses_about_3_s_shows_that_peak():
    d = traffic(1500, lambda t, rng: rng.normal(3.0, 0.5))
    hops = network_hops(junction(), 1)
    (h,) = np.flatnonzero((hops.src == 0) & (hops.dst == 1))
    mean, var = peak_loss(*pair_excess(hops, d, int(h)))
    assert mean == pytest.approx(3.0, abs=0.5)
    # the bins' width (2 s) and the loss's own spread, nothing like the generic loss's
    assert 0.3 < var < 4.0 < GENERIC_LOSS[1]
    model = pair_junctions(junction(), hops, d)
    assert model.offsets[(0, 1)] == mean and model.spreads[(0, 1)] == var


def red_light(t: float, rng) -> float:
    """A fixed-time signal: cycle 60 s, red for its first 30 s; no queue."""
    phase = t % 60.0
    return 30.0 - phase if phase < 30.0 else 0.0


def test_a_red_lights_waiters_keep_the_generic_time_lost():
    # half the vehicles go through on green (no time lost: a peak at 0 s), the others wait
    # 0-30 s for it: waiters beyond the peak, so the peak is not the time lost
    d = traffic(1500, red_light)
    hops = network_hops(junction(), 1)
    (h,) = np.flatnonzero((hops.src == 0) & (hops.dst == 1))
    assert peak_loss(*pair_excess(hops, d, int(h))) is None
    model = pair_junctions(junction(), hops, d)
    assert model == generic_junctions(junction())


def test_too_few_vehicles_show_no_peak():
    d = traffic(3, lambda t, rng: 3.0)
    hops = network_hops(junction(), 1)
    assert pair_junctions(junction(), hops, d) == generic_junctions(junction())
    assert peak_loss(np.zeros(0), np.zeros(0)) is None


def test_on_a_long_busy_input_the_first_pass_links_more_with_the_pairs_peak():
    # an hour at a vehicle every 2 s, each losing 0.5-1.5 s: with the generic time lost
    # (up to 90 s) every detection has about 45 competitors inside its gate
    d = traffic(1800, lambda t, rng: rng.uniform(0.5, 1.5))
    net = junction()
    hops = network_hops(net, 1)
    generic, _ = solve(hops, d, MotionParams(), generic_junctions(net))
    pairs, _ = solve(hops, d, MotionParams(), pair_junctions(net, hops, d))
    assert accuracy(pairs, d.target).accuracy > accuracy(generic, d.target).accuracy + 0.1
