"""In-process tests of the association node (private rclpy Context, a test publisher).

A hand-made road with a known association: 4 sensors, 3 targets far apart in time, so the
right answer is certain. Bad inputs are mixed into the stream; each one must be rejected or
handled with its reason counted in /diagnostics, and every valid detection must end up in the
final tracks or the unassigned arrays.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from visualization_msgs.msg import Marker, MarkerArray

from mlkm_assoc.association_node import AssociationNode
from mlkm_core.associators.base import available_methods
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from mlkm_ros.params import ParameterError
from road_sensor_msgs.msg import Detection, EpisodeInfo, SensorLayout, TrackArray

pytestmark = pytest.mark.ros

IDS = [10, 11, 12, 13]
NAMES = ['s_a', 's_b', 's_c', 's_d']
POS = [100.0, 200.0, 300.0, 400.0]
LAYOUT = Layout(500.0, np.array(POS), np.array(IDS), tuple(NAMES))
#: target -> (entry time [s], speed [m/s]); passages 30-40 s apart: the answer is certain.
TARGETS = {0: (0.0, 10.0), 1: (50.0, 20.0), 2: (100.0, 40.0)}


def passages(offset: float = 0.0) -> list[tuple[int, int, float, int]]:
    """(sensor index, stamp ns, velocity, target) of every true passage."""
    out = []
    for target, (t0, v) in TARGETS.items():
        for s, p in enumerate(POS):
            out.append((s, conv.seconds_to_ns(offset + t0 + p / v), v, target))
    return out


class Harness:
    """A test node with publishers for layout, episodes and each sensor; collects outputs."""

    def __init__(self, context, spin_until, **params) -> None:
        overrides = [
            Parameter('diagnostics_period', value=0.2),
            Parameter('completion_timeout', value=1.0),
        ]
        overrides += [Parameter(k, value=v) for k, v in params.items()]
        self.node = AssociationNode(context=context, parameter_overrides=overrides)
        self.test = Node('association_test', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.test)
        self.spin_until = spin_until
        self.layout_pub = self.test.create_publisher(
            SensorLayout, qos.LAYOUT_TOPIC, qos.LAYOUT_QOS
        )
        self.episode_pub = self.test.create_publisher(
            EpisodeInfo, qos.EPISODE_TOPIC, qos.EPISODE_QOS
        )
        self.det_pubs = [
            self.test.create_publisher(Detection, qos.detections_topic(n), qos.DETECTIONS_QOS)
            for n in NAMES
        ]
        self.tracks: list[TrackArray] = []
        self.diag: dict[str, str] = {}
        self.diag_level: int | None = None
        self.diag_message = ''
        self.test.create_subscription(
            TrackArray, qos.TRACKS_TOPIC, self.tracks.append, qos.TRACKS_QOS
        )
        self.test.create_subscription(
            DiagnosticArray, qos.DIAGNOSTICS_TOPIC, self._on_diag, qos.DIAGNOSTICS_QOS
        )

    def _on_diag(self, msg: DiagnosticArray) -> None:
        name = self.node.get_fully_qualified_name()
        values = conv.diagnostics_values(msg, name)
        if values is not None:
            self.diag = values
            status = next(st for st in msg.status if st.name == name)
            self.diag_level = status.level[0]
            self.diag_message = status.message

    def wait(self, predicate, timeout: float = 120.0) -> None:
        # an upper bound only: the solver process may take a minute to start on a busy machine
        assert self.spin_until(self.executor, predicate, timeout), 'timed out'

    def wait_matched(self) -> None:
        self.wait(lambda: all(p.get_subscription_count() >= 1 for p in self.det_pubs))

    def detect(
        self,
        s: int,
        stamp_ns: int,
        velocity: float,
        *,
        sensor_id: int | None = None,
        position: float | None = None,
    ) -> None:
        self.det_pubs[s].publish(
            conv.detection_to_msg(
                IDS[s] if sensor_id is None else sensor_id,
                stamp_ns,
                POS[s] if position is None else position,
                velocity,
            )
        )

    def finals(self) -> dict[int, TrackArray]:
        return {m.episode_id: m for m in self.tracks if m.final}

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.test.destroy_node()


@pytest.fixture
def harness(rclpy_context, spin_until):
    made = []

    def make(**params) -> Harness:
        h = Harness(rclpy_context, spin_until, **params)
        made.append(h)
        return h

    yield make
    for h in made:
        h.close()


def keyed(msg: TrackArray) -> dict[tuple[int, int], int]:
    ids, stamps, _, labels = conv.tracks_from_msg(msg)
    return dict(zip(zip(ids.tolist(), stamps.tolist()), labels.tolist()))


def window(offset: float) -> tuple[int, int]:
    stamps = [p[1] for p in passages(offset)]
    return min(stamps), max(stamps) + conv.seconds_to_ns(20.0)


def test_known_association_with_every_bad_input(harness) -> None:
    h = harness(method='mlkm', segment_size=2)
    # Detection before the layout: the node finds the sensor topic in the graph, holds the
    # detection, and checks it once the layout is known.
    h.wait_matched()
    valid = passages()
    first = valid[0]
    h.detect(first[0], first[1], first[2])
    h.wait(lambda: h.node.assembler.handled['before_layout'] == 1)
    h.layout_pub.publish(conv.layout_to_msg(LAYOUT, 0))
    h.wait(lambda: h.node.assembler.layout is not None)
    start, end = window(0.0)
    h.episode_pub.publish(conv.episode_started_msg(0, 3, start, end, 0))
    h.wait(lambda: h.node.assembler.knows_episode(0))

    # Sensor c (index 2) receives target 1 before target 0: a stamp out of order.
    rest = valid[1:]
    c_t0 = next(p for p in rest if p[0] == 2 and p[3] == 0)
    c_t1 = next(p for p in rest if p[0] == 2 and p[3] == 1)
    rest = [p for p in rest if p not in (c_t0, c_t1)]
    h.detect(2, c_t1[1], c_t1[2])
    h.detect(2, c_t0[1], c_t0[2])
    for s, ns, v, _ in rest:
        h.detect(s, ns, v)
    s15 = conv.seconds_to_ns(15.0)
    h.detect(0, s15, math.nan)
    h.detect(0, s15 + 1, math.inf)
    h.detect(0, s15 + 2, 0.0)
    h.detect(0, s15 + 3, -12.0)
    h.detect(0, s15 + 4, 12.0, position=150.0)  # not where sensor a stands
    h.detect(0, s15 + 5, 12.0, sensor_id=99)  # unknown sensor id
    dup = next(p for p in valid if p[0] == 1)
    h.detect(1, dup[1], dup[2])  # duplicate (same sensor and stamp)
    extra_ns = conv.seconds_to_ns(115.0)
    h.detect(3, extra_ns, 25.0)  # a 4th detection at a sensor that saw 3 targets
    h.detect(2, conv.seconds_to_ns(5.0), 20.0)  # before the episode's window
    # ENDED counts every message each sensor published, refused ones included; only accepted
    # detections count towards completion, so this episode completes by completion_timeout.
    counts = {10: 3 + 5, 11: 3 + 1, 12: 3, 13: 3 + 1}
    h.episode_pub.publish(conv.episode_ended_msg(0, 3, start, end, 0, counts))
    h.wait(lambda: 0 in h.finals())
    h.wait(lambda: h.diag.get('episodes_final') == '1')

    d = h.diag
    assert d['received'] == str(len(valid) + 9)
    for reason in (
        'nan_velocity',
        'inf_velocity',
        'zero_velocity',
        'negative_velocity',
        'position_mismatch',
        'unknown_sensor',
        'duplicate',
        'outside_episode',
    ):
        assert d[f'rejected.{reason}'] == '1', reason
    assert d['rejected'] == '8'
    assert d['handled.before_layout'] == '1'
    assert d['handled.out_of_order'] == '1'
    assert d['handled.excess_at_sensor'] == '1'

    # Every valid detection is in a track or unassigned, and the association is right.
    got = keyed(h.finals()[0])
    expected_keys = {(IDS[s], ns) for s, ns, _, _ in valid} | {(13, extra_ns)}
    assert set(got) == expected_keys
    track_of_target = {}
    for s, ns, _, target in valid:
        track_of_target.setdefault(target, set()).add(got[(IDS[s], ns)])
    assert all(len(t) == 1 and -1 not in t for t in track_of_target.values())
    assert len({next(iter(t)) for t in track_of_target.values()}) == 3
    assert h.finals()[0].segments_done == h.finals()[0].segments_total == 2

    # The node keeps working: a clean second episode is associated perfectly.
    start1, end1 = window(1000.0)
    h.episode_pub.publish(conv.episode_started_msg(1, 3, start1, end1, 0))
    second = passages(1000.0)
    for s, ns, v, _ in sorted(second, key=lambda p: p[1]):
        h.detect(s, ns, v)
    h.episode_pub.publish(conv.episode_ended_msg(1, 3, start1, end1, 0, {i: 3 for i in IDS}))
    h.wait(lambda: 1 in h.finals())
    got = keyed(h.finals()[1])
    assert set(got) == {(IDS[s], ns) for s, ns, _, _ in second}
    groups = {}
    for s, ns, _, target in second:
        groups.setdefault(target, set()).add(got[(IDS[s], ns)])
    assert sorted(len(g) for g in groups.values()) == [1, 1, 1]


def test_partial_tracks_segment_by_segment_with_stable_ids(harness) -> None:
    h = harness(method='kmeans_pp', segment_size=2)
    h.layout_pub.publish(conv.layout_to_msg(LAYOUT, 0))
    h.wait(lambda: h.node.assembler.layout is not None)
    h.wait_matched()
    start, end = window(0.0)
    h.episode_pub.publish(conv.episode_started_msg(0, 3, start, end, 0))
    h.wait(lambda: h.node.assembler.knows_episode(0))
    for s, ns, v, _ in sorted(passages(), key=lambda p: p[1]):
        h.detect(s, ns, v)
    # Paper mode: each sensor's segment completes at num_targets detections, before ENDED.
    h.wait(lambda: len(h.tracks) >= 2)
    partial = [m for m in h.tracks if not m.final]
    assert [m.segments_done for m in partial] == [1, 2]
    assert sum(len(t.sensor_ids) for t in partial[0].tracks) == 6  # sensors a and b
    h.episode_pub.publish(conv.episode_ended_msg(0, 3, start, end, 0, {i: 3 for i in IDS}))
    h.wait(lambda: 0 in h.finals())
    first, final = keyed(partial[0]), keyed(h.finals()[0])
    assert all(final[k] == v for k, v in first.items())  # ids stable from partial to final


def test_invalid_parameters_refused(rclpy_context) -> None:
    with pytest.raises(ParameterError, match='unknown method .nope.; choose one of'):
        AssociationNode(
            context=rclpy_context, parameter_overrides=[Parameter('method', value='nope')]
        )
    with pytest.raises(ParameterError, match='segment_size'):
        AssociationNode(
            context=rclpy_context, parameter_overrides=[Parameter('segment_size', value=0)]
        )
    node = AssociationNode(context=rclpy_context)
    try:
        result = node.set_parameters([Parameter('method', value='nope')])[0]
        assert not result.successful
        assert 'choose one of' in result.reason and 'mlkm' in result.reason
        assert node.get_parameter('method').value == 'mlkm'
        for method in available_methods():  # every registered associator is accepted
            assert node.set_parameters([Parameter('method', value=method)])[0].successful
        assert node.config.method == available_methods()[-1]
        assert not node.set_parameters([Parameter('completion_timeout', value=-1.0)])[0].successful
    finally:
        node.destroy_node()


def test_remaps_are_honoured(rclpy_context, spin_until) -> None:
    """-r remaps the layout and a sensor topic; the node listens where it is told."""
    node = AssociationNode(
        context=rclpy_context,
        cli_args=[
            '--ros-args',
            '-r',
            '/road/sensor_layout:=/elsewhere/layout',
            '-r',
            f'/road/sensors/{NAMES[0]}/detections:=/elsewhere/a',
            '-p',
            'mode:=episodes',  # no episode source here: auto would track the stream
        ],
    )
    test = Node('remap_test', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    executor.add_node(test)
    try:
        pub = test.create_publisher(SensorLayout, '/elsewhere/layout', qos.LAYOUT_QOS)
        pub.publish(conv.layout_to_msg(LAYOUT, 0))
        assert spin_until(executor, lambda: node.assembler.layout is not None, 60.0)
        det = test.create_publisher(Detection, '/elsewhere/a', qos.DETECTIONS_QOS)
        assert spin_until(executor, lambda: det.get_subscription_count() >= 1, 60.0)
        det.publish(conv.detection_to_msg(IDS[0], 10**9, POS[0], 10.0))
        assert spin_until(executor, lambda: node.assembler.received == 1, 60.0)
    finally:
        executor.shutdown()
        node.destroy_node()
        test.destroy_node()


def test_new_layout_moves_the_subscriptions(harness) -> None:
    h = harness()
    h.layout_pub.publish(conv.layout_to_msg(LAYOUT, 0))
    h.wait_matched()
    other = Layout(900.0, np.array([300.0, 600.0]), np.array([7, 8]), ('s_x', 's_y'))
    pubs = [
        h.test.create_publisher(Detection, qos.detections_topic(n), qos.DETECTIONS_QOS)
        for n in other.names
    ]
    h.layout_pub.publish(conv.layout_to_msg(other, 0))
    h.wait(lambda: all(p.get_subscription_count() == 1 for p in pubs))
    h.wait(lambda: all(p.get_subscription_count() == 0 for p in h.det_pubs))
    assert h.node.assembler.layout.n_sensors == 2
    # An invalid layout (a sensor name that cannot be a topic name) is refused, not fatal.
    bad = conv.layout_to_msg(other, 0)
    bad.sensor_names = ['s_x', 'bad name']
    h.layout_pub.publish(bad)
    h.wait(lambda: h.node.assembler.rejected['invalid_layout'] == 1)
    assert h.node.assembler.layout.n_sensors == 2


def start_episode(h: Harness, episode_id: int = 0, offset: float = 0.0, stamp_ns: int = 0):
    """Layout (if not known yet) and STARTED; returns the window."""
    if h.node.assembler.layout is None:
        h.layout_pub.publish(conv.layout_to_msg(LAYOUT, stamp_ns))
        h.wait(lambda: h.node.assembler.layout is not None)
        h.wait_matched()
    start, end = window(offset)
    h.episode_pub.publish(conv.episode_started_msg(episode_id, 3, start, end, stamp_ns))
    h.wait(lambda: h.node.assembler.knows_episode(episode_id, start))
    return start, end


def assert_perfect(msg: TrackArray, offset: float = 0.0) -> None:
    """Every true passage is in the final tracks, one track per target."""
    got = keyed(msg)
    truth = passages(offset)
    assert set(got) >= {(IDS[s], ns) for s, ns, _, _ in truth}
    groups: dict[int, set[int]] = {}
    for s, ns, _, target in truth:
        groups.setdefault(target, set()).add(got[(IDS[s], ns)])
    assert all(len(g) == 1 and -1 not in g for g in groups.values()), groups
    assert len({next(iter(g)) for g in groups.values()}) == 3


def test_absurd_finite_values_are_rejected(harness) -> None:
    h = harness(method='mlkm', segment_size=2)
    start, end = start_episode(h)
    for s, ns, v, _ in sorted(passages(), key=lambda p: p[1]):
        h.detect(s, ns, v)
    h.detect(1, conv.seconds_to_ns(20.0), 1e308)  # finite, far beyond any road speed
    h.detect(2, conv.seconds_to_ns(21.0), 5e-324)  # positive, far below any road speed
    h.detect(3, conv.seconds_to_ns(22.0), 200.0)  # above the max_speed parameter
    h.episode_pub.publish(conv.episode_ended_msg(0, 3, start, end, 0, {i: 3 for i in IDS}))
    h.wait(lambda: 0 in h.finals())
    h.wait(lambda: h.diag.get('episodes_final') == '1')
    assert h.diag['rejected.speed_out_of_range'] == '3'
    assert h.diag['accepted'] == '12'
    assert_perfect(h.finals()[0])
    # The bound is a parameter: widened, 200 m/s is a speed like any other.
    assert h.node.set_parameters([Parameter('max_speed', value=250.0)])[0].successful
    assert h.node.assembler.bounds.refuse(10.0, 200.0) is None
    # Bounds that contradict each other are refused as a whole.
    assert not h.node.set_parameters([Parameter('min_speed', value=300.0)])[0].successful


def test_solver_error_shows_as_diagnostics_error(harness) -> None:
    from mlkm_assoc.encoding import encode
    from mlkm_assoc.solver import Result

    h = harness()
    error = 'mlkm failed on episode 7, segment 0: ValueError: boom'
    empty = np.zeros(0, dtype=np.int64)
    result = Result(
        episode_id=7,
        method='mlkm',
        final=False,
        segments_done=1,
        segments_total=2,
        layout=LAYOUT,
        sensor_index=empty,
        stamps_ns=empty,
        velocities=np.zeros(0),
        labels=empty,
        solve_time=0.0,
        completed_at=0.0,
        forced=False,
        error=error,
    )
    h.node._publish(encode(result))
    h.wait(lambda: h.diag.get('solver_errors') == '1')
    assert h.diag_level == DiagnosticStatus.ERROR[0]
    assert error in h.diag_message


def test_rejected_message_does_not_count_towards_completion(harness) -> None:
    h = harness(completion_timeout=60.0)
    start, end = start_episode(h)
    ordered = sorted(passages(), key=lambda p: p[1])
    last = ordered[-1]
    for s, ns, v, _ in ordered[:-1]:
        h.detect(s, ns, v)
    # The simulator published 3 detections per sensor; the last one is still in flight when a
    # malformed message arrives on the same sensor's topic.
    h.episode_pub.publish(conv.episode_ended_msg(0, 3, start, end, 0, {i: 3 for i in IDS}))
    h.wait(lambda: h.node.assembler.episode_ended(0))
    h.detect(last[0], last[1] - 1, math.nan)
    h.wait(lambda: h.node.assembler.received == 12)
    h.detect(last[0], last[1], last[2])
    h.wait(lambda: 0 in h.finals())
    assert_perfect(h.finals()[0])
    h.wait(lambda: h.diag.get('episodes_final') == '1')
    assert h.diag['rejected.nan_velocity'] == '1'
    assert h.diag['rejected.after_episode_final'] == '0'


def test_invalid_layout_and_episode_refused_episode_kept(harness) -> None:
    h = harness(segment_size=2)
    start, end = start_episode(h)
    ordered = sorted(passages(), key=lambda p: p[1])
    for s, ns, v, _ in ordered[:5]:
        h.detect(s, ns, v)
    bad = conv.layout_to_msg(LAYOUT, 0)
    bad.road_length = math.inf
    h.layout_pub.publish(bad)
    h.wait(lambda: h.node.assembler.rejected['invalid_layout'] == 1)
    # Refused EpisodeInfos: no targets; a window that ends before it starts.
    h.episode_pub.publish(conv.episode_started_msg(1, 0, end + 10, end + 20, 0))
    h.episode_pub.publish(conv.episode_started_msg(2, 3, end + 30, end + 20, 0))
    h.wait(lambda: h.node.assembler.rejected['invalid_episode'] == 2)
    for s, ns, v, _ in ordered[5:]:
        h.detect(s, ns, v)
    h.episode_pub.publish(conv.episode_ended_msg(0, 3, start, end, 0, {i: 3 for i in IDS}))
    h.wait(lambda: 0 in h.finals())
    assert_perfect(h.finals()[0])
    assert h.node.assembler.layout.road_length == LAYOUT.road_length
    h.wait(lambda: h.diag.get('rejected.invalid_episode') == '2')
    assert h.diag['rejected.invalid_layout'] == '1'


def run_episode(h: Harness, episode_id: int, offset: float, stamp_ns: int) -> None:
    start, end = window(offset)
    h.episode_pub.publish(conv.episode_started_msg(episode_id, 3, start, end, stamp_ns))
    h.wait(lambda: h.node.assembler.knows_episode(episode_id, start))
    for s, ns, v, _ in sorted(passages(offset), key=lambda p: p[1]):
        h.detect(s, ns, v)
    counts = {i: 3 for i in IDS}
    h.episode_pub.publish(conv.episode_ended_msg(episode_id, 3, start, end, stamp_ns, counts))


@pytest.mark.parametrize('trigger', ['layout', 'started_stamp', 'window'])
def test_simulator_restart_starts_a_new_run(harness, trigger: str) -> None:
    h = harness()
    start_episode(h, stamp_ns=1_000)
    run_episode(h, 0, 0.0, 1_000)
    h.wait(lambda: len([m for m in h.tracks if m.final]) == 1)
    # The simulator restarts: episode ids begin again at 0. It publishes its layout again
    # (newer stamp, same content); with the same seed the window and the detections are the
    # same and only the publication stamps are newer; with another seed the window differs.
    if trigger == 'layout':
        h.layout_pub.publish(conv.layout_to_msg(LAYOUT, 5_000))
        h.wait(lambda: h.node.assembler.runs == 2)
    offset = 3000.0 if trigger == 'window' else 0.0
    run_episode(h, 0, offset, 6_000)
    h.wait(lambda: len([m for m in h.tracks if m.final]) == 2)
    second = [m for m in h.tracks if m.final][1]
    assert second.episode_id == 0
    assert_perfect(second, offset)
    assert h.node.assembler.runs == 2
    assert h.node.assembler.rejected['after_episode_final'] == 0


def test_episode_of_a_dead_simulator_times_out(harness) -> None:
    h = harness(episode_timeout=1.0)
    start_episode(h)
    ordered = sorted(passages(), key=lambda p: p[1])
    for s, ns, v, _ in ordered[:5]:
        h.detect(s, ns, v)
    # No ENDED, no further detection: the simulator died.
    h.wait(lambda: 0 in h.finals())
    assert len(keyed(h.finals()[0])) == 5
    h.wait(lambda: h.diag.get('handled.episode_timeout') == '1')
    assert h.diag['open_episodes'] == '0'
    assert h.diag['buffered_open_episodes'] == '0'


def test_restarted_node_reports_missing_not_an_empty_final(harness) -> None:
    h = harness()
    # Latched EpisodeInfos of an episode whose detections this node never saw (it was down).
    start, end = start_episode(h)
    h.episode_pub.publish(conv.episode_ended_msg(0, 3, start, end, 0, {i: 3 for i in IDS}))
    # The next episode arrives while the node is up, except one detection lost at sensor a.
    start_episode(h, 1, 1000.0)
    lost = min(passages(1000.0), key=lambda p: p[1])
    for s, ns, v, _ in sorted(passages(1000.0), key=lambda p: p[1]):
        if ns != lost[1]:
            h.detect(s, ns, v)
    s1, e1 = window(1000.0)
    h.episode_pub.publish(conv.episode_ended_msg(1, 3, s1, e1, 0, {i: 3 for i in IDS}))
    h.wait(lambda: 1 in h.finals())
    h.wait(lambda: h.diag.get('episodes_unseen') == '1')
    assert h.diag['missing_detections'] == str(12 + 1)
    assert 0 not in h.finals()
    assert len(keyed(h.finals()[1])) == 11
    assert h.node.assembler.rejected['after_episode_final'] == 0


def test_diagnostics_judge_recent_rejections(harness) -> None:
    h = harness(diagnostics_window=1.0)
    start_episode(h)
    h.detect(0, conv.seconds_to_ns(15.0), math.nan)
    h.wait(lambda: h.diag.get('rejected') == '1' and h.diag_level == DiagnosticStatus.WARN[0])
    # One old rejection does not keep the node in WARN for ever.
    h.wait(lambda: h.diag_level == DiagnosticStatus.OK[0])
    assert h.diag['rejected'] == '1'


def test_statistics_are_bounded(harness) -> None:
    from mlkm_assoc.encoding import encode
    from mlkm_assoc.solver import Result

    h = harness()
    empty = np.zeros(0, dtype=np.int64)
    update = encode(
        Result(
            episode_id=0,
            method='mlkm',
            final=False,
            segments_done=1,
            segments_total=2,
            layout=LAYOUT,
            sensor_index=empty,
            stamps_ns=empty,
            velocities=np.zeros(0),
            labels=empty,
            solve_time=0.001,
            completed_at=0.0,
            forced=False,
        )
    )
    for _ in range(3000):
        h.node._publish(update)
    values = h.node.diagnostics()
    assert values['track_updates_published'] == 3000
    assert 0 < values['latency_count'] <= 1000


def test_method_choices_are_described(rclpy_context) -> None:
    node = AssociationNode(context=rclpy_context)
    try:
        desc = node.describe_parameter('method')
        for method in available_methods():
            assert method in desc.additional_constraints
    finally:
        node.destroy_node()


def test_markers_show_road_stations_and_tracks_where_they_are(harness) -> None:
    """/mlkm/markers after the first segment: the road, the 4 stations with their detections,
    and each track of the partial TrackArray placed along the road from its last station at
    its last speed, at the graph's latest detection stamp."""
    h = harness(method='mlkm', segment_size=2, markers_rate=50.0)
    arrays: list[MarkerArray] = []
    h.test.create_subscription(MarkerArray, qos.MARKERS_TOPIC, arrays.append, qos.MARKERS_QOS)
    h.layout_pub.publish(conv.layout_to_msg(LAYOUT, 0))
    h.wait(lambda: h.node.assembler.layout is not None)
    h.wait_matched()
    h.episode_pub.publish(conv.episode_started_msg(0, 3, 0, conv.seconds_to_ns(100.0), 0))
    h.wait(lambda: h.node.assembler.knows_episode(0))
    # (entry time [s], speed [m/s]); at sensors a and b only, the latest stamp is 24 s
    targets = [(0.0, 10.0), (8.0, 12.5), (12.0, 20.0)]
    for t0, v in targets:
        for s in (0, 1):
            h.detect(s, conv.seconds_to_ns(t0 + POS[s] / v), v)
    h.wait(lambda: any(m.segments_done == 1 for m in h.tracks))
    partial = next(m for m in h.tracks if m.segments_done == 1)

    def status(array: MarkerArray) -> str:
        return next((m.text for m in array.markers if m.ns == 'status'), '')

    h.wait(lambda: any(status(a) == 'episode 0, 1/2 segments' for a in arrays))
    array = next(a for a in arrays if status(a) == 'episode 0, 1/2 segments')
    markers = array.markers
    assert markers[0].action == Marker.DELETEALL
    assert all(m.header.frame_id == 'road' for m in markers)
    assert conv.time_to_ns(markers[0].header.stamp) == conv.seconds_to_ns(24.0)
    by_ns: dict[str, dict[int, Marker]] = {}
    for m in markers[1:]:
        by_ns.setdefault(m.ns, {})[m.id] = m
    assert [p.x for p in by_ns['road'][0].points] == [0.0, 500.0]
    assert [by_ns['stations'][i].pose.position.x for i in range(4)] == POS
    assert [by_ns['station_names'][i].text for i in range(4)] == NAMES
    assert sorted((i, len(m.points)) for i, m in by_ns['detections'].items()) == [(0, 3), (1, 3)]
    # each track: last station b (200 m), x = 200 + v (24 s - t_b), at most station c (300 m)
    expected = {}
    for track in partial.tracks:
        assert track.positions[-1] == 200.0
        elapsed = 24.0 - conv.time_to_ns(track.stamps[-1]) / 1e9
        expected[track.track_id] = min(200.0 + track.velocities[-1] * elapsed, 300.0)
    assert len(expected) == 3
    got = {i: m.pose.position.x for i, m in by_ns['tracks'].items()}
    assert got == pytest.approx(expected, abs=1e-6)
    assert {i: m.text for i, m in by_ns['track_ids'].items()} == {i: str(i) for i in expected}
    assert any(200.0 < x < 300.0 for x in got.values())  # one is between the stations
    # switched off at run time: one last array clears the displays
    assert h.node.set_parameters([Parameter('markers', value=False)])[0].successful
    h.wait(lambda: [m.action for m in arrays[-1].markers] == [Marker.DELETEALL])


