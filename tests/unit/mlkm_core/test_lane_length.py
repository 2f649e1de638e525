"""Lane and vehicle length in the associators: hand-made traffic where they decide, the fit of
their parameters, and the speed-jump part of the traffic model."""

import math
import warnings

import numpy as np
import pytest

from mlkm_core.associators import AssociatorConfig, available_methods, kalman_fit, make_associator
from mlkm_core.associators.base import DegradedResultWarning, canonical_order
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.associators.linking import link, merge_double_reports, relabel
from mlkm_core.associators.multiframe import FIT_MARGIN
from mlkm_core.associators.pairwise_fit import kalman_lead
from mlkm_core.associators.repair import repaired
from mlkm_core.metrics import accuracy
from mlkm_core.model import lane, length
from mlkm_core.model.motion import MotionParams
from mlkm_core.simulator import SimConfig, simulate
from mlkm_core.types import Detections, Layout

N_SENSORS = 12
SPACING = 200.0
LENGTHS = np.array([4.0, 4.6, 5.1, 6.5, 12.0, 16.5])


def background(n: int, seed: int, change_prob: float = 0.0, length_noise: float = 0.0):
    """Free-flow vehicles every ~8 s at steady speeds, each in a lane with a fixed length.

    Returns (layout, columns) with columns sensor, stamp, speed, target, lane, length."""
    rng = np.random.default_rng(seed)
    layout = Layout(SPACING * (N_SENSORS + 1), SPACING * np.arange(1, N_SENSORS + 1))
    cols = {k: [] for k in ('sensor', 'stamp', 'speed', 'target', 'lane', 'length')}
    for k in range(n):
        t = 8.0 * k + rng.uniform(0, 2)
        v = rng.uniform(25, 35)
        lane = int(rng.integers(0, 3))
        size = float(rng.choice(LENGTHS))
        for s, x in enumerate(layout.positions):
            if s and rng.random() < change_prob:
                lane = int(np.clip(lane + rng.choice([-1, 1]), 0, 2))
            cols['sensor'].append(s)
            cols['stamp'].append(t + x / v + rng.normal(0, 0.05))
            cols['speed'].append(v + rng.normal(0, 0.2))
            cols['target'].append(k)
            cols['lane'].append(lane)
            cols['length'].append(size + rng.normal(0, length_noise) if length_noise else size)
    return layout, cols


def detections(cols, lane: bool = True, length: bool = True) -> Detections:
    return Detections(
        np.array(cols['sensor']),
        np.array(cols['stamp']),
        np.array(cols['speed']),
        np.array(cols['target']),
        np.array(cols['lane']) if lane else None,
        np.array(cols['length']) if length else None,
    )


def swapping_pair(cols, first_target: int, swap_at: int) -> None:
    """Two vehicles at the same speed 0.1 s apart in the same lane, a car and a truck; at
    sensor ``swap_at`` their passage times are exchanged (the order swaps there only)."""
    v = 30.0
    t0 = 500.0
    for k, (gap, size) in enumerate(((0.0, 4.6), (0.1, 16.5))):
        for s in range(N_SENSORS):
            x = SPACING * (s + 1)
            own = gap if s != swap_at else 0.1 - gap
            cols['sensor'].append(s)
            cols['stamp'].append(t0 + own + x / v)
            cols['speed'].append(v)
            cols['target'].append(first_target + k)
            cols['lane'].append(1)
            cols['length'].append(size)


def labels_of_pair(method: str, with_length: bool) -> tuple[np.ndarray, np.ndarray]:
    layout, cols = background(40, 1)
    swapping_pair(cols, 40, swap_at=6)
    d = detections(cols, lane=True, length=with_length)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DegradedResultWarning)
        labels = make_associator(method).associate(layout, d, 42)
    pair = d.target >= 40
    return labels[pair], d.target[pair]


