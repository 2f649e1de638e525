"""Ctrl-C ends every node with exit 0, no traceback, within a bound, at any moment.

Multi-process tests of the installed executables: SIGINT goes to the node's process group, as
a terminal sends it, while the node imports its modules (start-up), once it is up with
nothing to do (idle), and while it works on a running graph (busy). After it, the node must
exit 0 within ``BOUND`` seconds, its output (and that of its helper processes) holds no
'Traceback', and nothing of its process group is left.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from mlkm_ros import qos
from road_sensor_msgs.msg import GroundTruth, TrackArray

pytestmark = [pytest.mark.ros, pytest.mark.slow]

#: Longest time from SIGINT to the end of a node's whole process group [s], on a busy machine.
BOUND = 10.0
REPO = Path(__file__).resolve().parents[2]
SAMPLE_BAG = REPO / 'bags' / 'sample'

#: name -> (package, executable, ROS node name, arguments); tmp is replaced by the test's dir
NODES = {
    'association_node': ('mlkm_assoc', 'association_node', 'association_node', ()),
    'association_stream': (
        'mlkm_assoc', 'association_node', 'association_node', ('-p', 'mode:=stream'),
    ),
    'scorer_node': ('mlkm_assoc', 'scorer_node', 'scorer_node', ()),
    'sensor_sim': ('road_sensors', 'sensor_sim', 'sensor_sim', ('-p', 'wait_for_subscribers:=1')),
    'sumo_sensors': (
        'road_sensors', 'sumo_sensors', 'sumo_sensors',
        ('-p', 'scenario:=single_lane', '-p', 'vehicles:=5', '-p', 'stations:=3',
         '-p', 'wait_for_subscribers:=1'),
    ),
    'bag_recorder': ('rosbag_mcap', 'bag_recorder', 'bag_recorder', ('-p', 'output:={tmp}/bag')),
    'bag_player': (
        'rosbag_mcap', 'bag_player', 'bag_player',
        ('-p', f'bag:={SAMPLE_BAG}', '-p', 'wait_for_subscribers:=1', '-p', 'wait_timeout:=0.0'),
    ),
}  # fmt: skip


def start(ros_process, tmp_path: Path, name: str):
    """The node, under a name of its own (a node of another run cannot pass for it)."""
    package, exe, _, args = NODES[name]
    args = tuple(a.replace('{tmp}', str(tmp_path)) for a in args)
    own = f'{NODES[name][2]}_{os.getpid()}_{tmp_path.name}'.replace('-', '_').replace('.', '_')
    return ros_process(package, exe, '--ros-args', '-r', f'__node:={own}', *args), own


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def interrupt(proc, what: str, sent_at: float | None = None) -> float:
    """SIGINT to the node's group (unless it was sent at ``sent_at``); asserts exit 0, no
    traceback and an empty group within BOUND seconds; returns how long it took."""
    t0 = sent_at
    if t0 is None:
        t0 = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)
    code = proc.wait(max(0.0, t0 + BOUND - time.monotonic()))
    while code is not None and group_alive(proc.pid) and time.monotonic() - t0 < BOUND:
        time.sleep(0.02)  # the helper processes die with the node: poll until they are gone
    took = time.monotonic() - t0
    out = proc.output()
    assert code == 0, f'{what}: exit {code} {took:.1f} s after SIGINT:\n{out[-3000:]}'
    assert 'Traceback' not in out, f'{what}:\n{out[-3000:]}'
    assert not group_alive(proc.pid), f'{what}: helper processes left after {took:.1f} s'
    print(f'{what}: ended {took:.2f} s after SIGINT')
    return took


def wait_until(predicate, timeout: float, step: float = 0.005) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(step)
    return True


def importing_rclpy(pid: int) -> bool:
    """The process has loaded rclpy's C extension: its imports are under way."""
    try:
        return '_rclpy_pybind11' in Path(f'/proc/{pid}/maps').read_text()
    except (FileNotFoundError, ProcessLookupError):
        return True  # gone: let interrupt() report its exit


@pytest.mark.parametrize('name', list(NODES))
def test_sigint_during_start_up(ros_process, tmp_path, name) -> None:
    proc, _ = start(ros_process, tmp_path, name)
    assert wait_until(lambda: importing_rclpy(proc.pid), 60.0), proc.output()
    interrupt(proc, f'{name} during start-up')


