"""Multi-process tests: the real executables over loopback DDS, each test in its own domain.

Every process is started through the ``ros_process`` fixture, which stops it at teardown
even when the test fails.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from mlkm_core.associators.base import AssociatorConfig, make_associator
from mlkm_core.metrics import accuracy
from mlkm_core.simulator import SimConfig, simulate_episodes
from mlkm_core.types import Detections
from mlkm_ros import conversions as conv
from mlkm_ros import qos
from mlkm_ros.processes import wait_idle
from road_sensor_msgs.msg import AssociationScore, TrackArray

pytestmark = [pytest.mark.ros, pytest.mark.slow]

#: What a replay plays: the sensors' side of the graph (not the recorded tracks or scores).
REPLAYED = r'^/road/(sensor_layout|episode|ground_truth|sensors/[^/]+/detections)$'


def offline_accuracies(
    config: SimConfig, seed: int, episodes: int, gap: float, method: str
) -> list[float]:
    """The offline core on the same datasets (stamps as the graph carries them: whole ns)."""
    out = []
    for ds in simulate_episodes(config, seed, episodes, gap):
        d = ds.detections
        same = Detections(
            d.sensor_index,
            conv.ns_to_seconds(conv.seconds_to_ns_array(d.stamp)),
            d.velocity,
            d.target,
        )
        labels = make_associator(method, AssociatorConfig()).associate(
            ds.layout, same, ds.n_targets
        )
        out.append(accuracy(labels, same.target).accuracy)
    return out


class Listener:
    def __init__(self, context) -> None:
        self.node = Node('graph_test_listener', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.scores: dict[int, AssociationScore] = {}
        self.finals: dict[int, TrackArray] = {}
        self.diag: dict[str, str] = {}
        self.node.create_subscription(
            AssociationScore,
            qos.SCORE_TOPIC,
            lambda m: self.scores.__setitem__(m.episode_id, m),
            qos.SCORE_QOS,
        )
        self.node.create_subscription(
            TrackArray, qos.TRACKS_TOPIC, self._on_tracks, qos.TRACKS_QOS
        )
        self.node.create_subscription(
            DiagnosticArray, qos.DIAGNOSTICS_TOPIC, self._on_diag, qos.DIAGNOSTICS_QOS
        )

    def _on_tracks(self, msg: TrackArray) -> None:
        if msg.final:
            self.finals[msg.episode_id] = msg

    def _on_diag(self, msg: DiagnosticArray) -> None:
        values = conv.diagnostics_values(msg, '/association_node')
        if values is not None:
            self.diag = values

    def tracks_matched(self, subscribers: int) -> bool:
        return (
            self.node.count_publishers('/mlkm/tracks') >= 1
            and self.node.count_subscribers('/mlkm/tracks') >= subscribers
        )

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.fixture
def listener(rclpy_context):
    lst = Listener(rclpy_context)
    yield lst
    lst.close()


def test_live_equals_offline_and_replay_equals_live(
    ros_process, listener, spin_until, tmp_path
) -> None:
    """Same seed and method: live accuracy == offline core accuracy on the same datasets;
    the recorded bag replayed into fresh nodes gives the same accuracy again."""
    episodes, seed = 3, 7
    bag = tmp_path / 'live_bag'
    assoc = ros_process(
        'mlkm_assoc',
        'association_node',
        '--ros-args',
        *('-p', 'method:=mlkm', '-p', 'markers_rate:=20.0'),
    )
    scorer = ros_process('mlkm_assoc', 'scorer_node')
    recorder = ros_process(
        'rosbag_mcap',
        'bag_recorder',
        '--ros-args',
        '-p',
        f'output:={bag}',
        '-p',
        'exclude_regex:=^/(rosout|parameter_events)$',
    )
    assert spin_until(listener.executor, lambda: listener.tracks_matched(3), 30.0)
    sim = ros_process(
        'road_sensors',
        'sensor_sim',
        '--ros-args',
        '-p',
        f'episodes:={episodes}',
        '-p',
        f'seed:={seed}',
        '-p',
        'wait_for_subscribers:=2',
        '-p',
        'wait_for_truth_subscribers:=2',
    )
    assert spin_until(listener.executor, lambda: len(listener.scores) >= episodes, 90.0), (
        sim.output() + assoc.output() + scorer.output()
    )
    assert sim.proc.wait(30) == 0
    live = [listener.scores[e].accuracy for e in range(episodes)]
    assert live == offline_accuracies(SimConfig(), seed, episodes, 10.0, 'mlkm')
    last = listener.scores[episodes - 1]
    assert last.episodes_scored == episodes
    assert last.mean_accuracy == pytest.approx(np.mean(live))
    assert all(listener.scores[e].total == 1000 for e in range(episodes))
    assert 'episode 0 [mlkm]: accuracy' in scorer.output()

    # Record -> bag -> replay into fresh association and scorer nodes.
    wait_idle(recorder.pid, timeout=60.0)
    assert recorder.stop(30.0) == 0
    assert (bag / 'metadata.yaml').is_file()
    check_recorded_markers(bag)
    assoc.stop()
    scorer.stop()
    listener.scores.clear()
    ros_process('mlkm_assoc', 'association_node', '--ros-args', '-p', 'method:=mlkm')
    ros_process('mlkm_assoc', 'scorer_node')
    assert spin_until(listener.executor, lambda: listener.tracks_matched(2), 30.0)
    player = ros_process(
        'rosbag_mcap',
        'bag_player',
        '--ros-args',
        '-p',
        f'bag:={bag}',
        '-p',
        'rate:=0.0',
        '-p',
        f'include_regex:={REPLAYED}',
        '-p',
        'wait_for_subscribers:=1',
        '-p',
        'linger:=-1.0',
    )
    assert spin_until(listener.executor, lambda: len(listener.scores) >= episodes, 90.0), (
        player.output()
    )
    assert [listener.scores[e].accuracy for e in range(episodes)] == live
    assert all(listener.scores[e].total == 1000 for e in range(episodes))


def _marker_rows(markers) -> list[tuple[str, int, float, str]]:
    return [(m.ns, m.id, round(float(m.pose.position.x), 9), m.text) for m in markers]


def _expected(msg, now_s: float, positions: list[float], road: float) -> dict[int, float]:
    """Marker id -> x [m] of each track of ``msg`` drawn at stamp ``now_s`` [s]."""
    out = {}
    for t in msg.tracks:
        if not len(t.positions):
            continue
        last = float(t.positions[-1])
        nxt = next((p for p in positions if p > last), road)
        stamp = t.stamps[-1].sec + t.stamps[-1].nanosec * 1e-9
        x = min(last + float(t.velocities[-1]) * max(0.0, now_s - stamp), nxt)
        assert last <= x <= nxt
        if t.status == 2 and x >= nxt:  # FINAL and gone past its clamp: not drawn
            continue
        out[int(t.track_id)] = x
    return out


def check_recorded_markers(bag: Path) -> None:
    """The bag's /mlkm/markers decode alike with rosbags and mcap-ros2-support, and each
    track's marker is where its track puts it: between the track's last station and the next
    (or the road's end), at last position + last speed x (marker stamp - last stamp)."""
    arrays, tracks, layout = [], [], None
    for path in sorted(bag.glob('*.mcap')):
        with open(path, 'rb') as stream:
            reader = make_reader(stream, decoder_factories=[DecoderFactory()])
            for _, channel, _, msg in reader.iter_decoded_messages(
                topics=['/mlkm/markers', '/mlkm/tracks', '/road/sensor_layout']
            ):
                if channel.topic == '/mlkm/markers':
                    arrays.append(msg)
                elif channel.topic == '/mlkm/tracks':
                    tracks.append(msg)
                else:
                    layout = msg
    assert layout is not None and arrays
    # rosbags decodes the markers alike (visualization_msgs from its Jazzy type store)
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conns = [c for c in reader.connections if c.topic == '/mlkm/markers']
        decoded = [
            _marker_rows(reader.deserialize(raw, c.msgtype).markers)
            for c, _, raw in reader.messages(connections=conns)
        ]
    assert decoded == [_marker_rows(a.markers) for a in arrays]

    positions = [float(p) for p in layout.positions]
    road = float(layout.road_length)
    placed = 0
    for array in arrays:
        status = next((m.text for m in array.markers if m.ns == 'status'), '')
        shown = {m.id: m.pose.position.x for m in array.markers if m.ns == 'tracks'}
        if not status:  # before the first tracks: the road and its detections only
            assert not shown
            continue
        if status.startswith('stream'):
            # the node switched to stream mode once the simulator had gone: a new run, with
            # no track of its own; the episodes' tracks have ended
            assert not shown and all(not t.tracks for t in tracks if t.mode == 1)
            continue
        match = re.fullmatch(r'episode (\d+), (\d+)/(\d+) segments(, final)?', status)
        assert match, status
        episode, done, final = int(match[1]), int(match[2]), match[4] is not None
        now = array.markers[0].header.stamp
        now_s = now.sec + now.nanosec * 1e-9
        candidates = [
            t for t in tracks if (t.episode_id, t.segments_done, t.final) == (episode, done, final)
        ]
        assert candidates, status
        assert any(
            shown == pytest.approx(_expected(c, now_s, positions, road), abs=1e-6)
            for c in candidates
        ), (status, shown)
        placed += len(shown)
    assert placed > 0  # some tracks were drawn


def test_nothing_lost_under_load(ros_process, listener, spin_until) -> None:
    """rtf 0, 200 targets on 40 sensors: every published detection reaches the node."""
    episodes = 2
    ros_process(
        'mlkm_assoc',
        'association_node',
        '--ros-args',
        '-p',
        'method:=kmeans_pp',
        '-p',
        'diagnostics_period:=0.5',
    )
    assert spin_until(listener.executor, lambda: listener.tracks_matched(1), 30.0)
    sim = ros_process(
        'road_sensors',
        'sensor_sim',
        '--ros-args',
        '-p',
        f'episodes:={episodes}',
        '-p',
        'n_targets:=200',
        '-p',
        'n_sensors:=40',
        '-p',
        'real_time_factor:=0.0',
        '-p',
        'wait_for_subscribers:=1',
    )
    assert spin_until(listener.executor, lambda: len(listener.finals) >= episodes, 120.0), (
        sim.output()
    )
    assert sim.proc.wait(30) == 0
    published = 200 * 40
    assert f'published {published * episodes} detections' in sim.output()
    for e in range(episodes):
        final = listener.finals[e]
        total = sum(len(t.sensor_ids) for t in final.tracks) + len(final.unassigned_sensor_ids)
        assert total == published
    assert spin_until(
        listener.executor, lambda: listener.diag.get('episodes_published') == str(episodes), 10.0
    )
    assert listener.diag['received'] == str(published * episodes)
    assert listener.diag['rejected'] == '0'


@pytest.mark.parametrize(
    'package,exe,param,reason',
    [
        ('mlkm_assoc', 'association_node', 'method:=nope', 'choose one of'),
        ('mlkm_assoc', 'association_node', 'segment_size:=0', 'out of range'),
        ('road_sensors', 'sensor_sim', 'n_targets:=0', 'out of range'),
        ('road_sensors', 'sensor_sim', 'miss_probability:=1.0', 'miss_probability must be in'),
        ('mlkm_assoc', 'scorer_node', 'truth_timeout:=-1.0', 'out of range'),
    ],
)
def test_invalid_parameter_refused_on_command_line(
    ros_process, package, exe, param, reason
) -> None:
    proc = ros_process(package, exe, '--ros-args', '-p', param)
    assert proc.proc.wait(30) == 2
    assert reason in proc.output()


def test_clutter_live_equals_offline(ros_process, listener, spin_until) -> None:
    """Misses, false alarms and noise: sensors with more detections than targets complete
    early, the late ones make the node re-associate the episode; still live == offline."""
    episodes, seed, method = 2, 5, 'mlkm_robust'
    clutter = dict(
        miss_probability=0.05, false_alarm_rate=0.05, stamp_noise=0.2, velocity_noise=0.5
    )
    ros_process('mlkm_assoc', 'association_node', '--ros-args', '-p', f'method:={method}')
    ros_process('mlkm_assoc', 'scorer_node')
    assert spin_until(listener.executor, lambda: listener.tracks_matched(2), 30.0)
    args = [a for k, v in clutter.items() for a in ('-p', f'{k}:={v}')]
    sim = ros_process(
        'road_sensors',
        'sensor_sim',
        '--ros-args',
        '-p',
        f'episodes:={episodes}',
        '-p',
        f'seed:={seed}',
        '-p',
        'wait_for_truth_subscribers:=1',
        *args,
    )

    def done() -> bool:
        # the scorer's score and the listener's copy of the final tracks travel separately: on
        # a loaded machine either can arrive first
        return len(listener.scores) >= episodes and len(listener.finals) >= episodes

    assert spin_until(listener.executor, done, 90.0), sim.output()
    datasets = simulate_episodes(SimConfig(**clutter), seed, episodes, 10.0)
    for e, ds in enumerate(datasets):
        final = listener.finals[e]
        total = sum(len(t.sensor_ids) for t in final.tracks) + len(final.unassigned_sensor_ids)
        assert total == len(ds.detections)  # every detection in a track or unassigned
    live = [listener.scores[e].accuracy for e in range(episodes)]
    assert live == offline_accuracies(SimConfig(**clutter), seed, episodes, 10.0, method)


def test_invalid_value_in_params_file_refused(ros_process, tmp_path) -> None:
    params = tmp_path / 'bad.param.yaml'
    params.write_text(
        'association_node:\n  ros__parameters:\n    method: nope\n    segment_size: 3\n'
    )
    proc = ros_process(
        'mlkm_assoc', 'association_node', '--ros-args', '--params-file', str(params)
    )
    assert proc.proc.wait(30) == 2
    out = proc.output()
    assert "unknown method 'nope'; choose one of" in out and 'mlkm' in out
