"""The network's fixed-lag stream (``network_assoc.stream``) on hand-made traffic through a
junction: a lag longer than the traffic equals the batch association; with a short lag every
detection is committed exactly once, a committed link never changes, the tracks end FINAL
with all their detections; a detection older than the commit horizon is committed alone; window
solves run beside the stream (an executor that answers late, or fails) commit the same."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from mlkm_core.metrics import score
from mlkm_core.network import RoadLink, RoadNetwork
from mlkm_core.network_assoc import associate_network
from mlkm_core.network_assoc.stream import NetworkStreamConfig, NetworkStreamTracker
from mlkm_core.streaming.config import FINAL
from mlkm_core.types import Detections

NET = RoadNetwork(
    links=(RoadLink(0, 'in', 1000.0), RoadLink(1, 'left', 800.0), RoadLink(2, 'right', 800.0)),
    connections=((0, 1), (0, 2)),
    station_ids=np.arange(4),
    station_names=('a', 'b', 'c', 'd'),
    station_links=np.array([0, 0, 1, 2]),
    station_offsets=np.array([200.0, 800.0, 300.0, 300.0]),
)


def traffic(n: int, seed: int = 0) -> Detections:
    """``n`` vehicles 2-6 s apart at about 25 m/s through the diverge, a third turning right."""
    rng = np.random.default_rng(seed)
    rows, t = [], 0.0
    for k in range(n):
        t += rng.uniform(2.0, 6.0)
        v = 25.0 + rng.normal(0, 1.5)
        right = rng.random() < 1 / 3
        t1 = t + 600.0 / v + rng.normal(0, 0.1)
        t2 = t1 + 500.0 / v + rng.normal(0, 0.3)
        rows += [(0, t, v, k), (1, t1, v, k), (3 if right else 2, t2, v, k)]
    s, tt, vv, kk = (np.array(c) for c in zip(*rows, strict=True))
    return Detections(s.astype(np.int64), tt, vv, kk.astype(np.int64))


class LateExecutor:
    """Runs each job it is given (pickled and unpickled, as the node's solver process gets
    it) but reports it done only ``delay`` pushes later, or when its result is waited for;
    ``fail``: every job raises."""

    def __init__(self, delay: int, fail: bool = False) -> None:
        self.delay, self.fail, self.submitted, self.clock = delay, fail, 0, 0

    def submit(self, fn, *args) -> LateFuture:
        fn, args = pickle.loads(pickle.dumps((fn, args)))
        self.submitted += 1
        return LateFuture(self, self.clock + self.delay, lambda: fn(*args))

    def tick(self) -> None:
        """One push went by."""
        self.clock += 1


class LateFuture:
    def __init__(self, executor: LateExecutor, due: int, run) -> None:
        self.executor, self.due, self.run = executor, due, run

    def done(self) -> bool:
        return self.executor.clock >= self.due

    def result(self):
        if self.executor.fail:
            raise RuntimeError('solver gone')
        return self.run()


def stream(d: Detections, config: NetworkStreamConfig, executor=None):
    """(labels committed, every update) of pushing ``d`` in stamp order and flushing; each
    push's update shows the pushed detection in a track (its immediate link)."""
    tracker = NetworkStreamTracker(NET, config, executor)
    labels = np.full(len(d), -2, np.int64)
    updates = []
    for i in np.lexsort((np.arange(len(d)), d.sensor_index, d.stamp)).tolist():
        if executor is not None:
            executor.tick()
        updates.append(tracker.push(i, int(d.sensor_index[i]), float(d.stamp[i]),
                                    float(d.velocity[i])))  # fmt: skip
        assert any(i in t.keys for t in updates[-1].tracks)
        for key, track in updates[-1].committed.tolist():
            assert labels[key] == -2, 'committed twice'
            labels[key] = track
    updates.append(tracker.flush())
    for key, track in updates[-1].committed.tolist():
        assert labels[key] == -2, 'committed twice'
        labels[key] = track
    return labels, updates, tracker


