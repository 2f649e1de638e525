"""scorer_node in stream mode, in process (private context): hand-made stream tracks and truth
go straight into its callbacks, the scores it publishes come back over loopback DDS.

Sensors 10, 11, 12 at 100, 200, 300 m; windows of 60 s. Window 0: vehicles 0 and 1 pass
every sensor; vehicle 1's detection at sensor 11 is first published in vehicle 0's track and
then revised, its detection at sensor 12 ends up committed in vehicle 0's track. Window 1:
vehicle 2 and a false alarm first published in its track, then left unassigned.
"""

from __future__ import annotations

import math
import time

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from mlkm_assoc.scorer_node import ScorerNode
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import AssociationScore, Track

pytestmark = pytest.mark.ros

S = conv.NS_PER_S
SENSORS = (10, 11, 12)
POSITIONS = {10: 100.0, 11: 200.0, 12: 300.0}
LAYOUT = Layout(400.0, list(POSITIONS.values()), list(SENSORS), ('a', 'b', 'c'))
TENTATIVE, CONFIRMED, FINAL = Track.STATUS_TENTATIVE, Track.STATUS_CONFIRMED, Track.STATUS_FINAL


def det(sensor: int, t: float, lane: int = 0) -> tuple:
    """A stream row (sensor id, stamp ns, velocity, position, lane, length)."""
    return (sensor, int(t * S), 10.0, POSITIONS[sensor], lane, math.nan)


A = [det(10, 10.0), det(11, 20.0), det(12, 30.0)]  # vehicle 0
B = [det(10, 12.0, 1), det(11, 22.0, 1), det(12, 32.0, 1)]  # vehicle 1
C = [det(10, 70.0), det(11, 80.0), det(12, 90.0)]  # vehicle 2
FA = det(11, 85.0, 1)  # a false alarm


class Harness:
    def __init__(self, context, spin_until, **params) -> None:
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        self.node = ScorerNode(context=context, parameter_overrides=overrides)
        self.probe = Node('stream_scorer_probe', context=context)
        self.scores: list[AssociationScore] = []
        self.probe.create_subscription(
            AssociationScore, qos.SCORE_TOPIC, self.scores.append, qos.SCORE_QOS
        )
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self._spin_until = spin_until
        self.node._on_layout(conv.layout_to_msg(LAYOUT, S))

    def spin_until(self, predicate, timeout: float = 30.0) -> bool:
        return self._spin_until(self.executor, predicate, timeout)

    def tracks(self, tracks, unassigned=(), committed_s: float = 0.0, run: int = 0) -> None:
        self.node._on_tracks(
            conv.stream_tracks_to_msg(
                method='multiframe',
                tracks=tracks,
                unassigned=list(unassigned),
                committed_until_ns=int(committed_s * S),
                solve_time=0.0,
                stamp_ns=0,
                run=run,
            )
        )

    def truth(self, rows, target: int) -> None:
        for sensor, ns, v, _, lane, _ in rows:
            self.node._on_truth(conv.ground_truth_to_msg(0, sensor, ns, target, v, lane))

    def close(self) -> None:
        self.executor.shutdown()
        self.probe.destroy_node()
        self.node.destroy_node()


@pytest.fixture
def harness(rclpy_context, spin_until):
    made: list[Harness] = []

    def make(**params) -> Harness:
        made.append(Harness(rclpy_context, spin_until, **params))
        return made[-1]

    yield make
    for h in made:
        h.close()