@pytest.mark.parametrize('method', ['assignment', 'multiframe', 'mlkm_robust'])
def test_order_swap_separable_only_by_length(method):
    labels, target = labels_of_pair(method, with_length=True)
    # with length: the car and the truck are two clean tracks of 12 detections each
    assert accuracy(labels, target).correct == 2 * N_SENSORS
    assert len(set(labels[target == 40])) == 1 and len(set(labels[target == 41])) == 1
    # control, the same stamps and speeds without length: the swap is taken as no swap
    labels, target = labels_of_pair(method, with_length=False)
    assert accuracy(labels, target).correct < 2 * N_SENSORS


@pytest.mark.parametrize('method', ['assignment', 'multiframe'])
def test_lane_change_between_two_stations_keeps_the_track(method):
    layout, cols = background(40, 2)
    # vehicle 7 moves from its lane to the next between sensors 5 and 6; a vehicle of the same
    # length is in the new lane 0.6 s later at every sensor (a tempting wrong link)
    lanes = np.array(cols['lane'])
    own = np.array(cols['target']) == 7
    new_lane = (lanes[own][0] + 1) % 3
    lanes[own & (np.array(cols['sensor']) >= 6)] = new_lane
    cols['lane'] = lanes.tolist()
    stamp = np.array(cols['stamp'])[own]
    speed = np.array(cols['speed'])[own]
    size = np.array(cols['length'])[own][0]
    for s in range(N_SENSORS):
        cols['sensor'].append(s)
        cols['stamp'].append(stamp[s] + 0.6 + 0.2 * (s >= 6))
        cols['speed'].append(speed[s] - 0.3)
        cols['target'].append(40)
        cols['lane'].append(int(new_lane))
        cols['length'].append(float(size))
    d = detections(cols)
    labels = make_associator(method).associate(layout, d, 41)
    assert len(set(labels[d.target == 7])) == 1
    assert len(set(labels[d.target == 40])) == 1
    assert labels[d.target == 7][0] != labels[d.target == 40][0]
    assert accuracy(labels, d.target).accuracy == 1.0


@pytest.mark.parametrize('method', ['assignment', 'multiframe', 'mlkm_robust'])
def test_double_report_of_a_lane_change_on_a_station_keeps_the_track(method):
    layout, cols = background(40, 7)
    # vehicle 9 changes lane on top of sensor 5: the old lane's loop reports it too (a false
    # alarm with the same stamp, speed and length), the new lane carries on downstream
    lanes = np.array(cols['lane'])
    own = np.array(cols['target']) == 9
    sensor = np.array(cols['sensor'])
    old = int(lanes[own][0])
    new_lane = 1 if old != 1 else 2
    lanes[own & (sensor >= 5)] = new_lane
    cols['lane'] = lanes.tolist()
    at5 = np.flatnonzero(own & (sensor == 5))[0]
    for key, value in (('sensor', 5), ('target', -1), ('lane', old)):
        cols[key].append(value)
    for key in ('stamp', 'speed', 'length'):
        cols[key].append(cols[key][at5])
    d = detections(cols)
    labels = make_associator(method).associate(layout, d, 40)
    assert len(set(labels[d.target == 9])) == 1
    assert accuracy(labels, d.target).accuracy == 1.0


def twin_reports(speed: float, late: float, speed_change: float) -> Detections:
    """One car (4.5 m) at constant ``speed`` past sensors 0, 1, 2, changing from lane 0 to
    lane 1 on top of sensor 1, where the new lane's loop reports it ``late`` s after the old
    one, ``speed_change`` m/s faster (detection 3, a false alarm)."""
    t = np.array([0.0, 100.0, 200.0]) / speed
    return Detections(
        np.array([0, 1, 2, 1]),
        np.array([*t, t[1] + late]),
        np.array([speed, speed, speed, speed + speed_change]),
        np.array([0, 0, 0, -1]),
        np.array([0, 0, 1, 1]),
        np.full(4, 4.5),
    )


def test_the_report_left_alone_joins_its_twins_track():
    p = MotionParams(stamp_noise=0.05, velocity_noise=0.2)
    d = twin_reports(30.0, 0.05, 0.1)
    # the track went on from the old lane's report; the new lane's report is alone
    np.testing.assert_array_equal(merge_double_reports(d, np.array([7, 7, 7, 8]), p), [7] * 4)
    # the track ended on the old lane's report and the new lane's carried on
    np.testing.assert_array_equal(merge_double_reports(d, np.array([7, 7, 8, 8]), p), [7] * 4)