def test_a_lag_longer_than_the_traffic_equals_the_batch_association():
    d = traffic(120)
    labels, _, _ = stream(d, NetworkStreamConfig(lag=10_000.0))
    batch = associate_network(NET, d)
    assert score(d, labels).accuracy == score(d, batch).accuracy
    assert len(set(zip(labels.tolist(), batch.tolist()))) == len(set(batch.tolist()))


def test_a_short_lag_commits_each_detection_once_and_never_revises_a_commit():
    d = traffic(300, seed=1)
    cfg = NetworkStreamConfig(lag=20.0, warmup_rows=300)
    labels, updates, tracker = stream(d, cfg)
    assert (labels > -2).all()  # every detection committed exactly once
    assert score(d, labels).accuracy > 0.95
    # commits came before the end: the stream did not wait for the flush
    assert sum(u.committed.shape[0] for u in updates[:-1]) > 0.5 * len(d)
    assert tracker.lag >= 2 * 20.0  # grown to twice the p95 link time (about 24 s + 20 s)
    # the last update of each track is FINAL and holds exactly its committed detections
    last = {}
    for u in updates:
        for t in u.tracks:
            last[t.track_id] = t
    for tid, t in last.items():
        assert t.status == FINAL
        assert sorted(t.keys.tolist()) == sorted(np.flatnonzero(labels == tid).tolist())
    assert set(np.unique(labels[labels >= 0]).tolist()) <= set(last)
    assert tracker.stats()['committed'] == len(d) and tracker.working_set == 0
    # once a model is there, the immediate link joins most detections to their vehicle's
    # track at once: each vehicle starts one track, and few detections more start one
    assert tracker.stats()['started'] < 1.2 * 300


@pytest.mark.parametrize('fail', [False, True])
def test_solves_beside_the_stream_commit_what_solves_inside_it_commit(fail):
    d = traffic(300, seed=1)
    cfg = NetworkStreamConfig(lag=20.0, warmup_rows=300)
    inline, _, _ = stream(d, cfg)
    executor = LateExecutor(delay=7, fail=fail)
    beside, updates, tracker = stream(d, cfg, executor)
    assert executor.submitted > 10  # the windows went to the executor
    assert (beside > -2).all()
    # the same tracks (ids are numbered as tracks start, which the immediate links decide)
    assert np.array_equal(beside < 0, inline < 0)
    pairs = set(zip(beside.tolist(), inline.tolist()))
    assert len(pairs) == len(set(beside.tolist())) == len(set(inline.tolist()))
    stats = tracker.stats()
    assert stats['executor_errors'] == (stats['solves'] if fail else 0)
    # pushes during a solve in flight still returned with their detection in a track (checked
    # in ``stream``); the tracks end FINAL holding exactly their committed detections
    last = {}
    for u in updates:
        for t in u.tracks:
            last[t.track_id] = t
    for tid in np.unique(beside[beside >= 0]).tolist():
        assert last[tid].status == FINAL
        assert sorted(last[tid].keys.tolist()) == np.flatnonzero(beside == tid).tolist()


def test_a_detection_older_than_the_commit_horizon_is_committed_alone():
    d = traffic(200, seed=2)
    tracker = NetworkStreamTracker(NET, NetworkStreamConfig(lag=20.0, warmup_rows=100))
    for i in np.argsort(d.stamp).tolist():
        tracker.push(i, int(d.sensor_index[i]), float(d.stamp[i]), float(d.velocity[i]))
    assert math.isfinite(tracker.committed_until)
    late = tracker.push(10_000, 0, tracker.committed_until - 5.0, 25.0)
    assert late.committed.tolist() == [[10_000, -1]]
    assert tracker.stats()['late'] == 1


def test_settings_out_of_range_are_refused():
    for bad in ({'lag': 0.0}, {'solve_interval': math.inf}, {'context': -1.0},
                {'calibration_every': 0}, {'warmup_rows': -1}):  # fmt: skip
        with pytest.raises(ValueError):
            NetworkStreamConfig(**bad)
    with pytest.raises(ValueError, match='station index 9'):
        NetworkStreamTracker(NET).push(0, 9, 0.0, 20.0)
