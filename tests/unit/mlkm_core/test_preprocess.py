"""The paper's back-projection and its inverse."""

import numpy as np

from mlkm_core.preprocess import back_project, forward_project, preprocess
from mlkm_core.simulator import SimConfig, simulate
from mlkm_core.types import Detections, Layout


def test_paper_example():
    # S_2 reads V = 20 m/s, T = 50 s, R_2 - R_1 = 100: T' = 45 s
    assert back_project(np.array([50.0]), np.array([20.0]), np.array([200.0]), 100.0)[0] == 45.0


def test_round_trip():
    rng = np.random.default_rng(0)
    t, v, r = rng.uniform(-100, 900, 500), rng.uniform(5, 80, 500), rng.uniform(1, 5000, 500)
    back = back_project(t, v, r, 37.0)
    assert np.allclose(forward_project(back, v, r, 37.0), t)


def test_constant_speed_targets_collapse_to_their_time_at_the_first_sensor():
    ds = simulate(SimConfig(n_targets=15, n_sensors=12, velocity_variation=0.0), 2)
    d = ds.detections
    tp = preprocess(ds.layout, d)
    for tgt in range(ds.n_targets):
        m = d.target == tgt
        assert np.ptp(tp[m]) < 1e-6
        assert np.isclose(tp[m][d.sensor_index[m] == 0][0], d.stamp[m & (d.sensor_index == 0)][0])


def test_a_station_at_the_origin_and_negative_stamps_project_as_any_other():
    # a road is [0, road_length]: a station at 0, stamps measured from an event (negative)
    layout = Layout(500.0, np.array([0.0, 200.0, 500.0]))
    speed, at_origin = np.array([20.0, 25.0]), np.array([-30.0, -12.5])
    stamps = at_origin[:, None] + layout.positions[None, :] / speed[:, None]
    dets = Detections(
        np.tile(np.arange(3), 2), stamps.ravel(), np.repeat(speed, 3), np.repeat([0, 1], 3)
    )
    back = preprocess(layout, dets)
    assert np.allclose(back, np.repeat(at_origin, 3))
    position = layout.positions[dets.sensor_index]
    assert np.allclose(forward_project(back, dets.velocity, position, 0.0), dets.stamp)