def test_stream_windows_hand_computed(harness) -> None:
    h = harness()  # mode auto: stream once stream tracks arrive
    h.truth(A + B, 0)  # truth first: held for both modes until the tracks say which
    h.truth(B, 1)  # (corrects B's target: the last message for a key wins)
    assert h.node._buffered == 6  # episodes mode holds its copy too, for now
    h.tracks([(0, TENTATIVE, A[:1])])
    assert h.node._buffered == 0 and not h.node._open  # a stream: episodes mode forgot it
    h.tracks([(0, CONFIRMED, [A[0], B[1]]), (1, TENTATIVE, [B[0]])], committed_s=5.0)
    h.tracks([(0, CONFIRMED, A[:2]), (1, CONFIRMED, B[:2])], committed_s=40.0)
    h.spin_until(lambda: False, 1.2)
    assert h.scores == []  # window 0 is not committed yet
    h.tracks([(0, FINAL, [*A, B[2]]), (1, FINAL, B[:2])], committed_s=61.0)
    assert h.spin_until(lambda: len(h.scores) == 1)
    w0 = h.scores[0]
    assert (w0.mode, w0.episode_id) == (AssociationScore.MODE_STREAM, 0)
    assert (conv.time_to_ns(w0.window_start), conv.time_to_ns(w0.window_end)) == (0, 60 * S)
    assert (w0.correct, w0.total) == (5, 6) and w0.accuracy == pytest.approx(5 / 6)
    assert (w0.links_published, w0.links_revised) == (6, 1)
    assert w0.revision_rate == pytest.approx(1 / 6)
    assert w0.truth_complete and (w0.truth_expected, w0.truth_received) == (6, 6)
    assert w0.mean_accuracy == pytest.approx(5 / 6) and w0.episodes_scored == 1

    h.tracks([(2, CONFIRMED, [C[0], C[1], FA])], committed_s=70.0)
    h.tracks([(2, FINAL, C)], unassigned=[FA], committed_s=125.0)
    h.truth(C[:2], 2)
    h.truth([FA], -1)
    h.spin_until(lambda: False, 1.2)
    assert len(h.scores) == 1  # window 1 waits for the truth of C at sensor 12
    h.truth(C[2:], 2)
    assert h.spin_until(lambda: len(h.scores) == 2)
    w1 = h.scores[1]
    assert (w1.episode_id, w1.correct, w1.total) == (1, 3, 3) and w1.accuracy == 1.0
    assert (w1.links_published, w1.links_revised) == (4, 1)
    assert w1.revision_rate == pytest.approx(0.25)
    # cumulative: one mapping over both windows, 8 of 9 true detections; revisions 2 of 10
    assert w1.mean_accuracy == pytest.approx(8 / 9) and w1.episodes_scored == 2
    assert w1.cumulative_revision_rate == pytest.approx(0.2)
    # everything of the scored windows was forgotten; late inputs for them are ignored
    held = h.node._stream.scorer.held()
    assert held['stream_buffered_truth'] == 0 and held['stream_tracked_detections'] == 0
    h.truth(A[:1], 0)
    assert h.node._stream.scorer.events['truth_after_score'] == 1


def test_truth_timeout_scores_with_the_truth_at_hand(harness) -> None:
    h = harness(mode='stream', truth_timeout=0.3)
    h.tracks([(0, FINAL, A), (1, FINAL, B)], committed_s=61.0)
    h.truth(A, 0)  # B's truth never comes
    assert h.spin_until(lambda: len(h.scores) == 1)
    s = h.scores[0]
    assert not s.truth_complete and (s.truth_expected, s.truth_received) == (6, 3)
    assert (s.correct, s.total, s.episodes_incomplete) == (3, 3, 1)


FLOAT_FIELDS = (
    'accuracy',
    'link_recall',
    'link_precision',
    'adjusted_rand_index',
    'mean_accuracy',
    'revision_rate',
    'cumulative_revision_rate',
)


def assert_numbers(scores: list[AssociationScore]) -> None:
    """No published score carries NaN or infinity."""
    for s in scores:
        bad = [f for f in FLOAT_FIELDS if not math.isfinite(getattr(s, f))]
        assert not bad, f'score {s.episode_id}: {bad} not finite'


def test_unscorable_window_is_not_published(harness) -> None:
    """Window 0 holds only a false alarm: no accuracy, so nothing is published (logged and
    counted). Window 1 is scored at the timeout with all its truth while its track is not
    FINAL yet: truth_complete, since the truth is. No published number is NaN."""
    h = harness(mode='stream', truth_timeout=0.3)
    h.tracks([], unassigned=[det(11, 30.0, 1)], committed_s=61.0)
    h.truth([det(11, 30.0, 1)], -1)
    h.tracks([(2, CONFIRMED, C)], committed_s=125.0)
    h.truth(C, 2)
    assert h.spin_until(lambda: len(h.scores) >= 1)
    s = h.scores[0]  # window 1's: window 0 is scored first and has nothing to publish
    assert (s.episode_id, s.correct, s.total, s.accuracy) == (1, 3, 3, 1.0)
    assert s.truth_complete and (s.truth_expected, s.truth_received) == (3, 3)
    assert (s.episodes_scored, s.episodes_incomplete, s.mean_accuracy) == (1, 0, 1.0)
    assert (s.links_published, s.links_revised, s.revision_rate) == (3, 0, 0.0)
    assert (h.node._stream.scorer.unscored, h.node._stream.scorer.not_final) == (1, 1)
    assert_numbers(h.scores)


