"""Entry and exit rates of each sensor estimated from the tracks (``associators.entries``)."""

import math

import numpy as np

from mlkm_core.associators.entries import estimate_entries
from mlkm_core.associators.likelihood import total_nll
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Detections, Layout

POSITIONS = 100.0 * np.arange(1, 5)
LAYOUT = Layout(500.0, POSITIONS)
PARAMS = MotionParams(
    sigma=1.0,
    length=500.0,
    stamp_noise=0.1,
    velocity_noise=0.2,
    p_miss=0.02,
    clutter_density=0.01,
)
SPEED = 20.0  # [m/s]


def road(vehicles: list[tuple[float, list[int]]]) -> Detections:
    """Vehicles at ``SPEED``, each (time [s] at the first sensor's position, the sensors it is
    seen at), with exact stamps; the target id is the vehicle's index."""
    s = np.concatenate([np.asarray(v[1]) for v in vehicles])
    t = np.concatenate([v[0] + (POSITIONS[v[1]] - POSITIONS[0]) / SPEED for v in vehicles])
    g = np.concatenate([np.full(len(v[1]), k) for k, v in enumerate(vehicles)])
    return Detections(s, t, np.full(s.size, SPEED), g)


THROUGH = [(10.0 * k, [0, 1, 2, 3]) for k in range(6)]
ENTERING = [(100.0 + 10.0 * k, [2, 3]) for k in range(4)]


def test_the_tracks_that_begin_mid_road_without_a_partner_give_the_entry_rate():
    d = road(THROUGH + ENTERING)
    p = estimate_entries(LAYOUT, d, d.target, PARAMS)
    # four of the ten tracks passing sensor 2 begin there, none ends before the last sensor
    np.testing.assert_allclose(p.entry_rate, [0.0, 0.0, 0.4, 0.0])
    assert p.exit_rate is None


def test_breaks_beyond_the_gate_are_no_entries():
    # three vehicles broken between sensors 1 and 2 far beyond the gate (their pieces 60 s
    # apart): each leaves a lone end and a lone start, which cancel
    d = road(THROUGH + [(200.0 + 100 * k, [0, 1]) for k in range(3)])
    d = Detections(
        np.concatenate([d.sensor_index, np.repeat([2, 3], 3)]),
        np.concatenate([d.stamp, [270.0, 370.0, 470.0, 275.0, 375.0, 475.0]]),
        np.full(len(d) + 6, SPEED),
        np.concatenate([d.target, [10, 11, 12, 10, 11, 12]]),
    )
    p = estimate_entries(LAYOUT, d, d.target, PARAMS)
    assert p.entry_rate is None and p.exit_rate is None


def test_vehicles_whose_first_detection_the_pass_left_alone_are_no_entries():
    # three vehicles' first detections at sensor 0 are left alone (-1), their tracks begin
    # at sensor 1 with no partner
    d = road(THROUGH + [(100.0 + 10.0 * k, [0, 1, 2, 3]) for k in range(3)])
    labels = np.where((d.target >= 6) & (d.sensor_index == 0), -1, d.target)
    assert estimate_entries(LAYOUT, d, labels, PARAMS).entry_rate is None
    # without those detections the same three tracks are vehicles entering at sensor 1
    seen = labels >= 0
    rates = estimate_entries(LAYOUT, d.subset(seen), labels[seen], PARAMS).entry_rate
    np.testing.assert_allclose(rates, [0.0, 3 / 9, 0.0, 0.0])


def test_fewer_than_three_lone_tracks_are_no_entries():
    d = road(THROUGH + ENTERING[:2])
    assert estimate_entries(LAYOUT, d, d.target, PARAMS).entry_rate is None


def test_a_track_begun_mid_road_costs_the_likelier_of_entering_and_missing():
    p = MotionParams(p_miss=0.02, entry_rate=np.array([0.0, 0.0, 0.25, 0.0]))
    cost = p.misses_before(np.array([0, 2, 3]))
    np.testing.assert_allclose(
        cost, [0.0, -math.log(0.25 + 0.02**2), 3 * -math.log(0.02)], rtol=1e-12
    )


def test_an_entering_vehicle_is_not_taken_for_the_tail_of_one_that_left():
    # vehicle 10 is seen at sensors 0 and 1 only, vehicle 11 enters at sensor 2 one second
    # after vehicle 10 would have passed it; four more vehicles enter at sensor 2
    d = road(THROUGH + ENTERING + [(200.0, [0, 1]), (201.0, [2, 3])])
    truth = d.target
    joined = np.where(truth == 11, 10, truth)
    # charged as two misses, vehicle 11's own track costs more than the join's poor link
    assert total_nll(LAYOUT, d, joined, PARAMS, 'pairwise') < total_nll(
        LAYOUT, d, truth, PARAMS, 'pairwise'
    )
    # with the entry rate the data show (five of the eleven tracks passing sensor 2 begin
    # there; vehicle 11, with a partner within the gate, is not counted) the truth is likelier
    fitted = estimate_entries(LAYOUT, d, truth, PARAMS)
    np.testing.assert_allclose(fitted.entry_rate, [0.0, 0.0, 4 / 11, 0.0])
    assert total_nll(LAYOUT, d, truth, fitted, 'pairwise') < total_nll(
        LAYOUT, d, joined, fitted, 'pairwise'
    )
