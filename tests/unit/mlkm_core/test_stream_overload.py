"""The streaming tracker when its window solves cannot keep up: the backlog of detections
waiting for their commit stays bounded (``max_uncommitted``), the due boundaries are committed
on the immediate links, and the solves resume once the executor is back.

The executor here never finishes a solve until the test says so: a deterministic backlog,
not a timing.
"""

from __future__ import annotations

import numpy as np

from mlkm_core.streaming import FINAL, StreamConfig, StreamTracker
from mlkm_core.types import Layout

#: five stations 200 m apart
ROAD = Layout(1100.0, np.arange(1, 6) * 200.0)
VEHICLES = 400
SPACING = 3.0  # [s] between vehicles: far apart, so every immediate link is right
SPEED = 25.0  # [m/s]: 8 s between stations
BUDGET = 120


class StuckExecutor:
    """Takes every solve and finishes none until ``release``; then each is solved when its
    result is asked for."""

    def __init__(self) -> None:
        self.submitted = 0
        self.released = False

    def submit(self, fn, *args):
        self.submitted += 1
        return _Future(self, fn, args)

    def release(self) -> None:
        self.released = True


class _Future:
    def __init__(self, executor: StuckExecutor, fn, args) -> None:
        self._executor, self._fn, self._args = executor, fn, args

    def done(self) -> bool:
        return self._executor.released

    def result(self):
        return self._fn(*self._args)


def rows() -> list[tuple[int, int, float, float]]:
    """(key, sensor, stamp, speed) in stamp order; key = vehicle * 5 + station."""
    out = [
        (v * 5 + s, s, v * SPACING + float(ROAD.positions[s]) / SPEED, SPEED)
        for v in range(VEHICLES)
        for s in range(5)
    ]
    return sorted(out, key=lambda r: r[2])


def test_stuck_solves_keep_the_backlog_bounded_and_commit_real_tracks() -> None:
    config = StreamConfig(method='assignment', lag=15.0, max_uncommitted=BUDGET)
    executor = StuckExecutor()
    tracker = StreamTracker(ROAD, config, executor=executor)
    labels: dict[int, int] = {}

    def take(update) -> None:
        for key, track in update.committed.tolist():
            assert key not in labels, 'a detection was committed twice'
            labels[key] = track

    data = rows()
    half = len(data) // 2
    peak = 0
    for key, s, stamp, v in data[:half]:
        take(tracker.push(key, s, stamp, v))
        peak = max(peak, tracker.stats()['uncommitted'])
        if stamp > 100.0:  # the commits keep up: a budget of traffic (72 s) and the lag
            assert tracker.committed_until >= stamp - 100.0, 'the commits fell behind'
    stats = tracker.stats()
    # no solve ever finished, yet the backlog stayed within the budget
    assert stats['solves'] == 0 and peak <= BUDGET + 1
    assert stats['skipped_solves'] > 10 and stats['forced_commits'] > 0
    assert stats['overloaded'] == 1 and tracker.overloaded
    assert tracker.working_set < 2 * BUDGET
    # one solve went to the executor and no other was queued behind it
    assert executor.submitted == 1
    # the solves resume once the executor finishes them
    executor.release()
    for key, s, stamp, v in data[half:]:
        take(tracker.push(key, s, stamp, v))
    take(tracker.flush())
    stats = tracker.stats()
    assert stats['solves'] > 0 and not tracker.overloaded
    assert tracker.working_set == 0 and sorted(labels) == sorted(r[0] for r in data)
    # every committed label is a real association: each vehicle one track of its own
    tracks: dict[int, set[int]] = {}
    for key, track in labels.items():
        assert track >= 0, f'detection {key} left alone'
        tracks.setdefault(track, set()).add(key // 5)
    assert all(len(vehicles) == 1 for vehicles in tracks.values())
    assert len(tracks) == VEHICLES


def test_flush_while_overloaded_commits_the_immediate_links() -> None:
    # a budget below the lag's traffic (27-43 detections): overloaded at every boundary
    config = StreamConfig(method='assignment', lag=15.0, max_uncommitted=10)
    tracker = StreamTracker(ROAD, config, executor=StuckExecutor())
    data = rows()[:300]
    for key, s, stamp, v in data:
        tracker.push(key, s, stamp, v)
    assert tracker.overloaded and tracker.stats()['uncommitted'] > 10
    update = tracker.flush()
    stats = tracker.stats()
    assert tracker.working_set == 0 and not tracker.solving and stats['solves'] == 0
    assert stats['committed'] == stats['forced_commits'] == len(data)
    final = [t.keys.tolist() for t in update.tracks if t.status == FINAL and t.keys.size]
    assert final and all(len({k // 5 for k in keys}) == 1 for keys in final)


def test_without_a_bound_the_backlog_grows_with_stuck_solves() -> None:
    """What the bound is for: the same stream with max_uncommitted 0 holds everything."""
    tracker = StreamTracker(
        ROAD, StreamConfig(method='assignment', lag=15.0), executor=StuckExecutor()
    )
    data = rows()[:1000]
    for key, s, stamp, v in data:
        tracker.push(key, s, stamp, v)
    assert tracker.stats()['uncommitted'] == len(data)
