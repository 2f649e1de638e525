"""scorer_node in process (private context): inputs are handed to its callbacks, the scores it
publishes are received over loopback DDS by a probe node. A renamed, namespaced scorer
started as its own process reads the installed parameter file and a user's one.

The episodes are hand-made: sensors 10, 11, 12 at 100, 200, 300 m; targets 0 and 1 pass each
sensor once (six true detections); the tracks either get them right or swap one detection.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
from ament_index_python.packages import get_package_share_directory
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import GetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from mlkm_assoc.scorer_node import ScorerNode
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import AssociationScore

S = conv.NS_PER_S
SENSORS = (10, 11, 12)
POSITIONS = (100.0, 200.0, 300.0)
LAYOUT = Layout(
    road_length=400.0,
    positions=np.array(POSITIONS),
    sensor_ids=np.array(SENSORS),
    names=('a', 'b', 'c'),
)


def passages(offset_s: float) -> list[tuple[int, int, int]]:
    """(sensor id, stamp ns, target) of the six true detections, ``offset_s`` later."""
    out = []
    for target, t0 in ((0, 10.0), (1, 12.0)):
        for k, sensor in enumerate(SENSORS):
            out.append((sensor, int((offset_s + t0 + 10.0 * k) * S), target))
    return out


class Harness:
    def __init__(self, context, spin_until, **params) -> None:
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        self.node = ScorerNode(context=context, parameter_overrides=overrides)
        self.probe = Node('scorer_probe', context=context)
        self.scores: list[AssociationScore] = []
        self.diag: dict[str, str] = {}
        self.probe.create_subscription(
            AssociationScore, qos.SCORE_TOPIC, self.scores.append, qos.SCORE_QOS
        )
        self.probe.create_subscription(
            DiagnosticArray, qos.DIAGNOSTICS_TOPIC, self._on_diag, qos.DIAGNOSTICS_QOS
        )
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)
        self._spin_until = spin_until
        self.layout(stamp_s=1.0)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        values = conv.diagnostics_values(msg, self.node.get_fully_qualified_name())
        if values is not None:
            self.diag = values

    def spin_until(self, predicate, timeout: float = 30.0) -> bool:
        return self._spin_until(self.executor, predicate, timeout)

    def wait_scores(self, n: int) -> list[AssociationScore]:
        assert self.spin_until(lambda: len(self.scores) >= n), f'{len(self.scores)} scores'
        return self.scores

    # inputs, straight into the node's callbacks
    def layout(self, stamp_s: float) -> None:
        self.node._on_layout(conv.layout_to_msg(LAYOUT, int(stamp_s * S)))

    def started(self, episode: int, offset_s: float, published_s: float) -> None:
        start, end = int(offset_s * S), int((offset_s + 50.0) * S)
        self.node._on_episode(
            conv.episode_started_msg(episode, 2, start, end, int(published_s * S))
        )

    def ended(self, episode: int, offset_s: float, published_s: float) -> None:
        start, end = int(offset_s * S), int((offset_s + 50.0) * S)
        counts = {s: 2 for s in SENSORS}
        self.node._on_episode(
            conv.episode_ended_msg(episode, 2, start, end, int(published_s * S), counts)
        )

    def truth(self, episode: int, offset_s: float, skip: int = 0) -> None:
        for sensor, stamp, target in passages(offset_s)[skip:]:
            self.node._on_truth(conv.ground_truth_to_msg(episode, sensor, stamp, target, 30.0))

    def final(self, episode: int, offset_s: float, swap: bool = False) -> None:
        """Final tracks: right, or with target 1's detection at sensor 12 in track 0."""
        rows = passages(offset_s)
        labels = [target for _, _, target in rows]
        if swap:
            labels[5] = 0
        self.node._on_tracks(
            conv.tracks_to_msg(
                episode_id=episode,
                method='mlkm',
                final=True,
                segments_done=1,
                segments_total=1,
                sensor_ids=[r[0] for r in rows],
                stamps_ns=[r[1] for r in rows],
                velocities=[30.0] * 6,
                positions=[POSITIONS[SENSORS.index(r[0])] for r in rows],
                labels=labels,
                solve_time=0.0,
                stamp_ns=0,
            )
        )

    def episode(self, episode: int, offset_s: float, published_s: float, swap=False) -> None:
        self.started(episode, offset_s, published_s)
        self.truth(episode, offset_s)
        self.ended(episode, offset_s, published_s + 60.0)
        self.final(episode, offset_s, swap)

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


