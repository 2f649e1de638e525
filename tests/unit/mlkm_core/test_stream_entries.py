"""Where the stream's vehicles enter and leave mid-road (``mlkm_core.streaming.entries``): the
rates from the tracks it ended, by hand, and on real traffic observed over part of the road
(no ROS)."""

from pathlib import Path

import numpy as np
import pytest

from mlkm_core.loops import even_positions, virtual_loops
from mlkm_core.metrics import accuracy
from mlkm_core.model.motion import MotionParams
from mlkm_core.streaming import StreamConfig, StreamTracker
from mlkm_core.streaming.entries import EndedTracks
from mlkm_core.trajectories import read_trajectories
from mlkm_core.types import Layout

DATA = Path(__file__).resolve().parents[3] / 'data' / 'ngsim_i80' / 'i80_trajectories_a.csv.gz'


def three_stations() -> Layout:
    return Layout(300.0, np.array([0.0, 100.0, 200.0]))


def whole_road(n: int, size: int = 3000) -> EndedTracks:
    """A stream begun at 0 s that ended ``n`` vehicles over the whole road of
    ``three_stations`` at 10 m/s, 20 s apart."""
    ended = EndedTracks(three_stations(), size)
    ended.begin(0.0)
    for k in range(n):
        t = 20.0 * k
        ended.add_track([(0, t, 10.0), (1, t + 10.0, 10.0), (2, t + 20.0, 10.0)])
    return ended


def test_the_rates_count_the_vehicles_that_began_mid_road_after_the_stream_did():
    ended = whole_road(10)
    # five that entered between the first two stations, first seen at the second one
    for k in range(5):
        t = 35.0 + 40.0 * k
        ended.add_track([(1, t, 10.0), (2, t + 10.0, 10.0)])
    # one first seen at the second station 5 s into the stream: at 10 m/s it passed the first
    # station before the stream began, so where it begins says nothing of the road
    ended.add_track([(1, 5.0, 10.0), (2, 15.0, 10.0)])
    entry, exit_ = ended.rates(MotionParams())
    # five of the fifteen tracks passing the second station began there; none ended early
    assert entry is not None and entry[1] == pytest.approx(5 / 15)
    assert entry[0] == entry[2] == 0.0
    assert exit_ is None


def test_two_lone_beginnings_are_not_vehicles_entering():
    ended = whole_road(10)
    for t in (45.0, 125.0):  # fewer than MIN_EXCESS: a missed first detection, a break
        ended.add_track([(1, t, 10.0), (2, t + 10.0, 10.0)])
    assert ended.rates(MotionParams()) == (None, None)


def test_only_whole_tracks_are_kept_within_the_size():
    ended = whole_road(4, size=7)
    # the oldest tracks go whole: two of three detections are left, not a fragment
    assert [len(t) for t in ended._tracks] == [3, 3]
    assert [float(t[0, 1]) for t in ended._tracks] == [40.0, 60.0]


@pytest.fixture(scope='module')
def open_road():
    """NGSIM I-80, five loops over 400 m from 95.4 m on (the fourth placement of the bench's
    real part), every observed crossing: vehicles whose observation ends at the fourth loop
    are tracks that end there."""
    traj = read_trajectories(DATA)
    x0 = float(np.random.default_rng(4).uniform(20.0, 100.0))
    return virtual_loops(traj, even_positions(5, x0, x0 + 400.0), False).dataset


def streamed(ds, config: StreamConfig) -> tuple[np.ndarray, StreamTracker]:
    """The committed track of every detection of ``ds`` pushed in stamp order and flushed."""
    d = ds.detections
    tracker = StreamTracker(ds.layout, config)
    labels = np.full(len(d), -1, np.int64)

    def take(update) -> None:
        for key, track in update.committed.tolist():
            labels[key] = track

    for k in np.lexsort((d.sensor_index, d.stamp)).tolist():
        take(tracker.push(k, int(d.sensor_index[k]), float(d.stamp[k]), float(d.velocity[k]),
                          int(d.lane[k]), float(d.length[k])))  # fmt: skip
    take(tracker.flush())
    return labels, tracker


def test_the_stream_prices_the_ends_of_real_vehicles_observed_over_part_of_the_road(open_road):
    # without the rates the windows charged those ends as misses and linked them on to other
    # vehicles' detections (98.09 %); batch: 100 %
    labels, tracker = streamed(open_road, StreamConfig(method='multiframe'))
    entry, exit_ = tracker._ended.rates(tracker.params)
    assert exit_ is not None and exit_[3] > 0.1  # the loop where many observations end
    assert accuracy(labels, open_road.detections.target).accuracy > 0.985


def test_a_lag_that_holds_the_whole_open_road_gives_the_batch_tracks(open_road):
    # nothing is committed before the flush, whose window is the whole input: its vehicles'
    # passages are whole, and it estimates the rates as batch does
    from mlkm_core.associators import AssociatorConfig, make_associator

    config = StreamConfig(method='multiframe', lag=1e5, solve_interval=1e5)  # the flush solves
    labels, _ = streamed(open_road, config)
    ds = open_road
    batch = make_associator('multiframe', AssociatorConfig()).associate(
        ds.layout, ds.detections, ds.n_targets
    )

    def tracks(lab):
        return {frozenset(np.flatnonzero(lab == t).tolist()) for t in set(lab.tolist()) - {-1}}

    assert tracks(labels) == tracks(np.asarray(batch))
