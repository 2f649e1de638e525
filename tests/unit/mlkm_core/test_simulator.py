"""Simulator invariants (Algorithm 1) and the clutter knobs' statistics."""

import math

import numpy as np
import pytest

from mlkm_core.simulator import SimConfig, simulate, simulate_episodes, time_window
from mlkm_core.types import FALSE_ALARM


def _by_target(ds):
    d = ds.detections
    out = {}
    for tgt in np.unique(d.target):
        m = d.target == tgt
        out[int(tgt)] = (d.sensor_index[m], d.stamp[m])
    return out


@pytest.mark.parametrize('n_targets,n_sensors,seed', [(10, 10, 0), (50, 20, 7), (30, 45, 3)])
def test_one_detection_per_target_per_sensor_and_monotone_times(n_targets, n_sensors, seed):
    ds = simulate(SimConfig(n_targets=n_targets, n_sensors=n_sensors), seed)
    d = ds.detections
    assert len(d) == n_targets * n_sensors
    counts = np.zeros((n_targets, n_sensors), int)
    np.add.at(counts, (d.target, d.sensor_index), 1)
    assert np.all(counts == 1)
    for sensors, stamps in _by_target(ds).values():
        order = np.argsort(sensors)
        assert np.all(np.diff(stamps[order]) > 0)
    # detections are sorted by (sensor_index, stamp)
    key = np.lexsort((d.stamp, d.sensor_index))
    assert np.array_equal(key, np.arange(len(d)))


def test_positions_unique_inside_road_and_targets_overtake():
    cfg = SimConfig()
    ds = simulate(cfg, 11)
    pos = ds.layout.positions
    assert np.unique(pos).size == pos.size == cfg.n_sensors
    assert pos.min() > 0 and pos.max() < cfg.road_length
    # the order in which targets pass differs between the first and the last sensor
    d = ds.detections
    first = d.target[d.sensor_index == 0]
    last = d.target[d.sensor_index == cfg.n_sensors - 1]
    assert not np.array_equal(first, last)


def test_reproducible_with_seed():
    a, b, c = (simulate(SimConfig(), s) for s in (5, 5, 6))
    for f in ('sensor_index', 'stamp', 'velocity', 'target'):
        assert np.array_equal(getattr(a.detections, f), getattr(b.detections, f))
    assert np.array_equal(a.layout.positions, b.layout.positions)
    assert not np.array_equal(a.detections.stamp, c.detections.stamp)


def test_cruise_speed_is_normal_with_variance_40():
    # without fluctuation every target keeps v0 ~ N(50, 40): the paper's N(mu, sigma^2)
    ds = simulate(SimConfig(n_targets=4000, n_sensors=2, velocity_variation=0.0), 1)
    d = ds.detections
    v0 = d.velocity[d.sensor_index == 0]
    assert np.allclose(np.sort(v0), np.sort(d.velocity[d.sensor_index == 1]))
    assert abs(v0.mean() - 50.0) < 0.4
    assert abs(v0.std() - math.sqrt(40.0)) < 0.3


def test_start_increments_can_be_negative():
    ds = simulate(SimConfig(n_targets=200, n_sensors=2, velocity_variation=0.0), 2)
    d = ds.detections
    s0 = d.sensor_index == 0
    # target ids are in entry order; with U(-10, 30) increments some enter before predecessors
    t_entry = d.stamp[s0] - ds.layout.positions[0] / d.velocity[s0]
    order = np.argsort(d.target[s0])
    inc = np.diff(t_entry[order])
    assert inc.min() < 0 and inc.max() > 20
    assert np.all((inc > -10 - 1e-9) & (inc < 30 + 1e-9))


def test_miss_and_false_alarm_rates_within_statistical_bounds():
    n, s, p, rate = 500, 40, 0.1, 0.05
    cfg = SimConfig(n_targets=n, n_sensors=s, miss_probability=p, false_alarm_rate=rate)
    d = simulate(cfg, 3).detections
    true = d.target != FALSE_ALARM
    passages = n * s
    miss = 1 - true.sum() / passages
    assert abs(miss - p) < 4 * math.sqrt(p * (1 - p) / passages)
    n_fa = int((~true).sum())
    expected = rate * n * s
    assert abs(n_fa - expected) < 4 * math.sqrt(expected)
    # false alarms fall inside the time span of each sensor's true traffic
    for k in range(s):
        at = d.sensor_index == k
        lo, hi = d.stamp[at & true].min() - 60, d.stamp[at & true].max() + 60
        assert np.all((d.stamp[at & ~true] >= lo) & (d.stamp[at & ~true] <= hi))


def test_measurement_noise_has_the_configured_std():
    clean = simulate(SimConfig(n_targets=300, n_sensors=30), 4).detections
    noisy = simulate(
        SimConfig(n_targets=300, n_sensors=30, stamp_noise=0.2, velocity_noise=0.5), 4
    ).detections

    def aligned(d):
        o = np.lexsort((d.target, d.sensor_index))
        return d.stamp[o], d.velocity[o]

    (t0, v0), (t1, v1) = aligned(clean), aligned(noisy)
    assert abs(np.std(t1 - t0) - 0.2) < 0.01
    assert abs(np.std(v1 - v0) - 0.5) < 0.02


def test_episodes_share_layout_and_do_not_overlap():
    cfg = SimConfig(n_targets=20, n_sensors=8)
    eps = simulate_episodes(cfg, 9, 4, gap=5.0)
    first = simulate(cfg, 9)
    assert np.array_equal(eps[0].detections.stamp, first.detections.stamp)
    for a, b in zip(eps, eps[1:]):
        assert b.layout is eps[0].layout
        assert time_window(b)[0] == pytest.approx(time_window(a)[1] + 5.0)
    assert not np.array_equal(np.diff(eps[1].detections.stamp), np.diff(eps[2].detections.stamp))


@pytest.mark.parametrize(
    'bad',
    [
        dict(road_length=0),
        dict(miss_probability=1.0),
        dict(false_alarm_rate=-1),
        dict(start_increment_min=40),
    ],
)
def test_invalid_config_rejected(bad):
    with pytest.raises(ValueError):
        SimConfig(**bad)