def test_complete_episode_hand_computed(harness) -> None:
    """Truth after the tracks: scored once the ENDED counts are met; one swapped detection
    of six true ones gives 5/6."""
    h = harness()
    h.started(0, 0.0, 2.0)
    h.final(0, 0.0, swap=True)
    h.ended(0, 0.0, 60.0)
    h.truth(0, 0.0, skip=1)
    h.spin_until(lambda: False, timeout=0.3)
    assert h.scores == []  # one truth message is still missing
    h.truth(0, 0.0)
    (s,) = h.wait_scores(1)
    assert (s.episode_id, s.correct, s.total) == (0, 5, 6)
    assert s.accuracy == pytest.approx(5 / 6)
    assert s.truth_complete and (s.truth_expected, s.truth_received) == (6, 6)
    assert (s.episodes_scored, s.episodes_incomplete) == (1, 0)
    assert s.mean_accuracy == pytest.approx(5 / 6)


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
        assert not bad, f'episode {s.episode_id}: {bad} not finite'


def test_unscorable_episode_is_never_published(harness) -> None:
    """No truth at all (with or without ENDED): no accuracy, so nothing is published, the
    episode is logged and counted unscored; partial truth: scored over what arrived, flagged,
    outside the mean, whose value is 0 (never NaN) while no episode is in it; the mean holds
    complete ones only. No published number is NaN."""
    h = harness(truth_timeout=0.2, diagnostics_period=0.1)
    h.started(0, 0.0, 2.0)
    h.ended(0, 0.0, 60.0)
    h.final(0, 0.0)
    assert h.spin_until(lambda: h.diag.get('episodes_unscored') == '1')

    h.started(1, 100.0, 70.0)
    h.ended(1, 100.0, 160.0)
    h.truth(1, 100.0, skip=2)  # 4 of 6
    h.final(1, 100.0, swap=True)
    (s,) = h.wait_scores(1)
    assert (s.episode_id, s.correct, s.total) == (1, 3, 4)
    assert not s.truth_complete and (s.truth_expected, s.truth_received) == (6, 4)
    assert (s.episodes_scored, s.episodes_incomplete, s.mean_accuracy) == (0, 1, 0.0)

    h.episode(2, 200.0, 170.0, swap=True)
    h.final(3, 300.0)  # ENDED and truth never came: not scored either
    s2 = h.wait_scores(2)[1]
    assert s2.truth_complete and s2.accuracy == pytest.approx(5 / 6)
    assert (s2.episodes_scored, s2.episodes_incomplete) == (1, 1)
    assert s2.mean_accuracy == pytest.approx(5 / 6)
    assert h.spin_until(lambda: h.diag.get('episodes_unscored') == '2')
    assert [s.episode_id for s in h.scores] == [1, 2]
    assert h.diag['mean_accuracy'] == f'{5 / 6:.6f}'
    assert_numbers(h.scores)


