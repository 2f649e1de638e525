"""scorer_node in stream mode, in process (private context): hand-made stream tracks and truth
go straight into its callbacks, the scores it publishes come back over loopback DDS.

Sensors 10, 11, 12 at 100, 200, 300 m; windows of 60 s. Window 0: vehicles 0 and 1 pass
every sensor; vehicle 1's detection at sensor 11 is first published in vehicle 0's track and
then revised, its detection at sensor 12 ends up committed in vehicle 0's track. Window 1:
vehicle 2 and a false alarm first published in its track, then left unassigned.
"""

from __future__ import annotations

import math

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

    def tracks(self, tracks, unassigned=(), committed_s: float = 0.0) -> None:
        self.node._on_tracks(
            conv.stream_tracks_to_msg(
                method='multiframe',
                tracks=tracks,
                unassigned=list(unassigned),
                committed_until_ns=int(committed_s * S),
                solve_time=0.0,
                stamp_ns=0,
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
