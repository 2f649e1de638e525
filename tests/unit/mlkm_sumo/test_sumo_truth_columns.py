"""What a live source needs beside the detections: the SUMO vehicle behind each detection,
its speed before measurement noise, and the road of a seed without running SUMO."""

from __future__ import annotations

import numpy as np

from mlkm_sumo import MeasurementConfig, generate, road
from mlkm_sumo.measurement import DOUBLE_REPORT, FALSE_ALARM, PASSAGE


def test_every_detection_names_its_vehicle_and_true_speed() -> None:
    noise = MeasurementConfig(speed_noise=1.0, false_alarm_rate=200.0)
    ds = generate('highway', n_vehicles=25, n_stations=4, seed=2, measurement=noise)
    d, kind = ds.detections, ds.kind
    assert ds.vehicle.shape == ds.true_speed.shape == (len(d),)
    real = kind == PASSAGE
    assert [ds.vehicle_ids[t] for t in d.target[real]] == ds.vehicle[real].tolist()
    assert all(v == '' for v in ds.vehicle[kind == FALSE_ALARM])
    assert (kind == FALSE_ALARM).sum() > 0
    assert all(v.startswith('v') for v in ds.vehicle[kind == DOUBLE_REPORT])
    assert (d.target[kind != PASSAGE] == -1).all()
    # Measured = true + N(0, 1 m/s): the difference has about unit spread.
    diff = (d.velocity - ds.true_speed)[real]
    assert 0.7 < diff.std() < 1.3
    # Without noise the two agree exactly.
    clean = generate('highway', n_vehicles=5, n_stations=2, seed=2)
    assert np.array_equal(clean.detections.velocity, clean.true_speed)


def test_road_of_a_seed_is_the_datasets_road() -> None:
    ds = generate('ramps', n_vehicles=3, n_stations=6, seed=4)
    r = road('ramps', 6, 4)
    assert np.array_equal(r.layout.positions, ds.layout.positions)
    assert np.array_equal(r.lanes, ds.road.lanes)
    assert [p.position for p in r.ramps] == [1200.0, 2300.0, 3200.0, 4300.0]
