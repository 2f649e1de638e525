"""The time-space diagram's data on a hand-made case: its lines, crosses and red links."""

import numpy as np
import pytest

from mlkm_core.timespace import NO_TRUTH, time_space

# Three stations, three vehicles seen at each, one false alarm at the last station.
STATION = np.array([0.0, 100.0, 200.0])
#            t0 at s0, s1, s2 | t1 at s0, s1, s2 | t2 at s0, s1, s2 | clutter at s2
SENSOR = np.array([0, 1, 2, 0, 1, 2, 0, 1, 2, 2])
STAMP = np.array([0.0, 4.0, 8.0, 2.0, 6.0, 10.0, 3.0, 7.5, 11.0, 12.0])
TARGET = np.array([0, 0, 0, 1, 1, 1, 2, 2, 2, -1])
# track 10 = vehicle 0 whole; track 11 = vehicle 1, then vehicle 2's last detection (wrong);
# track 12 = vehicle 2's first two, then the false alarm (wrong); vehicle 1's last unassigned.
LABELS = np.array([10, 10, 10, 11, 11, -1, 12, 12, 11, 12])
WRONG_PAIRS = {(4, 8), (7, 9)}  # (earlier, later) detection of each wrong link


def _pairs(ts, mask, stamp=STAMP):
    """The (earlier, later) detection indices of the links selected by ``mask``."""
    where = {(float(t), float(y)): i for i, (t, y) in enumerate(zip(stamp, STATION[SENSOR]))}
    return {(where[tuple(a)], where[tuple(b)]) for a, b in ts.links[mask].tolist()}


def test_hand_made_case_lines_crosses_and_exactly_the_wrong_links():
    ts = time_space(STATION[SENSOR], STAMP, LABELS, TARGET)
    assert ts.tracks.tolist() == [10, 11, 12]
    assert len(ts.links) == 6  # 2 per track: a track of n detections has n - 1 links
    assert len(ts.points) == 9 and len(ts.crosses) == 1
    assert ts.crosses.tolist() == [[10.0, 200.0]]  # vehicle 1 at the last station
    assert ts.n_wrong == 2
    assert _pairs(ts, ts.wrong) == WRONG_PAIRS
    assert _pairs(ts, ~ts.wrong) == {(0, 1), (1, 2), (3, 4), (6, 7)}
    assert sorted(ts.link_track[ts.wrong].tolist()) == [11, 12]
    # links go along the road: the earlier station first, grouped by track
    assert np.all(ts.links[:, 0, 1] < ts.links[:, 1, 1])
    assert ts.link_track.tolist() == sorted(ts.link_track.tolist())


def test_the_input_order_does_not_matter():
    perm = np.random.default_rng(3).permutation(SENSOR.size)
    ts = time_space(STATION[SENSOR][perm], STAMP[perm], LABELS[perm], TARGET[perm])
    assert _pairs(ts, ts.wrong) == WRONG_PAIRS
    assert len(ts.links) == 6 and len(ts.crosses) == 1


def test_without_truth_no_link_is_wrong_and_missing_truth_judges_nothing():
    ts = time_space(STATION[SENSOR], STAMP, LABELS)
    assert not ts.has_truth and ts.n_wrong == 0 and len(ts.links) == 6
    target = TARGET.copy()
    target[8] = NO_TRUTH  # vehicle 2's last detection: its truth was lost
    ts = time_space(STATION[SENSOR], STAMP, LABELS, target)
    assert _pairs(ts, ts.wrong) == {(7, 9)}


def test_two_false_alarms_in_one_track_are_a_wrong_link():
    ts = time_space([0.0, 100.0], [0.0, 5.0], [0, 0], [-1, -1])
    assert ts.n_wrong == 1


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match='one entry per detection'):
        time_space([0.0, 1.0], [0.0], [0, 0])
    with pytest.raises(ValueError, match='finite'):
        time_space([0.0, np.nan], [0.0, 1.0], [0, 0])
    with pytest.raises(ValueError, match='>= 0, or -1'):
        time_space([0.0, 1.0], [0.0, 1.0], [0, -3])
