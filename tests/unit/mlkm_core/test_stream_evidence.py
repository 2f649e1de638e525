"""What a method decides about the traffic once per stream: ``multiframe``'s choice of the
motion model its search scores with, taken on the evidence of every window so far (no ROS)."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import mlkm_core.associators.multiframe as multiframe
from mlkm_core.associators import AssociatorConfig, make_associator
from mlkm_core.associators.base import canonical_order
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.associators.linking import link, relabel
from mlkm_core.associators.pairwise_fit import kalman_evidence, kalman_lead, lead_per_link
from mlkm_core.associators.repair import repaired
from mlkm_core.loops import even_positions, virtual_loops
from mlkm_core.metrics import accuracy
from mlkm_core.simulator import SimConfig, simulate
from mlkm_core.streaming import StreamConfig, StreamTracker
from mlkm_core.streaming.solve import EVIDENCE_WEIGHT, add_evidence
from mlkm_core.trajectories import read_trajectories
from mlkm_core.types import Detections

DATA = Path(__file__).resolve().parents[3] / 'data' / 'ngsim_i80' / 'i80_trajectories_a.csv.gz'


def test_evidence_adds_up_and_fades_past_its_weight():
    assert add_evidence(None, (3.0, 10.0)) == (3.0, 10.0)
    assert add_evidence((3.0, 10.0), (-1.0, 30.0)) == (2.0, 40.0)
    # a window that commits a quarter of its rows counts for a quarter of its links
    assert add_evidence((3.0, 10.0), (-4.0, 40.0), 0.25) == (2.0, 20.0)
    # past the weight both parts scale down together: the lead per link is kept
    total, weight = add_evidence((0.5 * EVIDENCE_WEIGHT, EVIDENCE_WEIGHT), (300.0, 1000.0))
    assert weight == EVIDENCE_WEIGHT
    assert total / weight == pytest.approx(
        (0.5 * EVIDENCE_WEIGHT + 300.0) / (EVIDENCE_WEIGHT + 1000)
    )


def test_lead_per_link_needs_ten_links():
    assert lead_per_link((5.0, 9.0)) == 0.0
    assert lead_per_link((5.0, 10.0)) == 0.5


def _window():
    """A simulated window, its calibrated model and its repaired pairwise pass."""
    ds = simulate(SimConfig(n_targets=30, n_sensors=10), 3)
    d = ds.detections.subset(canonical_order(ds.detections))
    p = estimate_params(ds.layout, d, None)
    pairwise = repaired(ds.layout, d, link(ds.layout, d, p, 'pairwise'), p)
    return ds.layout, d, p, relabel(pairwise)


def test_settled_decides_on_the_windows_before_and_its_own():
    layout, d, p, labels = _window()
    own = kalman_evidence(layout, d, labels, p)
    assert own[1] > 200  # the window's links
    assert own[0] / own[1] == pytest.approx(kalman_lead(layout, d, labels, p))
    # the simulator's vehicles keep a cruise speed: alone, the window takes the Kalman model
    assert own[0] / own[1] < multiframe.FIT_MARGIN
    mf = make_associator('multiframe', AssociatorConfig())
    alone, evidence = mf.settled(layout, d, p, None)
    assert alone.kalman_fits is True and evidence == pytest.approx(own)
    # windows before it whose links the Kalman model predicted 1 nat worse each, twenty
    # times as many: the stream stays with the pairwise model
    before = (20 * own[1] * 1.0, 20 * own[1])
    settled, evidence = mf.settled(layout, d, p, before)
    assert settled.kalman_fits is False and evidence == pytest.approx(own)
    assert replace(settled, kalman_fits=None) == p  # nothing else changed


def test_a_decided_model_is_not_decided_again(monkeypatch):
    layout, d, p, _ = _window()
    calls = []
    real = multiframe.kalman_fits
    monkeypatch.setattr(multiframe, 'kalman_fits', lambda *a: calls.append(1) or real(*a))
    mf = make_associator('multiframe', AssociatorConfig())
    undecided = mf.associate(layout, d, 30, motion=p)
    assert calls == [1]  # undecided: the input decides (the Kalman model, on the simulator)
    kalman = mf.associate(layout, d, 30, motion=replace(p, kalman_fits=True))
    assert calls == [1] and np.array_equal(kalman, undecided)
    decided = mf.associate(layout, d, 30, motion=replace(p, kalman_fits=False))
    assert calls == [1]
    # searched under the pairwise model's Markov chain, as where the Kalman model does not fit
    monkeypatch.setattr(multiframe, 'kalman_fits', lambda *a: False)
    assert np.array_equal(decided, mf.associate(layout, d, 30, motion=p))


def test_the_pairwise_search_starts_from_the_pass_settled_made(monkeypatch):
    """A window decided for the pairwise model searches from the pairwise pass that
    ``settled`` made for its decision, not from a second one, and associates alike."""
    layout, d, p, _ = _window()
    mf = make_associator('multiframe', AssociatorConfig())
    settled, _ = mf.settled(layout, d, p, (1e6, 1e6))  # before: 1 nat per link worse
    assert settled.kalman_fits is False
    calls = []
    real = multiframe.MultiFrameAssociator._pairwise
    counted = staticmethod(lambda *a: calls.append(1) or real(*a))
    monkeypatch.setattr(multiframe.MultiFrameAssociator, '_pairwise', counted)
    reused = mf.associate(layout, d, 30, motion=settled)
    assert calls == []
    fresh = make_associator('multiframe', AssociatorConfig())
    assert np.array_equal(reused, fresh.associate(layout, d, 30, motion=settled))
    assert calls == [1]
    # another model object, or other detections: the pass is made for them
    mf.associate(layout, d, 30, motion=replace(settled))
    assert calls == [1, 1]
    settled, _ = mf.settled(layout, d, p, (1e6, 1e6))
    assert calls == [1, 1, 1]
    mf.associate(layout, d.subset(np.arange(len(d) - 1)), 30, motion=settled)
    assert calls == [1, 1, 1, 1]


@pytest.mark.slow
def test_stream_on_real_traffic_keeps_one_model_and_the_accuracy_of_batch(monkeypatch):
    """NGSIM I-80, 20 loops over 400 m, vehicles seen where observed, time and speed: the
    whole input rejects the Kalman model; decided on each window alone, 8 of 26 windows took
    it and the stream trailed batch by 1.5 points (0.5 now)."""
    traj = read_trajectories(DATA)
    x0 = 60.9  # the benchmark's first placement
    loops = virtual_loops(traj, even_positions(20, x0, x0 + 400.0), closed=False)
    ds = loops.dataset
    d = Detections(
        ds.detections.sensor_index,
        ds.detections.stamp,
        ds.detections.velocity,
        ds.detections.target,
    )  # time and speed only
    batch = accuracy(make_associator('multiframe').associate(ds.layout, d, 0), d.target)
    decisions = []
    real = multiframe.MultiFrameAssociator.settled

    def settled(self, *args):
        out = real(self, *args)
        decisions.append(out[0].kalman_fits)
        return out

    monkeypatch.setattr(multiframe.MultiFrameAssociator, 'settled', settled)
    tracker = StreamTracker(ds.layout, StreamConfig(method='multiframe'))
    labels = np.full(len(d), -1)
    order = np.lexsort((d.sensor_index, d.stamp))
    updates = [
        tracker.push(int(i), int(d.sensor_index[i]), float(d.stamp[i]), float(d.velocity[i]))
        for i in order
    ]
    for update in [*updates, tracker.flush()]:
        for key, track in update.committed.tolist():
            labels[key] = track
    assert len(decisions) > 20
    assert sum(decisions[5:]) == 0  # once a few windows are in, the pairwise model only
    stream = accuracy(labels, d.target)
    assert stream.accuracy >= batch.accuracy - 0.01
