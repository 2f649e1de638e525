"""Count curves: the extra time of a gap whose queue builds up, or that a first pass linked whole
vehicles off, from the stations' counts (hand-made single-lane traffic where the speeds alone
cannot link it)."""

from dataclasses import replace

import numpy as np
import pytest

from mlkm_core.associators import count_curves, make_associator
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.associators.count_curves import (
    conserving_gaps,
    count_curve_profiles,
    count_pairs,
    running_median,
    shifted_gaps,
)
from mlkm_core.associators.linking import link, relabel
from mlkm_core.metrics import accuracy
from mlkm_core.model.gap_delays import GapDelays, GapProfile
from mlkm_core.model.motion import MotionParams
from mlkm_core.streaming.solve import CarriedModel
from mlkm_core.types import Detections, Layout

POSITIONS = np.array([0.0, 600.0, 1200.0, 1800.0])
#: the queue between stations 1 and 2 holds a vehicle entering at t up to this long [s]
HOLDUP = 40.0


def holdup(t: np.ndarray) -> np.ndarray:
    """The queue builds from t = 50 s to 200 s and clears by 300 s [s]."""
    return HOLDUP * np.interp(t, [50.0, 200.0, 300.0], [0.0, 1.0, 0.0])


def growing_queue(
    seed: int, n: int = 120, headways=(2.0, 4.0), hold=holdup
) -> tuple[Layout, Detections]:
    """One lane (no overtaking), ``n`` vehicles 2-4 s apart (``headways``) at 25 m/s, give or
    take 0.3 m/s at every station; between stations 1 and 2 a queue whose holdup (``hold``
    of the time of entry) rises from 0 to 40 s and falls back (the speeds at the stations do
    not show it)."""
    rng = np.random.default_rng(seed)
    t0 = np.cumsum(rng.uniform(*headways, n))
    sensor, stamp, speed, target = [], [], [], []
    t, before = t0.copy(), None
    for s, x in enumerate(POSITIONS):
        v = 25.0 + rng.normal(0.0, 0.3, n)
        if before is not None:
            dx = x - POSITIONS[s - 1]
            t = t + dx * (1 / v + 1 / before) / 2 + (hold(t) if s == 2 else 0.0)
            t = np.maximum.accumulate(t + 1e-3)  # nobody overtakes in the lane
        before = v
        sensor += [s] * n
        stamp += t.tolist()
        speed += v.tolist()
        target += list(range(n))
    layout = Layout(2000.0, POSITIONS.copy())
    d = Detections(np.array(sensor), np.array(stamp), np.array(speed), target=np.array(target))
    return layout, d


def test_count_pairs_pair_the_kth_vehicle_upstream_with_the_kth_downstream() -> None:
    layout, d = growing_queue(1)
    a, b = count_pairs(layout, d, 1, float(np.quantile(d.velocity, count_curves.FAST_QUANTILE)))
    assert np.array_equal(d.target[a], d.target[b])


def test_the_profile_follows_the_holdup_of_the_queue() -> None:
    layout, d = growing_queue(2)
    found = count_curve_profiles(layout, d)
    level, profile, ratio = found[1]
    a = np.flatnonzero(d.sensor_index == 1)
    est = level + profile.at(d.stamp[a])
    err = np.abs(est - holdup(d.stamp[a]))
    assert np.median(err) < 0.5  # the speeds' noise
    assert np.max(err) < 4.0  # the running median cuts the peak of the holdup
    assert ratio > 5
    # the free gaps: no holdup, nothing to follow
    for g in (0, 2):
        assert abs(found[g][0]) < 0.5 and found[g][2] < count_curves.PROFILE_RATIO


@pytest.mark.parametrize('seed', [3, 4])
def test_a_growing_queue_is_linked_with_the_count_curves_and_not_without(
    seed: int, monkeypatch
) -> None:
    layout, d = growing_queue(seed)
    with_counts = make_associator('assignment').associate(layout, d, 120)
    assert accuracy(with_counts, d.target).accuracy > 0.97
    monkeypatch.setattr(count_curves, 'PROFILE_RATIO', np.inf)  # a constant extra time only
    without = make_associator('assignment').associate(layout, d, 120)
    assert accuracy(without, d.target).accuracy < 0.9


#: a hold-up every vehicle shares, about two headways of the dense traffic below [s]
SHIFTED_HOLDUP = 3.2


def dense_holdup(seed: int) -> tuple[Layout, Detections]:
    """One lane, vehicles 1.4-1.8 s apart, every one held up 3.2 s between stations 1 and 2
    (a stretch of slow road the speeds at the stations do not show)."""
    return growing_queue(seed, headways=(1.4, 1.8), hold=lambda t: np.full_like(t, SHIFTED_HOLDUP))