def episode_msgs(episode: int, start_s: float, published_s: float):
    """STARTED and ENDED of an episode of vehicles 0 (A) and 1 (B), 50 s from ``start_s``."""
    start, end = int(start_s * S), int((start_s + 50.0) * S)
    counts = {s: 2 for s in SENSORS}
    return (
        conv.episode_started_msg(episode, 2, start, end, int(published_s * S)),
        conv.episode_ended_msg(episode, 2, start, end, int((published_s + 60) * S), counts),
    )


def final_tracks(episode: int, swap: bool):
    """The episode's final tracks (MODE_EPISODES): A and B, or B's last detection in A's."""
    rows = [*A, *B]
    labels = [0, 0, 0, 1, 1, 0 if swap else 1]
    return conv.tracks_to_msg(
        episode_id=episode,
        method='mlkm',
        final=True,
        segments_done=1,
        segments_total=1,
        sensor_ids=[r[0] for r in rows],
        stamps_ns=[r[1] for r in rows],
        velocities=[r[2] for r in rows],
        positions=[r[3] for r in rows],
        labels=labels,
        solve_time=0.0,
        stamp_ns=0,
        lanes=[r[4] for r in rows],
    )


def test_auto_follows_the_input_both_ways(harness) -> None:
    """mode auto: a stream is scored in windows; an episodes source started after it (its
    stamps from 0 again) is scored per episode, although the association node's flush of its
    stream comes after the first EpisodeInfo; a stream after the episodes is scored in
    windows again, numbered from 0."""
    h = harness(truth_timeout=0.5)
    h.truth(A, 0)
    h.tracks([(0, FINAL, A)], committed_s=61.0)
    assert h.spin_until(lambda: len(h.scores) == 1)
    assert (h.scores[0].mode, h.scores[0].correct) == (AssociationScore.MODE_STREAM, 3)

    started, ended = episode_msgs(0, 0.0, 100.0)
    h.node._on_episode(started)
    h.tracks([], committed_s=61.0)  # the association node flushed its stream
    h.truth(A, 0)
    h.truth(B, 1)
    h.node._on_episode(ended)
    h.node._on_tracks(final_tracks(0, swap=True))
    assert h.spin_until(lambda: len(h.scores) == 2)
    s = h.scores[1]
    assert (s.mode, s.episode_id) == (AssociationScore.MODE_EPISODES, 0)
    assert (s.correct, s.total, s.truth_complete) == (5, 6, True)

    h.tracks([(7, FINAL, C)], committed_s=125.0)  # a stream again
    h.truth(C, 2)
    assert h.spin_until(lambda: len(h.scores) == 3)
    w = h.scores[2]
    assert (w.mode, w.episode_id) == (AssociationScore.MODE_STREAM, 0)
    assert (w.correct, w.total, w.truth_complete) == (3, 3, True)
    assert_numbers(h.scores)


def test_truth_of_a_new_episodes_source_is_not_taken_by_the_stream(harness) -> None:
    """mode auto, scoring a stream: an episodes source starts, and its first ground truth
    arrives before its first EpisodeInfo and before the node's next tick. The truth is the
    episodes mode's: it waits for its episode there, the stream does not keep it."""
    h = harness()
    h.truth(A, 0)
    h.tracks([(0, CONFIRMED, A)], committed_s=5.0)
    assert h.node._stream.active
    source = h.probe.create_publisher(
        type(episode_msgs(0, 0.0, 0.0)[0]), qos.EPISODE_TOPIC, qos.EPISODE_QOS
    )
    deadline = time.monotonic() + 30.0
    while h.node.count_publishers(qos.EPISODE_TOPIC) < 1:  # the graph, not the executor
        assert time.monotonic() < deadline
        time.sleep(0.01)
    held = len(h.node._stream.scorer.truth)
    h.truth(B, 1)
    assert not h.node._stream.active
    assert len(h.node._stream.scorer.truth) == held
    assert sorted(k[0] for k in h.node._open[0].truth) == list(SENSORS)
    h.probe.destroy_publisher(source)


