"""The association node's bookkeeping without ROS: hand-made inputs, a fake clock, the jobs
it hands to the solver."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mlkm_assoc.assembly import Assembler, AssociationConfig, Job
from mlkm_core.types import Layout

IDS = [10, 11, 12, 13]
POS = [100.0, 200.0, 300.0, 400.0]
LAYOUT = Layout(500.0, np.array(POS), np.array(IDS), ('a', 'b', 'c', 'd'))
S = 1_000_000_000  # ns per s
WINDOW = (0, 100 * S)  # episode 0
WINDOW1 = (200 * S, 300 * S)  # episode 1


class Rig:
    """An Assembler with a fake monotonic clock; collects the jobs and rejections."""

    def __init__(self, **config) -> None:
        self.now = 1000.0
        self.jobs: list[Job] = []
        self.reasons: list[str] = []
        cfg = AssociationConfig(segment_size=2, completion_timeout=5.0, **config)
        self.a = Assembler(cfg, self.jobs.append, lambda r, _: self.reasons.append(r))

    def layout(self, stamp: int = 0) -> bool:
        return self.a.set_layout(LAYOUT, self.now, stamp)

    def started(self, eid: int, window=WINDOW, n: int = 2, stamp: int = 0) -> None:
        self.a.add_episode(eid, n, window[0], window[1], None, self.now, stamp)

    def ended(self, eid: int, counts, window=WINDOW, n: int = 2, stamp: int = 0) -> None:
        ended = dict(zip(IDS, counts))
        self.a.add_episode(eid, n, window[0], window[1], ended, self.now, stamp)

    def det(self, s: int, t: float, v: float = 10.0, position: float | None = None) -> None:
        pos = POS[s] if position is None else position
        self.a.add_detection(IDS[s], int(t * S), pos, v, self.now)

    def passages(self, base: float = 0.0, sensors=range(4)) -> None:
        """Two targets, 10 m/s and 20 m/s, entering at ``base`` and ``base + 40`` s."""
        for s in sensors:
            self.det(s, base + POS[s] / 10.0, 10.0)
            self.det(s, base + 40.0 + POS[s] / 20.0, 20.0)

    def advance(self, seconds: float) -> None:
        self.now += seconds
        self.a.tick(self.now)

    def kinds(self) -> list[tuple[str, int]]:
        return [(j.kind, j.episode_id) for j in self.jobs]


def fed(job: Job) -> set[tuple[int, int]]:
    """(sensor index, stamp ns) of every detection in a job."""
    return {
        (int(s), int(t))
        for p in job.parts
        for s, t in zip(p.sensor_index.tolist(), p.stamps_ns.tolist())
    }


def test_segments_complete_by_counts_in_order_and_final_at_ended() -> None:
    r = Rig()
    r.layout()
    r.started(0)
    # Sensor c and d (segment 1) first: segment 1 must wait for segment 0.
    r.passages(sensors=[2, 3])
    assert r.jobs == []
    r.passages(sensors=[0, 1])
    assert r.kinds() == [('segment', 0), ('segment', 0)]
    assert {s for s, _ in fed(r.jobs[0])} == {0, 1}
    assert {s for s, _ in fed(r.jobs[1])} == {2, 3}
    assert r.jobs[0].parts[0].velocities.tolist() == [10.0, 20.0, 10.0, 20.0]
    r.ended(0, [2, 2, 2, 2])
    assert r.kinds()[-1] == ('final', 0)
    assert r.jobs[-1].missing == 0 and not r.jobs[-1].forced
    assert r.a.accepted == 8 and r.a.episodes_final == 1


def test_detections_go_to_the_episode_whose_window_holds_them() -> None:
    r = Rig()
    r.layout()
    r.started(0)
    r.started(1, WINDOW1)
    r.passages(200.0)  # episode 1 first
    r.passages(0.0)
    segs = [j for j in r.jobs if j.kind == 'segment']
    assert [j.episode_id for j in segs] == [1, 1, 0, 0]
    assert all(t >= 200 * S for j in segs[:2] for _, t in fed(j))
    assert all(t < 100 * S for j in segs[2:] for _, t in fed(j))


def test_detection_before_its_episode_is_held_then_placed_or_rejected() -> None:
    r = Rig()
    r.layout()
    r.det(0, 10.0)  # STARTED not there yet
    assert r.a.buffer_sizes()['held_without_episode'] == 1
    r.started(0)
    assert r.a.buffer_sizes()['held_without_episode'] == 0
    assert r.a.accepted == 1
    r.det(0, 150.0)  # no episode holds it
    r.advance(6.0)
    assert r.reasons == ['outside_episode']


def test_detection_before_the_layout_is_held() -> None:
    r = Rig()
    r.det(0, 10.0)
    r.det(1, 20.0, v=math.nan)  # refused at once, not held
    assert r.a.handled['before_layout'] == 1 and r.reasons == ['nan_velocity']
    r.started(0)
    r.layout()
    assert r.a.accepted == 1


def test_refused_values_are_rejected_with_reasons_and_never_complete_a_sensor() -> None:
    r = Rig()
    r.layout()
    r.started(0)
    r.ended(0, [2, 2, 2, 2])
    r.passages(sensors=[0, 1, 2])
    r.det(3, 40.0)  # the first passage at d; the second is still in flight
    bad = [math.nan, math.inf, 0.0, -5.0, 1e308, 5e-324]
    for i, v in enumerate(bad):
        r.det(3, 50.0 + i, v)
    r.det(3, 60.0, position=123.0)
    r.a.add_detection(99, 61 * S, 400.0, 10.0, r.now)
    r.det(3, 40.0)  # duplicate
    assert r.reasons == [
        'nan_velocity',
        'inf_velocity',
        'zero_velocity',
        'negative_velocity',
        'speed_out_of_range',
        'speed_out_of_range',
        'position_mismatch',
        'unknown_sensor',
        'duplicate',
    ]
    assert ('final', 0) not in r.kinds()  # refused messages did not complete sensor d
    r.det(3, 60.0, 20.0)
    assert r.kinds()[-1] == ('final', 0)
    assert r.a.accepted == 8


def test_stamp_outside_the_bounds_is_rejected() -> None:
    r = Rig(max_stamp=50.0)
    r.layout()
    r.started(0)
    r.det(0, 60.0)
    assert r.reasons == ['stamp_out_of_range']
    r.a.config = AssociationConfig(segment_size=2, max_speed=1e9)
    r.det(0, 60.0, v=1e6)
    assert r.a.accepted == 1


def test_out_of_order_kept_and_late_detection_reruns_the_episode() -> None:
    r = Rig()
    r.layout()
    r.started(0)
    r.det(0, 50.0, 20.0)  # target 2 before target 1 at sensor a: out of order
    r.det(0, 10.0, 10.0)
    assert r.a.handled['out_of_order'] == 1
    r.passages(sensors=[1, 2, 3])
    assert r.kinds() == [('segment', 0), ('segment', 0)]
    r.ended(0, [3, 2, 2, 2])  # sensor a published a third (clutter), late for its segment
    r.det(0, 90.0, 15.0)
    assert r.a.handled['late_for_segment'] == 1
    assert r.kinds()[-1] == ('rerun', 0)
    rerun = r.jobs[-1]
    assert len(rerun.parts) == 2 and len(fed(rerun)) == 9
    assert (0, 90 * S) in fed(rerun)


def test_ended_episode_short_of_its_counts_completes_by_timeout_with_missing() -> None:
    r = Rig()
    r.layout()
    r.started(0)
    r.passages(sensors=[0, 1, 2])
    r.det(3, 40.0)
    r.ended(0, [2, 2, 2, 2])
    r.advance(4.0)
    assert ('final', 0) not in r.kinds()
    r.advance(2.0)
    final = r.jobs[-1]
    assert (final.kind, final.forced, final.missing) == ('final', True, 1)
    assert r.a.handled['completion_timeout'] == 1 and r.a.missing == 1
    assert r.a.buffer_sizes()['buffered_open_episodes'] == 0


def test_episode_that_never_ends_times_out_and_frees_its_buffer() -> None:
    r = Rig(episode_timeout=30.0)
    r.layout()
    r.started(0)
    r.det(0, 10.0)
    r.det(1, 20.0)
    r.advance(29.0)
    assert r.a.buffer_sizes()['buffered_open_episodes'] == 2
    r.advance(2.0)
    assert r.kinds() == [('segment', 0), ('segment', 0), ('final', 0)]
    assert r.a.handled['episode_timeout'] == 1
    assert r.a.buffer_sizes() == {
        'buffered_open_episodes': 0,
        'held_before_layout': 0,
        'held_without_episode': 0,
        'open_episodes': 0,
    }
    r.det(0, 30.0)
    assert r.reasons == ['after_episode_final']


def test_unseen_episode_gets_no_final_and_counts_missing() -> None:
    """A node that starts late receives latched STARTED and ENDED of episodes it never saw."""
    r = Rig()
    r.layout()
    r.started(0)
    r.ended(0, [2, 2, 2, 1])
    r.advance(6.0)
    assert r.jobs == []
    assert r.a.episodes_unseen == 1 and r.a.missing == 7
    assert r.a.buffer_sizes()['open_episodes'] == 0


def test_restarted_source_begins_a_new_run() -> None:
    r = Rig()
    r.layout(stamp=100)
    r.started(0, stamp=100)
    r.passages()
    r.ended(0, [2, 2, 2, 2], stamp=100)
    assert r.kinds()[-1] == ('final', 0)
    assert not r.layout(stamp=100)  # the same message again: nothing happens
    # Restart with the same seed: same layout and window, published later.
    r.started(0, stamp=500)
    assert r.a.runs == 2
    assert not r.layout(stamp=400)  # its layout, overtaken by its STARTED: same run
    assert r.a.runs == 2
    r.det(0, 10.0)  # open again for the new run
    r.started(1, WINDOW1, stamp=500)
    r.det(0, 210.0)
    # The source restarts while episode 0 is open: it is finalised with what it has.
    n_jobs = len(r.jobs)
    assert r.layout(stamp=900)
    assert r.a.runs == 3
    assert [k for k, _ in r.kinds()[n_jobs:]] == ['segment', 'segment', 'final'] * 2
    assert r.reasons == []


def test_known_id_with_another_window_begins_a_new_run() -> None:
    r = Rig()
    r.layout()
    r.started(0)
    r.det(0, 10.0)
    r.started(0, WINDOW1)
    assert r.a.runs == 2
    assert r.kinds()[-1] == ('final', 0)  # the old run's episode 0, with what it had
    assert r.a.knows_episode(0, WINDOW1[0])
    r.det(0, 210.0)
    assert r.a.accepted == 2 and r.reasons == []


def test_finished_episodes_are_forgotten_beyond_the_limit() -> None:
    r = Rig(max_finished_episodes=3)
    r.layout()
    for k in range(10):
        window = (k * 200 * S, k * 200 * S + 100 * S)
        r.started(k, window)
        r.passages(k * 200.0)
        r.ended(k, [2, 2, 2, 2], window)
    assert r.a.episodes_final == 10
    assert r.a.remembered_episodes() == 3
    r.det(0, 10.0)  # late for a forgotten episode
    r.det(0, 9 * 200.0 + 10.0)  # late for a remembered one
    assert r.reasons == ['outside_episode', 'after_episode_final']
    r.ended(0, [2, 2, 2, 2])  # the same source, an old message: ignored
    assert r.a.runs == 1 and r.a.handled['stale_episode_info'] == 1


@pytest.mark.parametrize(
    'kwargs', [{'min_speed': 0.0}, {'min_speed': 5.0, 'max_speed': 1.0}, {'max_stamp': math.inf}]
)
def test_contradicting_bounds_are_refused(kwargs) -> None:
    with pytest.raises(ValueError):
        AssociationConfig(**kwargs).bounds()
