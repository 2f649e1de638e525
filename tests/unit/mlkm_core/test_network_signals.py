"""Fixed-time signals on a network (``mlkm_core.network_assoc.signals``): the wait for a
green and a queue's releases computed by hand, the cycle and the green recovered from exit
times, a signal learned where there is one and none where there is not, and a hand-made
signal with irregular arrivals where the waits link more vehicles than a Gaussian time lost
alone."""

from __future__ import annotations

import numpy as np
import pytest
from test_network_assoc import detections, diverge, network

import mlkm_core.network_assoc.fit as fit
from mlkm_core.metrics import accuracy
from mlkm_core.network_assoc import network_hops
from mlkm_core.network_assoc.fit import calibrate_and_link
from mlkm_core.network_assoc.signals import (
    Approach,
    _gamma_tail,
    best_cycle,
    green_window,
    red_wait,
)


def test_the_wait_for_a_green_by_hand():
    # cycle 60 s, green from phase 30 s for 25 s
    arrive = np.array([30.0, 54.0, 56.0, 91.0, 125.0])
    assert red_wait(arrive, 60.0, 30.0, 25.0).tolist() == [0.0, 0.0, 34.0, 0.0, 25.0]


def test_a_queue_releases_first_in_first_out_a_headway_apart_on_green():
    # 100 m before the stop line at 10 m/s (10 s to it); green from phase 30 s for 20 s
    queue = Approach(station=0, lead=100.0, cycle=60.0, start=30.0, length=20.0, headway=2.0)
    stamps = np.array([12.0, 5.0, 13.0, 30.0, 45.0])
    got = queue.releases(stamps, np.full(5, 0.1))
    # the one seen at 5 s reaches the line at 15 s (red) and goes first at 30 s; 22 s and 23 s
    # follow 2 s apart; 40 s is on green; 55 s is past the green's end at 50 s: the next, 90 s
    assert got.tolist() == [32.0, 30.0, 34.0, 40.0, 90.0]


def test_the_cycle_and_the_green_from_exit_times():
    rng = np.random.default_rng(3)
    cycles = rng.integers(0, 12, 80)
    exits = 17.0 + 73.0 * cycles + rng.uniform(10.0, 40.0, 80)  # green 27-57 s of each
    period, chance = best_cycle([np.sort(exits)])
    assert period == pytest.approx(73.0, abs=0.3) and chance < 1e-6
    # the same number of exits at random times over the same span: no cycle stands out
    _, chance = best_cycle([np.sort(rng.uniform(0.0, 73.0 * 12, 80))])
    assert chance > 0.01
    start, length = green_window(np.mod(exits, 73.0), 73.0)
    assert start == pytest.approx(27.0, abs=1.5) and length == pytest.approx(30.0, abs=2.0)


def test_the_chance_of_a_cycle_in_random_exits_by_hand():
    # one connection: the Rayleigh statistic of random times is exponential with mean 1
    assert _gamma_tail(3.0, 1) == pytest.approx(np.exp(-3.0))
    # four: Gamma(4), P(X > 10) = exp(-10) (1 + 10 + 50 + 166.67)
    assert _gamma_tail(10.0, 4) == pytest.approx(np.exp(-10.0) * (1 + 10 + 50 + 1000 / 6))


def test_a_green_window_keeps_its_last_vehicles_and_drops_a_stray_one():
    # a green from 10 s, vehicles on two lanes 1 s apart to 40 s; one stray exit at 50 s (a
    # wrong link), one in 32
    phases = np.concatenate([np.arange(10.0, 40.5, 1.0), [50.0]])
    assert green_window(phases, 60.0) == (10.0, 30.0)


def irregular_signal(seed: int, n: int = 60):
    """A signal between links 0 and 1 (cycle 60 s, green from 30 s on); vehicles at random
    headways (1.5-9 s) and speeds (11-17 m/s), seen 200 m before the stop line and 100 m
    after it; a held vehicle leaves on green, 2 s after the one before it, at 8-8.2 m/s."""
    rng = np.random.default_rng(seed)
    net = network([(0, 400.0), (1, 400.0)], [(0, 1)], [(0, 200.0), (1, 100.0)])
    rows, leave, t0 = [], -np.inf, 0.0
    for k in range(n):
        t0 += rng.uniform(1.5, 9.0)
        v = rng.uniform(11.0, 17.0)
        arrive = t0 + 200.0 / v
        go = arrive if arrive % 60.0 >= 30.0 else arrive - arrive % 60.0 + 30.0
        leave = max(go, leave + 2.0)
        if leave % 60.0 < 30.0:
            leave += 30.0 - leave % 60.0
        speed = v if leave == arrive else 8.0 + 0.1 * k % 3
        rows.append([(0, t0, v), (1, leave + 100.0 / speed, speed)])
    return net, detections(rows)


def test_waits_for_the_green_link_more_vehicles_than_a_gaussian_time_lost(monkeypatch):
    new, old = [], []
    for seed in range(6):
        net, d = irregular_signal(seed)
        hops = network_hops(net, 2)
        labels, _ = calibrate_and_link(net, hops, d)
        new.append(accuracy(labels, d.target).accuracy)
        with monkeypatch.context() as m:
            m.setattr(fit, 'fit_signals', lambda *args: None)
            labels, _ = calibrate_and_link(net, hops, d)
        old.append(accuracy(labels, d.target).accuracy)
    assert all(a >= b for a, b in zip(new, old, strict=True)), (new, old)
    assert np.mean(new) > np.mean(old) + 0.05, (new, old)


def test_no_signal_where_no_vehicle_waits():
    # free flow through a diverge: 40 vehicles 5 s apart at 20-25 m/s
    rng = np.random.default_rng(1)
    rows = []
    for k in range(40):
        v, t = rng.uniform(20.0, 25.0), 5.0 * k
        branch = (2, 600.0) if k % 2 else (3, 700.0)
        rows.append([(0, t, v), (1, t + 500.0 / v, v), (branch[0], t + branch[1] / v, v)])
    net = diverge()
    _, model = calibrate_and_link(net, network_hops(net, 2), detections(rows))
    assert model.junctions.signals is None