def test_a_later_run_ends_the_earlier_ones_tracks(harness) -> None:
    """The association node restarted: run R1's tracks stay CONFIRMED, its committed_until
    stops at 40 s, its newest detection is at 82 s. R2's first message (empty, committed_until
    0) ends R1: window 0 is scored at once, long before truth_timeout, with R1's tracks as
    last carried; window 1 waits for R2's own commits. A late message of R1 reopens nothing:
    its tracks count as FINAL, its committed_until is not R2's."""
    r1, r2 = 1_700_000_000_000_000, 1_700_000_000_500_000  # runs [us since the epoch]
    d = [det(10, 62.0), det(11, 72.0), det(12, 82.0)]  # vehicle 3
    h = harness(mode='stream', truth_timeout=60.0)
    h.truth(A, 0)
    h.truth(B, 1)
    h.truth(C, 2)
    h.truth(d, 3)
    scorer = h.node._stream.scorer
    h.tracks(
        [(r1, CONFIRMED, [*A, B[2]]), (r1 + 1, CONFIRMED, B[:2]), (r1 + 2, CONFIRMED, d)],
        committed_s=40.0,
        run=r1,
    )
    assert scorer.ready(time.monotonic()) == []  # 40 s: window 0 is not committed yet

    began = time.monotonic()
    h.tracks([], run=r2)  # the restarted node announces its run
    assert h.spin_until(lambda: len(h.scores) == 1)
    assert time.monotonic() - began < 30.0  # not the truth_timeout (60 s)
    w0 = h.scores[0]
    assert (w0.episode_id, w0.correct, w0.total) == (0, 5, 6)
    assert w0.accuracy == pytest.approx(5 / 6) and w0.mean_accuracy == pytest.approx(5 / 6)
    assert w0.truth_complete and (w0.truth_expected, w0.truth_received) == (6, 6)
    assert (w0.links_published, w0.links_revised, w0.episodes_scored) == (6, 0, 1)
    assert scorer.not_final == 0  # R1's tracks counted as FINAL
    assert (scorer.events['runs_ended'], scorer.events['tracks_ended_with_run']) == (1, 3)
    assert scorer.ready(time.monotonic()) == []  # window 1 waits for R2's commits

    # a late message of R1: d split, A again (its window is scored), a larger commit
    h.tracks(
        [(r1, CONFIRMED, A), (r1 + 2, CONFIRMED, d[:2]), (r1 + 3, TENTATIVE, d[2:])],
        committed_s=45.0,
        run=r1,
    )
    assert scorer.events['tracks_of_ended_run'] == 1
    assert scorer.events['tracks_after_score'] == 3
    assert [scorer.current[k[0], k[4], k[1]][:2] for k in d] == [
        (r1 + 2, FINAL),
        (r1 + 2, FINAL),
        (r1 + 3, FINAL),
    ]
    assert scorer.committed_until == 0 and scorer.ready(time.monotonic()) == []

    h.tracks([(r2, FINAL, C)], committed_s=121.0, run=r2)
    assert h.spin_until(lambda: len(h.scores) == 2)
    assert time.monotonic() - began < 45.0
    w1 = h.scores[1]
    # d: r1 + 2 -> vehicle 3 (2 of 3), r1 + 3 unmatched; C: r2 -> vehicle 2 (3 of 3)
    assert (w1.episode_id, w1.correct, w1.total) == (1, 5, 6)
    assert w1.accuracy == pytest.approx(5 / 6) and w1.truth_complete
    # d's last link was revised by the late message (d[2] begins r1 + 3)
    assert (w1.links_published, w1.links_revised) == (6, 1)
    # cumulative: r1 -> 0 (3), r1 + 1 -> 1 (2), r1 + 2 -> 3 (2), r2 -> 2 (3): 10 of 12
    assert w1.mean_accuracy == pytest.approx(10 / 12) and w1.episodes_scored == 2
    assert w1.cumulative_revision_rate == pytest.approx(1 / 12)
    assert_numbers(h.scores)


def test_a_track_id_beyond_int64_is_refused(harness) -> None:
    """Track ids are uint64; one the scorer cannot hold is refused with a reason, and the
    stream goes on."""
    h = harness(mode='stream', truth_timeout=60.0)
    h.tracks([(2**63, FINAL, A)], committed_s=61.0, run=1)
    assert h.node._rejected['invalid_tracks'] == 1
    assert h.node._stream.scorer.held()['stream_tracked_detections'] == 0
    h.truth(A, 0)
    h.tracks([(1, FINAL, A)], committed_s=61.0, run=1)
    assert h.spin_until(lambda: len(h.scores) == 1)
    assert (h.scores[0].correct, h.scores[0].total) == (3, 3)
    assert_numbers(h.scores)