@pytest.mark.parametrize('name', list(NODES))
def test_sigint_while_idle(ros_process, rclpy_context, spin_until, tmp_path, name) -> None:
    node = Node('sigint_probe', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    proc, own = start(ros_process, tmp_path, name)
    up = spin_until(executor, lambda: own in node.get_node_names(), 60.0)
    assert up, proc.output()
    interrupt(proc, f'{name} while idle')


def graph_busy(ros_process, rclpy_context, spin_until, stream: bool, tmp_path: Path) -> dict:
    """sensor_sim, association_node, scorer_node and bag_recorder, running; returns once
    tracks flow (the first TrackArray that holds a track)."""
    node = Node('sigint_probe', context=rclpy_context)
    tracks: list[TrackArray] = []
    node.create_subscription(TrackArray, qos.TRACKS_TOPIC, tracks.append, qos.TRACKS_QOS)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    mode = ('-p', 'mode:=stream') if stream else ()
    source = ('-p', 'mode:=continuous') if stream else ('-p', 'episodes:=50')
    procs = {
        'association_node': ros_process('mlkm_assoc', 'association_node', '--ros-args', *mode),
        'scorer_node': ros_process('mlkm_assoc', 'scorer_node', '--ros-args', *mode),
        'bag_recorder': ros_process(
            # it takes the backlog already delivered, for at most stop_drain_timeout
            'rosbag_mcap',
            'bag_recorder',
            '--ros-args',
            '-p',
            f'output:={tmp_path}/bag',
            '-p',
            'stop_drain_timeout:=3.0',
        ),  # fmt: skip
        'sensor_sim': ros_process(
            'road_sensors',
            'sensor_sim',
            '--ros-args',
            *source,
            '-p',
            'real_time_factor:=0.0',
            '-p',
            'wait_for_subscribers:=2',
            '-p',
            'wait_for_truth_subscribers:=2',
        ),  # fmt: skip
    }
    flowing = spin_until(executor, lambda: any(m.tracks for m in tracks), 120.0)
    assert flowing, '\n'.join(f'--- {k}\n{p.output()[-2000:]}' for k, p in procs.items())
    return procs


@pytest.mark.parametrize('stream', [False, True], ids=['episodes', 'stream'])
def test_sigint_while_busy(ros_process, rclpy_context, spin_until, tmp_path, stream) -> None:
    procs = graph_busy(ros_process, rclpy_context, spin_until, stream, tmp_path)
    for name in ('sensor_sim', 'association_node', 'scorer_node', 'bag_recorder'):
        assert procs[name].poll() is None, f'{name} ended early:\n{procs[name].output()}'
    # every node at once, as Ctrl-C in a terminal that started them all
    sent_at = time.monotonic()
    for proc in procs.values():
        os.killpg(proc.pid, signal.SIGINT)
    for name, proc in procs.items():
        what = f'{name} while busy ({"stream" if stream else "episodes"} mode)'
        interrupt(proc, what, sent_at)


def test_sigint_while_the_player_plays(ros_process, rclpy_context, spin_until) -> None:
    node = Node('sigint_probe', context=rclpy_context)
    truth: list[GroundTruth] = []
    node.create_subscription(
        GroundTruth, qos.GROUND_TRUTH_TOPIC, truth.append, qos.GROUND_TRUTH_QOS
    )
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    player = ros_process(
        'rosbag_mcap', 'bag_player', '--ros-args', '-p', f'bag:={SAMPLE_BAG}',
        '-p', 'include_regex:=^/road/ground_truth$', '-p', 'rate:=1.0',
        '-p', 'wait_for_subscribers:=1', '-p', 'wait_timeout:=0.0',
    )  # fmt: skip
    assert spin_until(executor, lambda: len(truth) >= 1, 60.0), player.output()
    interrupt(player, 'bag_player while playing')


@pytest.mark.parametrize('name', ['scorer_node', 'association_node', 'bag_player'])
def test_sigint_again_and_again_until_it_ends(
    ros_process, rclpy_context, spin_until, tmp_path, name
) -> None:
    """Ctrl-C in the terminal of `ros2 launch` reaches a node twice: once from the terminal,
    once forwarded by launch, the second at any moment of the first one's clean-up, up to the
    interpreter's own shut-down. Every one of them must leave the exit status at 0."""
    node = Node('sigint_probe', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    proc, own = start(ros_process, tmp_path, name)
    assert spin_until(executor, lambda: own in node.get_node_names(), 60.0), proc.output()
    sent_at = time.monotonic()
    while proc.poll() is None and time.monotonic() - sent_at < BOUND:
        try:
            os.killpg(proc.pid, signal.SIGINT)
        except ProcessLookupError:
            break
        time.sleep(0.002)
    interrupt(proc, f'{name} under repeated SIGINT', sent_at)