def test_a_slow_vehicles_twin_reports_may_be_far_apart():
    p = MotionParams(stamp_noise=0.05, velocity_noise=0.2)
    labels = np.array([7, 7, 7, 8])
    # at 5 m/s the 4.5 m car covers its length in 0.9 s and may brake or accelerate meanwhile
    slow = merge_double_reports(twin_reports(5.0, 0.7, 1.2), labels, p)
    np.testing.assert_array_equal(slow, [7] * 4)
    # at 30 m/s, 0.7 s apart are two vehicles (a car covers its length in 0.15 s)
    fast = merge_double_reports(twin_reports(30.0, 0.7, 0.1), labels, p)
    np.testing.assert_array_equal(fast, labels)
    # a vehicle braking to merge into a queue: 7.1 -> 5.3 m/s between reports 0.48 s apart
    # (3.75 m/s^2) with speeds measured to 0.05 m/s; braking twice as hard is not one vehicle
    exact = MotionParams(stamp_noise=0.05, velocity_noise=0.05)
    braking = merge_double_reports(twin_reports(7.1, 0.48, -1.8), labels, exact)
    np.testing.assert_array_equal(braking, [7] * 4)
    harder = merge_double_reports(twin_reports(7.1, 0.48, -3.6), labels, exact)
    np.testing.assert_array_equal(harder, labels)
    # in adjacent lanes only
    far = twin_reports(5.0, 0.1, 0.1)
    far.lane[3] = 2
    np.testing.assert_array_equal(merge_double_reports(far, labels, p), labels)


@pytest.mark.parametrize(('noise', 'change'), [(0.3, 0.05), (0.6, 0.15)])
def test_fit_recovers_length_noise_and_lane_change_probability(noise, change):
    layout, cols = background(150, 3, change_prob=change, length_noise=noise)
    d = detections(cols)
    fit = length.fit(layout, d, d.target)
    assert fit.length_noise == pytest.approx(noise, rel=0.15)
    assert fit.length_outlier == pytest.approx(1e-3)
    fit = lane.fit(layout, d, d.target)
    # a change to a clipped lane (0 -> -1, 2 -> 3) is no change: 1/3 of the draws at the edges
    effective = change * (1 - 2 / 3 * 0.5)
    assert fit.change_rate * SPACING == pytest.approx(effective, rel=0.3)
    assert np.median(fit.change) == pytest.approx(effective, rel=0.4)


def jumpy_traffic(seed: int, jump_prob: float, jump_sigma: float):
    """Steady speeds that jump (probability ``jump_prob`` per 200 m gap, N(0, jump_sigma^2))
    at a uniform point between two sensors; exact travel times, small measurement noise."""
    rng = np.random.default_rng(seed)
    layout = Layout(SPACING * (N_SENSORS + 1), SPACING * np.arange(1, N_SENSORS + 1))
    sensor, stamp, speed, target = [], [], [], []
    for k in range(120):
        t = 6.0 * k
        v = rng.uniform(24, 34)
        for s in range(N_SENSORS):
            if s:
                if rng.random() < jump_prob:
                    a = rng.uniform(0, SPACING)
                    v2 = float(np.clip(v + rng.normal(0, jump_sigma), 10, 45))
                    t += a / v + (SPACING - a) / v2
                    v = v2
                else:
                    t += SPACING / v
            else:
                t += SPACING / v
            sensor.append(s)
            stamp.append(t + rng.normal(0, 0.05))
            speed.append(v + rng.normal(0, 0.1))
            target.append(k)
    return layout, Detections(np.array(sensor), np.array(stamp), np.array(speed), np.array(target))


def test_speed_jumps_are_fitted_where_they_happen_and_off_where_not():
    layout, d = jumpy_traffic(4, jump_prob=0.1, jump_sigma=4.0)
    p = estimate_params(layout, d)
    rate = -math.log(1 - 0.1) / SPACING
    assert p.jump_rate == pytest.approx(rate, rel=0.6)
    assert p.jump_sigma == pytest.approx(4.0, rel=0.5)
    assert p.stamp_noise == pytest.approx(0.05, rel=0.5)
    # the simulator's traffic has no jumps: the pure OU model is kept
    ds = simulate(SimConfig(n_targets=50, n_sensors=20), 1)
    assert estimate_params(ds.layout, ds.detections).jump_rate == 0.0


