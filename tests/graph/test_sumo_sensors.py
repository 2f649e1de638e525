"""``sumo_sensors``: SUMO as a live sensor source, as real processes over loopback DDS.

The episodes test checks the whole graph: sumo_sensors (episodes mode) feeds the association
and scorer nodes, and the live accuracy of every episode equals ``mlkm associate`` (the
offline CLI) on ``mlkm_sumo.episodes`` of the same scenario and seed written to CSV; on a road
network (``network:=interchange``) it equals the network association of ``mlkm sumo
--network``'s run of the same draw.
"""

from __future__ import annotations

import csv
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml
from ament_index_python.packages import get_package_share_directory
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock

from mlkm_ros import conversions as conv
from mlkm_ros import qos
from mlkm_sumo import episodes, road
from road_sensor_msgs.msg import (
    AssociationScore,
    Detection,
    EpisodeInfo,
    GroundTruth,
    SensorLayout,
)
from road_sensors.sumo_params import SPECS

pytestmark = [pytest.mark.ros, pytest.mark.slow]

SCENARIO, VEHICLES, STATIONS, EPISODES, SEED = 'highway', 20, 5, 2, 3


class Listener:
    """Receives scores, the layout, episode infos, ground truth and /clock."""

    def __init__(self, context) -> None:
        self.node = Node('sumo_test_listener', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.scores: dict[int, AssociationScore] = {}
        self.layout: SensorLayout | None = None
        self.infos: list[EpisodeInfo] = []
        self.truth: list[GroundTruth] = []
        self.clock: list[Clock] = []
        self.detections: list[Detection] = []
        sub = self.node.create_subscription
        sub(AssociationScore, qos.SCORE_TOPIC, self._on_score, qos.SCORE_QOS)
        sub(SensorLayout, qos.LAYOUT_TOPIC, self._on_layout, qos.LAYOUT_QOS)
        sub(EpisodeInfo, qos.EPISODE_TOPIC, self.infos.append, qos.EPISODE_QOS)
        sub(GroundTruth, qos.GROUND_TRUTH_TOPIC, self.truth.append, qos.GROUND_TRUTH_QOS)
        sub(Clock, qos.CLOCK_TOPIC, self.clock.append, qos.CLOCK_QOS)

    def _on_score(self, msg: AssociationScore) -> None:
        self.scores[msg.episode_id] = msg

    def _on_layout(self, msg: SensorLayout) -> None:
        self.layout = msg

    def subscribe_detections(self, names) -> None:
        for name in names:
            self.node.create_subscription(
                Detection, qos.detections_topic(name), self.detections.append, qos.DETECTIONS_QOS
            )

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.fixture
def listener(rclpy_context):
    lst = Listener(rclpy_context)
    yield lst
    lst.close()


def test_param_file_matches_declared_defaults() -> None:
    path = Path(get_package_share_directory('road_sensors')) / 'config' / 'sumo_sensors.param.yaml'
    params = yaml.safe_load(path.read_text())['/**']['ros__parameters']
    declared = {s.name: s.default for s in SPECS}
    assert params == declared
    assert all(type(params[k]) is type(v) for k, v in declared.items())
    for spec in SPECS:
        assert '[' in spec.description, f'{spec.name}: description without a unit'
    choices = {s.name: s.descriptor().additional_constraints for s in SPECS}
    assert choices['scenario'] == 'one of: single_lane, highway, long_highway, congested, ramps'
    assert choices['mode'] == 'one of: episodes, continuous'


@pytest.mark.parametrize(
    ('param', 'words'),
    [
        ('scenario:=nowhere', "unknown value 'nowhere'; choose one of single_lane, highway"),
        ('stations_at:=50,1000', 'station at 50 m is outside the usable road [100, 4900] m'),
        ('mode:=batch', "unknown value 'batch'; choose one of episodes, continuous"),
        ('cache_dir:=/dev/null/x', 'cannot create the network cache /dev/null/x'),
        ('stations_at:=500;1200', 'stations_at must list positions in metres separated by'),
        ('network:=ring', "unknown value 'ring'; choose one of , interchange, arterial, grid"),
    ],
)
def test_bad_setting_exits_2_with_one_clear_message(ros_process, param, words) -> None:
    proc = ros_process('road_sensors', 'sumo_sensors', '--ros-args', '-p', param)
    assert proc.proc.wait(60) == 2
    out = proc.output()
    assert words in out and 'sumo_sensors: error:' in out
    assert 'Traceback' not in out


def write_csv(path: Path, ds) -> None:
    """``mlkm associate``'s input, stamps in whole ns as the graph carries them."""
    lay, d = ds.layout, ds.detections
    with path.open('w', newline='') as f:
        w = csv.writer(f)
        w.writerow(
            ('sensor_id', 'position_m', 'stamp_s', 'velocity_mps', 'target_id', 'lane', 'length_m')
        )
        for k in np.argsort(d.stamp, kind='stable'):
            s = int(d.sensor_index[k])
            ns = conv.seconds_to_ns(d.stamp[k])
            w.writerow(
                [
                    int(lay.sensor_ids[s]),
                    repr(float(lay.positions[s])),
                    f'{ns // conv.NS_PER_S}.{ns % conv.NS_PER_S:09d}',
                    repr(float(d.velocity[k])),
                    int(d.target[k]),
                    int(d.lane[k]),
                    repr(float(d.length[k])),
                ]
            )


def offline_cli(tmp_path: Path, repo: Path) -> list[tuple[int, int]]:
    """(correct, total) of ``mlkm associate`` on every episode of the same scenario and seed."""
    mlkm = repo / 'ros2_ws' / 'install' / 'mlkm_assoc' / 'lib' / 'mlkm_assoc' / 'mlkm'
    out = []
    for k, ds in enumerate(episodes(SCENARIO, VEHICLES, EPISODES, STATIONS, SEED)):
        src = tmp_path / f'episode_{k}.csv'
        write_csv(src, ds)
        run = subprocess.run(
            [str(mlkm), 'associate', '--input', str(src), '--output', str(tmp_path / f'{k}.out')]
            + ['--method', 'mlkm', '--targets', str(ds.n_targets)],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert run.returncode == 0, run.stderr
        m = re.search(r'accuracy: [\d.]+ % \((\d+)/(\d+)\)', run.stdout)
        assert m, run.stdout
        out.append((int(m.group(1)), int(m.group(2))))
    return out


def test_episodes_live_equal_offline_cli(
    ros_process, listener, spin_until, tmp_path, repo_root
) -> None:
    expected = offline_cli(tmp_path, repo_root)
    # the tracks wait for the scorer's reader: a final published before the scorer matched
    # /mlkm/tracks on a busy machine would be lost to it
    assoc = ros_process(
        'mlkm_assoc', 'association_node', '--ros-args', '-p', 'method:=mlkm',
        '-p', 'wait_for_track_subscribers:=1',
    )  # fmt: skip
    scorer = ros_process('mlkm_assoc', 'scorer_node')
    sumo = ros_process(
        'road_sensors',
        'sumo_sensors',
        '--ros-args',
        *('-p', f'scenario:={SCENARIO}', '-p', f'vehicles:={VEHICLES}'),
        *('-p', f'stations:={STATIONS}', '-p', f'episodes:={EPISODES}', '-p', f'seed:={SEED}'),
        *('-p', 'wait_for_subscribers:=1', '-p', 'wait_for_truth_subscribers:=2'),
    )
    done = spin_until(listener.executor, lambda: len(listener.scores) >= EPISODES, 60.0)
    assert done, sumo.output() + assoc.output() + scorer.output()
    assert sumo.proc.wait(30) == 0, sumo.output()

    def announced() -> int:
        ended = [i for i in listener.infos if i.status == EpisodeInfo.STATUS_ENDED]
        return sum(sum(i.detection_counts) for i in ended) if len(ended) == EPISODES else -1

    # the scorer's copy of the truth can be complete before the listener's (a loaded machine),
    # and the latched layout may reach the listener last
    spin_until(
        listener.executor,
        lambda: len(listener.truth) >= announced() > 0 and listener.layout is not None,
        30.0,
    )
    live = [(listener.scores[k].correct, listener.scores[k].total) for k in range(EPISODES)]
    assert live == expected
    assert all(listener.scores[k].truth_complete for k in range(EPISODES))
    assert all(total > 0.7 * VEHICLES * STATIONS for _, total in live)
    # The layout carries the stations' lanes; the truth SUMO's vehicle ids, marked double
    # reports, and one episode id per batch.
    lay = listener.layout
    assert (
        lay is not None and list(lay.lane_counts) == road(SCENARIO, STATIONS, SEED).lanes.tolist()
    )
    assert list(lay.entry_positions) == list(lay.exit_positions) == []
    assert {t.episode_id for t in listener.truth} == set(range(EPISODES))
    assert all(re.fullmatch(r'v\d+', t.vehicle_id) for t in listener.truth)
    assert all(t.lane in range(3) for t in listener.truth)
    ended = [i for i in listener.infos if i.status == EpisodeInfo.STATUS_ENDED]
    assert sorted(i.episode_id for i in ended) == list(range(EPISODES))
    assert sum(sum(i.detection_counts) for i in ended) == len(listener.truth)


def test_a_network_episode_live_equals_its_offline_association(
    ros_process, listener, spin_until
) -> None:
    from mlkm_core.metrics import score
    from mlkm_core.network_assoc import associate_network
    from mlkm_ros.network_conversions import msg_to_network
    from mlkm_sumo.road_networks import draw_network, generate_network

    ds = generate_network(draw_network('interchange', 2, vehicles=40))
    d = ds.detections()
    d.stamp = np.array([conv.seconds_to_ns(t) / conv.NS_PER_S for t in d.stamp])  # as sent
    offline = score(d, associate_network(ds_network(ds), d, 'assignment'))
    assoc = ros_process(
        'mlkm_assoc', 'association_node', '--ros-args', '-p', 'method:=assignment',
        '-p', 'wait_for_track_subscribers:=1', '-p', 'markers:=false',
    )  # fmt: skip
    scorer = ros_process('mlkm_assoc', 'scorer_node')
    sumo = ros_process(
        'road_sensors',
        'sumo_sensors',
        '--ros-args',
        *('-p', 'network:=interchange', '-p', 'seed:=2', '-p', 'vehicles:=40'),
        *('-p', 'episodes:=1', '-p', 'wait_for_subscribers:=1'),
        '-p',
        'wait_for_truth_subscribers:=2',
    )
    done = spin_until(listener.executor, lambda: 0 in listener.scores, 120.0)
    assert done, sumo.output() + assoc.output() + scorer.output()
    assert sumo.proc.wait(30) == 0, sumo.output()
    live = listener.scores[0]
    assert (live.correct, live.total) == (offline.correct, offline.total)
    assert live.total > 100 and offline.accuracy > 0.8
    # the layout is the network's, its links with their SUMO shapes
    net = msg_to_network(listener.layout)
    assert net == ds_network(ds) and all(len(k.shape) >= 2 for k in net.links)


def ds_network(ds):
    from mlkm_core.network import network_from_mapping

    return network_from_mapping(ds.mapping, 'interchange')


def test_continuous_traffic_on_a_network_is_the_offline_network_stream(
    ros_process, listener, spin_until
) -> None:
    from mlkm_ros.network_conversions import msg_to_network
    from mlkm_sumo.road_networks import draw_network, network_stream

    draw = draw_network('interchange', 2, vehicles=20)
    stream = network_stream(draw, duration=150.0)
    offline = list(stream)
    names = [s['name'] for s in stream.road.mapping['stations']]
    listener.subscribe_detections(names)
    sumo = ros_process(
        'road_sensors',
        'sumo_sensors',
        '--ros-args',
        *('-p', 'network:=interchange', '-p', 'seed:=2', '-p', 'vehicles:=20'),
        *('-p', 'mode:=continuous', '-p', 'duration:=150.0'),
        *('-p', 'wait_for_subscribers:=1', '-p', 'wait_for_truth_subscribers:=1'),
    )
    assert spin_until(listener.executor, lambda: sumo.proc.poll() is not None, 120.0)
    assert sumo.proc.wait(5) == 0, sumo.output()
    n = len(offline)
    got = spin_until(
        listener.executor, lambda: len(listener.detections) >= n and len(listener.truth) >= n
    )
    assert got and n > 100, sumo.output()
    assert len(listener.detections) == len(listener.truth) == n
    assert listener.infos == [] and listener.node.count_publishers(qos.EPISODE_TOPIC) == 0
    # the network form of the layout, and each passage of the offline stream published once
    # at its station, lane, stamp and speed (the stamps moved by no jitter margin)
    net = msg_to_network(listener.layout)
    assert len(net.links) == len(stream.road.mapping['links']) and net.n_stations == len(names)
    sent = sorted(
        (d.sensor_id, d.lane, conv.time_to_ns(d.header.stamp), round(d.velocity, 6))
        for d in listener.detections
    )
    want = sorted(
        (p.station, p.lane, conv.seconds_to_ns(p.time), round(p.speed, 6)) for p in offline
    )
    assert sent == want
    vehicles = {t.vehicle_id for t in listener.truth if not t.false_alarm}
    assert vehicles == {p.vehicle for p in offline} and len(vehicles) > 50


def test_continuous_mode_streams_without_episodes(ros_process, listener, spin_until) -> None:
    stations = ('ramps_station_0', 'ramps_station_1', 'ramps_station_2')
    listener.subscribe_detections(stations)
    sumo = ros_process(
        'road_sensors',
        'sumo_sensors',
        '--ros-args',
        *('-p', 'scenario:=ramps', '-p', 'mode:=continuous', '-p', 'duration:=120.0'),
        *('-p', 'stations_at:=300,1300,2500', '-p', 'seed:=5', '-p', 'publish_clock:=true'),
        *('-p', 'wait_for_subscribers:=1', '-p', 'wait_for_truth_subscribers:=1'),
        *('-p', 'stamp_jitter:=0.05', '-p', 'speed_noise:=0.5', '-p', 'length_noise:=0.2'),
    )
    # A receiver in mode auto takes a source without a /road/episode publisher for a stream.
    assert spin_until(listener.executor, lambda: listener.layout is not None, 60.0)
    assert listener.node.count_publishers(qos.EPISODE_TOPIC) == 0
    assert spin_until(listener.executor, lambda: sumo.proc.poll() is not None, 60.0)
    assert sumo.proc.wait(5) == 0, sumo.output()
    n = int(re.search(r'published (\d+) detections', sumo.output()).group(1))
    got = spin_until(
        listener.executor, lambda: len(listener.detections) >= n and len(listener.truth) >= n
    )
    assert got and n > 20, sumo.output()
    assert len(listener.detections) == len(listener.truth) == n
    assert listener.infos == []  # no EpisodeInfo in continuous mode
    lay = listener.layout
    assert list(lay.positions) == [300.0, 1300.0, 2500.0]
    assert list(lay.lane_counts) == [3, 4, 3]
    assert list(lay.entry_positions) == [1200.0, 3200.0]
    assert list(lay.exit_positions) == [2300.0, 4300.0]
    assert all(t.episode_id == 0 for t in listener.truth)
    # One target numbering for the run: the vehicle behind a target id never changes.
    owner: dict[int, str] = {}
    for t in listener.truth:
        if not t.false_alarm:
            assert owner.setdefault(t.target_id, t.vehicle_id) == t.vehicle_id
    assert len(owner) == len(set(owner.values())) > 5
    # A detection and its truth share the join key (sensor, lane, stamp); stamps are >= 0.
    det_keys = {
        (d.sensor_id, d.lane, conv.time_to_ns(d.header.stamp)) for d in listener.detections
    }
    truth_keys = {(t.sensor_id, t.lane, conv.time_to_ns(t.header.stamp)) for t in listener.truth}
    assert det_keys == truth_keys and len(det_keys) == n
    assert all(d.header.stamp.sec >= 0 and 3.0 < d.length < 20.0 for d in listener.detections)
    assert listener.clock and all(c.clock.sec >= 0 for c in listener.clock)


def test_continuous_forever_stops_cleanly_on_ctrl_c(ros_process, listener, spin_until) -> None:
    sumo = ros_process(
        'road_sensors',
        'sumo_sensors',
        '--ros-args',
        *('-p', 'scenario:=single_lane', '-p', 'mode:=continuous', '-p', 'duration:=0.0'),
        *('-p', 'stations:=3', '-p', 'real_time_factor:=20.0'),
        *('-p', 'wait_for_subscribers:=0', '-p', 'wait_for_truth_subscribers:=1'),
    )
    assert spin_until(listener.executor, lambda: len(listener.truth) >= 3, 60.0), sumo.output()
    assert sumo.proc.poll() is None  # runs on: no duration
    assert sumo.stop() == 0
    assert 'Traceback' not in sumo.output() and 'error' not in sumo.output()


def test_sumo_failure_while_running_is_exit_2_with_its_message(rclpy_context, monkeypatch) -> None:
    """In process: SUMO failing in the middle of a run (here: the episode source raises
    SumoError after the layout went out) ends the run with exit code 2 and SUMO's message."""
    from rclpy.parameter import Parameter

    from mlkm_sumo import SumoError
    from road_sensors import sumo_sensors

    def failing(*_args, **_kwargs):
        raise SumoError('SUMO failed to start scenario highway: simulated crash')
        yield  # a generator, as mlkm_sumo.episodes

    monkeypatch.setattr(sumo_sensors, 'episodes', failing)
    overrides = [Parameter('stations', value=3), Parameter('wait_for_subscribers', value=0)]
    node = sumo_sensors.SumoSensorsNode(context=rclpy_context, parameter_overrides=overrides)
    try:
        assert node.wait_done(30.0)
        assert node.exit_code == 2
        assert node.error == 'SUMO failed: SUMO failed to start scenario highway: simulated crash'
    finally:
        node.stop()
        node.destroy_node()