def test_static_transform_where_tf2_msgs_is_installed(harness) -> None:
    """On a ROS 2 install the node places frame road under markers_parent_frame on
    /tf_static (the PyPI wheels have no tf2_msgs: skipped there)."""
    tf2 = pytest.importorskip('tf2_msgs.msg')
    h = harness(markers_parent_frame='odom')
    got: list = []
    h.test.create_subscription(tf2.TFMessage, '/tf_static', got.append, qos.TF_STATIC_QOS)
    h.wait(lambda: bool(got))
    (t,) = got[0].transforms
    assert (t.header.frame_id, t.child_frame_id) == ('odom', 'road')
    assert (t.transform.translation.x, t.transform.rotation.w) == (0.0, 1.0)


def test_tracks_are_held_until_the_awaited_subscribers_matched(harness) -> None:
    """wait_for_track_subscribers 2, the test's own subscriber one of them: the episode's
    tracks wait in the node (tracks_held on /diagnostics) and reach the subscriber, in order,
    once a second subscriber appeared."""
    h = harness(wait_for_track_subscribers=2)
    start_episode(h)
    run_episode(h, 0, 0.0, 0)
    h.wait(lambda: h.diag.get('episodes_final') == '1' and h.diag.get('tracks_held', '0') != '0')
    held = int(h.diag['tracks_held'])
    assert h.tracks == []
    h.test.create_subscription(TrackArray, qos.TRACKS_TOPIC, lambda _msg: None, qos.TRACKS_QOS)
    h.wait(lambda: 0 in h.finals())
    assert len(h.tracks) == held
    assert [m.final for m in h.tracks] == [False] * (held - 1) + [True]
    assert_perfect(h.finals()[0])
    h.wait(lambda: h.diag.get('tracks_held') == '0')