def test_waits_for_truth_while_it_keeps_arriving(harness) -> None:
    """The final tracks and ENDED of episodes 0 and 1 come first and their truth trickles in
    after them, ending long after truth_timeout (a backlog of the truth topic): each episode
    is scored with its whole truth; while they wait /diagnostics says which episode misses
    how many ground-truth messages."""
    h = harness(truth_timeout=3.0, diagnostics_period=0.1)
    for e in (0, 1):
        h.started(e, 100.0 * e, 2.0 + e)
        h.ended(e, 100.0 * e, 60.0 + e)
        h.final(e, 100.0 * e, swap=e == 1)
    assert h.spin_until(
        lambda: (
            h.diag.get('truth_waiting') == 'episode 0: 6 of 6 missing; episode 1: 6 of 6 missing'
        )
    ), h.diag
    assert h.diag['episodes_waiting_for_truth'] == '2'
    rows = [(e, row) for e in (0, 1) for row in passages(100.0 * e)]
    for k, (e, (sensor, stamp, target)) in enumerate(rows):
        # one message every 0.5 s: 6 s in all, each gap well inside truth_timeout
        h.spin_until(lambda: False, timeout=0.5)
        h.node._on_truth(conv.ground_truth_to_msg(e, sensor, stamp, target, 30.0))
        if k == 8:
            assert h.spin_until(
                lambda: h.diag.get('truth_waiting') == 'episode 1: 3 of 6 missing'
            ), h.diag
            assert len(h.scores) == 1  # episode 0 was complete
    s0, s1 = h.wait_scores(2)
    assert (s0.episode_id, s0.correct, s0.total, s0.truth_complete) == (0, 6, 6, True)
    assert (s1.episode_id, s1.correct, s1.total, s1.truth_complete) == (1, 5, 6, True)
    assert (s1.episodes_scored, s1.episodes_incomplete) == (2, 0)
    assert h.spin_until(lambda: h.diag.get('episodes_waiting_for_truth') == '0')


def test_restarted_source_is_scored_again(harness) -> None:
    """Episode ids from 0 again: a new window for a known id, or the same layout and window
    published again later (a same-seed restart), each start a new run that is scored."""
    h = harness()
    h.episode(0, 0.0, 2.0)
    assert h.wait_scores(1)[0].accuracy == 1.0
    # another window for episode 0: a new run
    h.episode(0, 1000.0, 900.0, swap=True)
    s = h.wait_scores(2)[1]
    assert (s.episode_id, s.correct, s.total, s.truth_complete) == (0, 5, 6, True)
    # the simulator restarted with the same seed: same layout, same window, later stamps
    h.layout(stamp_s=2000.0)
    h.episode(0, 1000.0, 2001.0)
    s = h.wait_scores(3)[2]
    assert (s.episode_id, s.correct, s.total, s.truth_complete) == (0, 6, 6, True)
    assert s.episodes_scored == 3 and s.mean_accuracy == pytest.approx((1 + 5 / 6 + 1) / 3)
    # repeated inputs of the scored episode are not scored again
    h.final(0, 1000.0)
    h.truth(0, 1000.0)
    h.started(0, 1000.0, 2001.0)
    h.spin_until(lambda: False, timeout=0.5)
    assert len(h.scores) == 3


def test_new_run_truth_before_its_episode_info(harness) -> None:
    """Truth of the new run arrives before its EpisodeInfo: kept for the new run."""
    h = harness()
    h.episode(0, 0.0, 2.0)
    h.wait_scores(1)
    h.truth(0, 500.0)  # outside the scored window: not the old episode's
    h.started(0, 500.0, 400.0)
    h.ended(0, 500.0, 460.0)
    h.final(0, 500.0, swap=True)
    s = h.wait_scores(2)[1]
    assert (s.correct, s.total, s.truth_complete) == (5, 6, True)


def test_old_run_final_after_the_new_layout_is_still_scored(harness) -> None:
    """The association node's last final of the old run can arrive after the restarted
    source's layout: it is scored with its truth, complete; the new run's episode 0 too."""
    h = harness()
    h.started(0, 0.0, 2.0)
    h.truth(0, 0.0)
    h.ended(0, 0.0, 60.0)
    h.layout(stamp_s=100.0)  # the source restarted
    h.final(0, 0.0, swap=True)
    s = h.wait_scores(1)[0]
    assert (s.episode_id, s.correct, s.total, s.truth_complete) == (0, 5, 6, True)
    h.episode(0, 0.0, 101.0)  # the new run: same window, published later
    s = h.wait_scores(2)[1]
    assert (s.episode_id, s.correct, s.truth_complete, s.episodes_scored) == (0, 6, True, 2)


