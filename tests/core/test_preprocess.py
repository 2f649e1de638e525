"""The paper's back-projection and its inverse."""

import numpy as np

from mlkm_core.preprocess import back_project, forward_project, preprocess
from mlkm_core.simulator import SimConfig, simulate


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
