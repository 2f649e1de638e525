"""MLKM: the three error-detection rules, the correction, a known scenario, seeded accuracy."""

import numpy as np
import pytest

from mlkm_core.associators import AssociatorConfig, make_associator
from mlkm_core.associators.mlkm import correct_errors, detect_errors
from mlkm_core.metrics import accuracy
from mlkm_core.simulator import SimConfig, simulate
from mlkm_core.types import Detections, Layout


def test_rule1_cluster_size():
    # cluster 0 misses sensor 2, cluster 2 holds only sensor 2's second detection
    sensor = np.array([0, 1, 0, 1, 2, 2])
    stamp = np.array([0.0, 1.0, 10.0, 11.0, 12.0, 2.0])
    labels = np.array([0, 0, 1, 1, 1, 2])
    rep = detect_errors(sensor, stamp, labels)
    assert rep.size == {0, 1, 2}
    assert rep.duplicate == set() and rep.order == set()


def test_rule2_two_detections_of_one_sensor():
    sensor = np.array([0, 1, 1, 2, 0, 2])
    stamp = np.array([0.0, 1.0, 1.5, 2.0, 10.0, 12.0])
    labels = np.array([0, 0, 0, 0, 1, 1])
    rep = detect_errors(sensor, stamp, labels)
    assert rep.duplicate == {1}
    assert rep.size == {1}
    assert rep.order == set()


def test_rule3_time_going_backwards_flags_the_downstream_sensor():
    sensor = np.array([0, 1, 2, 0, 1, 2])
    stamp = np.array([5.0, 4.0, 6.0, 10.0, 11.0, 12.0])
    labels = np.array([0, 0, 0, 1, 1, 1])
    rep = detect_errors(sensor, stamp, labels)
    assert rep.order == {1}
    assert rep.size == set() and rep.duplicate == set()
    assert rep.flagged == {1}


def test_correct_clustering_flags_nothing():
    sensor = np.array([0, 1, 2, 0, 1, 2])
    stamp = np.array([0.0, 2.0, 4.0, 1.0, 3.0, 5.0])
    rep = detect_errors(sensor, stamp, np.array([0, 0, 0, 1, 1, 1]))
    assert rep.flagged == set()


def test_correction_reassociates_flagged_sensor_by_predicted_arrival():
    positions = np.array([100.0, 200.0, 300.0])
    # targets a (t = 0, 2, 4) and b (t = 1, 3, 5), both at 50 m/s; layer 1 put both of
    # sensor 1's detections in cluster 0
    sensor = np.array([0, 0, 1, 1, 2, 2])
    stamp = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    velocity = np.full(6, 50.0)
    labels = np.array([0, 1, 0, 0, 0, 1])
    rep = detect_errors(sensor, stamp, labels)
    assert rep.flagged == {1}
    fixed = correct_errors(positions, sensor, stamp, velocity, labels, rep.flagged)
    assert fixed.tolist() == [0, 1, 0, 1, 0, 1]


def test_correction_of_the_last_sensor_uses_the_previous_one():
    positions = np.array([100.0, 200.0, 300.0])
    sensor = np.array([0, 0, 1, 1, 2, 2])
    stamp = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    velocity = np.full(6, 50.0)
    labels = np.array([0, 1, 0, 1, 1, 1])
    fixed = correct_errors(
        positions, sensor, stamp, velocity, labels, detect_errors(sensor, stamp, labels).flagged
    )
    assert fixed.tolist() == [0, 1, 0, 1, 0, 1]


def _hand_made():
    """Three constant-speed targets, six sensors; target 1 overtakes target 0 on the way."""
    positions = np.array([100.0, 300.0, 500.0, 700.0, 900.0, 1100.0])
    start = {0: 0.0, 1: 3.0, 2: 40.0}
    speed = {0: 40.0, 1: 60.0, 2: 50.0}
    sensor, stamp, velocity, target = [], [], [], []
    for k, r in enumerate(positions):
        for tgt in range(3):
            sensor.append(k)
            stamp.append(start[tgt] + r / speed[tgt])
            velocity.append(speed[tgt])
            target.append(tgt)
    layout = Layout(1200.0, positions)
    return layout, Detections(sensor, stamp, velocity, target)


@pytest.mark.parametrize('method', ['mlkm', 'mlkm_no_ec'])
def test_mlkm_hand_made_scenario(method):
    layout, d = _hand_made()
    labels = make_associator(method, AssociatorConfig(segment_size=3)).associate(layout, d, 3)
    # the known answer: one track per target, named by the first segment's time order
    # (target 0 passes sensor 0 first at 2.5 s, target 1 at 4.67 s, target 2 at 42 s)
    assert labels.tolist() == d.target.tolist()
    assert accuracy(labels, d.target).accuracy == 1.0


def test_mlkm_partial_track_ids_persist_to_the_final_result():
    ds = simulate(SimConfig(), 21)
    assoc = make_associator('mlkm', AssociatorConfig(segment_size=5, seed=21))
    session = assoc.session(ds.layout, ds.n_targets)
    d = ds.detections
    partial_ids = []
    for seg in range(4):
        idx = np.flatnonzero((d.sensor_index >= 5 * seg) & (d.sensor_index < 5 * seg + 5))
        labels = session.add_segment(d.subset(idx))
        assert labels.size == len(session.detections)
        partial_ids.append(set(labels.tolist()))
    # track ids are the first segment's clusters: they never change meaning
    assert partial_ids[0] == set(range(ds.n_targets))
    assert all(ids <= partial_ids[0] for ids in partial_ids)


def test_error_correction_helps_on_seeded_data():
    acc = {'mlkm': [], 'mlkm_no_ec': [], 'kmeans_pp': []}
    for seed in range(6):
        ds = simulate(SimConfig(), seed)
        for m in acc:
            lab = make_associator(m, AssociatorConfig(seed=seed)).associate(
                ds.layout, ds.detections, ds.n_targets
            )
            acc[m].append(accuracy(lab, ds.detections.target).accuracy)
    mean = {m: np.mean(v) for m, v in acc.items()}
    assert mean['mlkm'] > mean['mlkm_no_ec'] + 0.03
    assert mean['mlkm'] > mean['kmeans_pp']
    assert mean['mlkm'] > 0.85


def test_mlkm_survives_clutter_and_short_last_segment():
    cfg = SimConfig(n_targets=30, n_sensors=13, miss_probability=0.1, false_alarm_rate=0.05)
    ds = simulate(cfg, 2)
    labels = make_associator('mlkm', AssociatorConfig(segment_size=5)).associate(
        ds.layout, ds.detections, ds.n_targets
    )
    assert labels.shape == (len(ds.detections),) and labels.min() >= 0
    assert accuracy(labels, ds.detections.target).accuracy > 0.6