def test_memory_stays_bounded(harness) -> None:
    """Scored ids are remembered up to max_scored_episodes; unscored episodes are dropped
    beyond max_open_episodes and after forget_after; truth beyond max_buffered_truth is
    rejected; all counted in /diagnostics."""
    h = harness(
        max_scored_episodes=3,
        max_open_episodes=4,
        forget_after=0.5,
        max_buffered_truth=30,
        diagnostics_period=0.1,
    )
    for e in range(10):
        h.episode(e, 100.0 * e, 100.0 * e + 2.0)
    assert len(h.wait_scores(10)) == 10
    assert len(h.node._scored) == 3 and not h.node._open
    for e in range(10, 20):  # truth only, the association never finished them
        h.truth(e, 100.0 * e)
    assert len(h.node._open) <= 4
    assert h.node._buffered == sum(len(ep.truth) for ep in h.node._open.values()) <= 30
    assert h.spin_until(lambda: not h.node._open and h.node._buffered == 0)
    assert h.spin_until(lambda: h.diag.get('open_episodes') == '0')
    assert int(h.diag['episodes_dropped']) == 10
    assert int(h.diag['rejected_truth_buffer_full']) == 0
    # one episode bigger than the buffer: the excess is rejected, nothing else
    h2 = harness(max_buffered_truth=4, diagnostics_period=0.1)
    h2.truth(50, 0.0)
    assert h2.node._buffered == 4
    assert h2.spin_until(lambda: h2.diag.get('rejected_truth_buffer_full') == '2')


def test_malformed_inputs_are_rejected_and_scoring_goes_on(harness) -> None:
    h = harness(diagnostics_period=0.1)
    bad = conv.tracks_to_msg(
        episode_id=0,
        method='mlkm',
        final=True,
        segments_done=1,
        segments_total=1,
        sensor_ids=[10, 11],
        stamps_ns=[10 * S, 20 * S],
        velocities=[30.0, 30.0],
        positions=[100.0, 200.0],
        labels=[0, 0],
        solve_time=0.0,
        stamp_ns=0,
    )
    bad.tracks[0].velocities = [30.0]  # parallel arrays of different length
    h.node._on_tracks(bad)
    info = conv.episode_ended_msg(0, 2, 0, 50 * S, 60 * S, {10: 2})
    info.detection_counts = [2, 2]
    h.node._on_episode(info)
    h.episode(0, 0.0, 2.0, swap=True)
    (s,) = h.wait_scores(1)
    assert (s.correct, s.total, s.truth_complete) == (5, 6, True)
    assert h.spin_until(lambda: h.diag.get('rejected_invalid_tracks') == '1')
    assert h.diag['rejected_invalid_episode'] == '1'


def test_renamed_namespaced_scorer_reads_the_param_files(
    ros_process, rclpy_context, spin_until, tmp_path
) -> None:
    """The installed file keyed /** and a user's file reach a node started as
    /site_a/my_scorer; a value from the user's file wins, the others are the defaults."""
    installed = (
        Path(get_package_share_directory('mlkm_assoc')) / 'config' / 'scorer_node.param.yaml'
    )
    user = tmp_path / 'mine.param.yaml'
    user.write_text('/**:\n  ros__parameters:\n    truth_timeout: 42.5\n')
    proc = ros_process(
        'mlkm_assoc',
        'scorer_node',
        '--ros-args',
        '-r',
        '__node:=my_scorer',
        '-r',
        '__ns:=/site_a',
        '--params-file',
        installed,
        '--params-file',
        user,
    )
    node = Node('param_probe', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    try:
        client = node.create_client(GetParameters, '/site_a/my_scorer/get_parameters')
        assert spin_until(executor, client.service_is_ready, 60.0), proc.output()
        request = GetParameters.Request(names=['truth_timeout', 'max_open_episodes'])
        # The client sees the server before the server has matched the client's response
        # reader, and a request or response sent in that moment is lost (DDS discovery is
        # not symmetric): a request without an answer is sent again.
        future = None
        deadline = time.monotonic() + 60.0
        while future is None or not future.done():
            assert time.monotonic() < deadline, proc.output()
            if future is not None:
                client.remove_pending_request(future)
            future = client.call_async(request)
            spin_until(executor, future.done, 5.0)
        values = future.result().values
        assert values[0].double_value == 42.5
        assert values[1].integer_value == 100
    finally:
        executor.shutdown()
        node.destroy_node()
    assert proc.stop() == 0, proc.output()