def drifting_traffic(seed: int, drift: float, headway: float = 5.0):
    """Vehicles every ``headway`` s whose cruise speed drifts (a random walk, std ``drift`` m/s
    per km) with a fluctuation of 1 m/s around it, past 30 sensors 200 m apart (the drift
    shows over a few km); exact travel times, small measurement noise."""
    rng = np.random.default_rng(seed)
    n_sensors = 30
    layout = Layout(SPACING * (n_sensors + 1), SPACING * np.arange(1, n_sensors + 1))
    step = drift * math.sqrt(SPACING / 1000)
    sensor, stamp, speed, target = [], [], [], []
    for k in range(150):
        t = headway * k
        cruise = rng.uniform(24, 34)
        v = cruise
        for s in range(n_sensors):
            t += SPACING / v
            sensor.append(s)
            stamp.append(t + rng.normal(0, 0.05))
            speed.append(v + rng.normal(0, 0.1))
            target.append(k)
            cruise = float(np.clip(cruise + rng.normal(0, step), 8, 50))
            v = cruise + rng.normal(0, 1.0)
    return layout, Detections(np.array(sensor), np.array(stamp), np.array(speed), np.array(target))


def test_cruise_speed_drift_is_fitted_where_it_happens_and_off_where_not():
    layout, d = drifting_traffic(3, drift=4.0)
    assert estimate_params(layout, d).drift == pytest.approx(4.0, rel=0.5)
    # the simulator's targets keep their cruise speed: no drift
    ds = simulate(SimConfig(n_targets=50, n_sensors=20), 1)
    assert estimate_params(ds.layout, ds.detections).drift == 0.0


def test_assignment_gains_from_the_jumps(monkeypatch):
    layout, d = jumpy_traffic(5, jump_prob=0.15, jump_sigma=5.0)
    with_jumps = accuracy(make_associator('assignment').associate(layout, d, 120), d.target)
    monkeypatch.setattr(kalman_fit, '_fit_jumps', lambda layout, d, seqs, p, bounds: p)
    pure_ou = accuracy(make_associator('assignment').associate(layout, d, 120), d.target)
    assert with_jumps.accuracy > 0.98
    assert with_jumps.correct > pure_ou.correct


def test_the_jumps_are_what_makes_the_kalman_model_fit_jumpy_traffic(monkeypatch):
    """Without its speed jumps the Kalman model predicts the links of jumpy traffic far worse
    than the pairwise model (``multiframe`` then searches under the pairwise model's Markov
    chain); with them it fits, and ``multiframe`` searches under it."""
    layout, d = jumpy_traffic(5, jump_prob=0.15, jump_sigma=5.0)
    c = d.subset(canonical_order(d))

    def lead() -> float:
        p = estimate_params(layout, c)
        return kalman_lead(
            layout, c, relabel(repaired(layout, c, link(layout, c, p, 'pairwise'), p)), p
        )

    assert lead() < FIT_MARGIN
    with_jumps = accuracy(make_associator('multiframe').associate(layout, d, 120), d.target)
    assert with_jumps.accuracy > 0.98
    monkeypatch.setattr(kalman_fit, '_fit_jumps', lambda layout, d, seqs, p, bounds: p)
    assert lead() > 5 * FIT_MARGIN


@pytest.mark.parametrize('method', available_methods())
def test_batch_equals_incremental_with_lane_and_length(method):
    layout, cols = background(25, 6, change_prob=0.05, length_noise=0.3)
    d = detections(cols)
    assoc = make_associator(method, AssociatorConfig(segment_size=4, seed=1))
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DegradedResultWarning)
        batch = assoc.associate(layout, d, 25)
        inc = assoc.associate_incrementally(layout, d, 25)
    np.testing.assert_array_equal(batch, inc)