@pytest.mark.parametrize('seed', [5, 6])
def test_a_gap_linked_whole_vehicles_off_gets_the_level_of_its_counts(
    seed: int, monkeypatch
) -> None:
    """Each vehicle linked to the one two places ahead fits the speeds as well as the truth
    (2 headways are about the hold-up), links every vehicle, and every estimate from those
    links keeps it; the counts pair the k-th with the k-th and sit 3.2 s higher."""
    layout, d = dense_holdup(seed)
    first = relabel(link(layout, d, MotionParams(), 'pairwise'))
    shifted = shifted_gaps(layout, d, first)
    assert list(shifted) == [1]
    assert shifted[1] == pytest.approx(SHIFTED_HOLDUP, abs=0.1)
    anchored = make_associator('assignment').associate(layout, d, 120)
    assert accuracy(anchored, d.target).accuracy > 0.97
    monkeypatch.setattr(count_curves, 'SHIFT', np.inf)  # no shifted gaps
    alone = make_associator('assignment').associate(layout, d, 120)
    assert accuracy(alone, d.target).accuracy < 0.8


def test_a_stream_window_is_calibrated_without_the_count_curves() -> None:
    """Counts pair the k-th vehicle up a gap with the k-th down it only where every passage
    is whole; a stream window cuts vehicles in transit at both ends, so its calibration
    (``whole_passages=False``) leaves the counts' level of the hold-up out."""
    layout, d = dense_holdup(5)
    whole = estimate_params(layout, d)
    window = estimate_params(layout, d, whole_passages=False)
    assert whole.delay is not None
    assert whole.delay.gap_time[1] == pytest.approx(SHIFTED_HOLDUP, abs=0.1)
    assert window.delay is None or abs(window.delay.gap_time[1] - SHIFTED_HOLDUP) > 1.0


def test_a_gap_its_pass_links_right_is_not_shifted() -> None:
    """The growing queue's free gaps, linked right by the first pass: nothing moves."""
    layout, d = growing_queue(7)
    assert shifted_gaps(layout, d, d.target) == {}
    layout, d = dense_holdup(7)
    assert shifted_gaps(layout, d, d.target) == {}  # the true links sit where the counts do


def test_the_constant_extra_times_keep_the_gaps_of_the_count_curves() -> None:
    """``beside``: a gap the counts gave a level (no profile) or a profile keeps theirs; the
    other gaps take the constant extra times estimated after them."""
    pos = np.array([0.0, 100.0, 200.0, 300.0])
    profile = GapProfile(2, np.array([0.0, 10.0]), np.array([-1.0, 1.0]))
    counted = GapDelays.per_gap(pos, np.array([0.0, 3.2, 7.0]), np.zeros(3), (profile,))
    delay = GapDelays.per_gap(pos, np.array([5.0, 0.0, 0.0]), np.zeros(3))
    both = count_curves.beside(delay, counted)
    assert both.gap_time.tolist() == pytest.approx([5.0, 3.2, 7.0])
    assert both.profiles == (profile,)


def test_no_count_curves_across_an_entry_or_an_exit() -> None:
    positions = np.array([0.0, 100.0, 200.0, 300.0])
    openings = MotionParams.road_openings(positions, (150.0,), (250.0,))
    assert conserving_gaps(4, None) == [0, 1, 2]
    assert conserving_gaps(4, openings) == [0]


def test_running_median_of_hand_made_values() -> None:
    x = np.array([1.0, 9.0, 2.0, 3.0, 100.0, 4.0])
    assert running_median(x, 3).tolist() == [5.0, 2.0, 3.0, 3.0, 4.0, 52.0]


def test_gap_profile_in_the_extra_time_of_a_forward_link_only() -> None:
    profile = GapProfile(1, np.array([0.0, 100.0]), np.array([-5.0, 5.0]))
    delays = GapDelays.per_gap(
        np.array([0.0, 100.0, 200.0]), np.array([1.0, 10.0]), np.array([0.0, 4.0]), (profile,)
    )
    # across gap 1 at t = 50: its mean 10 plus the profile's 0; at t = 100: + 5
    assert delays.extra_time(100.0, 200.0, 50.0) == pytest.approx(10.0)
    assert delays.extra_time(0.0, 200.0, np.array([100.0]))[0] == pytest.approx(16.0)
    assert delays.extra_time(0.0, 100.0, 100.0) == pytest.approx(1.0)  # gap 0 has none
    assert delays.extra_time(100.0, 200.0) == pytest.approx(10.0)  # no stamp: the mean
    assert delays.extra_time(200.0, 100.0, 100.0) == pytest.approx(-10.0)  # backwards
    assert delays.mirrored().profiles == ()
    assert delays.with_gap(1, 3.0, 0.0).profiles == ()
    assert delays.with_gap(0, 3.0, 0.0).profiles == (profile,)
    # a model carried to other detections keeps the means, not the times of a profile
    carried = CarriedModel.of(MotionParams(delay=delays)).params.delay
    assert carried.profiles == () and np.array_equal(carried.gap_time, delays.gap_time)
    assert replace(delays, profiles=()).extra_time(100.0, 200.0, 100.0) == pytest.approx(10.0)
