"""Targets seen first before they settle at their cruise speed: the fit of the change of their
speed level after the first sensor, and the track it keeps whole."""

from dataclasses import replace

import numpy as np
import pytest

from mlkm_core.associators.calibration import estimate_params
from mlkm_core.associators.likelihood import sequence_nll
from mlkm_core.model.motion import MotionParams
from mlkm_core.simulator import SimConfig, simulate
from mlkm_core.types import Detections, Layout

N_SENSORS = 12
SPACING = 300.0


def settling_traffic(seed: int, settle_prob: float, n: int = 100):
    """Vehicles every ~4 s at steady speeds, of which a share ``settle_prob`` passes the first
    sensor faster, by |N(0, 5^2)| m/s, and brakes to its speed at a uniform point of the first
    gap (a vehicle entering at its desired speed behind a slower leader); exact travel times,
    small measurement noise."""
    rng = np.random.default_rng(seed)
    layout = Layout(SPACING * (N_SENSORS + 1), SPACING * np.arange(1, N_SENSORS + 1))
    sensor, stamp, speed, target = [], [], [], []
    for k in range(n):
        v = rng.uniform(22, 30)
        first = v + abs(rng.normal(0, 5.0)) if rng.random() < settle_prob else v
        t = 4.0 * k + rng.uniform(0, 1.5) + SPACING / first
        for s in range(N_SENSORS):
            if s == 1:
                a = rng.uniform(0, SPACING)
                t += a / first + (SPACING - a) / v
            elif s > 1:
                t += SPACING / v
            sensor.append(s)
            stamp.append(t + rng.normal(0, 0.05))
            speed.append((first if s == 0 else v) + rng.normal(0, 0.1))
            target.append(k)
    return layout, Detections(np.array(sensor), np.array(stamp), np.array(speed), np.array(target))


def test_the_level_change_after_the_first_sensor_is_fitted_where_it_happens_and_off_where_not():
    layout, d = settling_traffic(2, settle_prob=0.3)
    p = estimate_params(layout, d)
    assert p.entry_jump == pytest.approx(0.3, rel=0.6)
    assert p.entry_sigma == pytest.approx(5.0, rel=0.6)
    # steady vehicles, and the simulator's targets, start at their cruise speed
    layout, d = settling_traffic(2, settle_prob=0.0)
    assert estimate_params(layout, d).entry_jump == 0.0
    ds = simulate(SimConfig(n_targets=50, n_sensors=20), 1)
    assert estimate_params(ds.layout, ds.detections).entry_jump == 0.0


def test_a_vehicle_braking_behind_its_leader_keeps_its_first_detection():
    """A vehicle passes the first sensor at 30.9 m/s and follows its leader at 23-25 m/s from
    the second one on (a single-lane SUMO road; its fitted model has slow fluctuations and
    rare, small jumps). Without the level change, its first detection is more likely a false
    alarm than the start of its track; with it, the whole track is."""
    x = np.array([361.0, 806.2, 913.1, 1123.2, 1248.9, 1528.7, 1917.7])
    t = np.array([211.14, 226.98, 231.35, 240.19, 245.57, 257.59, 274.33])
    v = np.array([30.88, 24.83, 24.07, 23.43, 23.45, 23.3, 23.15])
    layout, d = Layout(5000.0, x), Detections(np.arange(x.size), t, v)
    steady = MotionParams(
        sigma=1.2,
        length=9683.0,
        stamp_noise=0.0017,
        velocity_noise=0.013,
        p_miss=0.001,
        clutter_density=0.03,
        jump_rate=0.00046,
        jump_sigma=1.2,
    )
    whole = np.arange(x.size)[None, :]
    cut = np.array([[0, -1, -1, -1, -1, -1], [1, 2, 3, 4, 5, 6]])  # a false alarm, a track
    for p, kept in ((steady, False), (replace(steady, entry_jump=0.2, entry_sigma=4.0), True)):
        margin = sequence_nll(layout, d, cut, p).sum() - sequence_nll(layout, d, whole, p)[0]
        assert (margin > 5.0) if kept else (margin < -5.0)
