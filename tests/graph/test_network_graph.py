"""The live graph on a road network, as real processes over loopback DDS: a SUMO interchange
(``mlkm sumo --network interchange``: a diverge, a connector and a merge) written as a
detector log with its network layout file; log_source publishes the network layout and
replays the log as one episode; association_node and scorer_node work on the network. The
live accuracy equals ``mlkm associate --layout`` on the same file with the same method.
"""

from __future__ import annotations

import re
import signal
import subprocess
from pathlib import Path

import pytest
from score_listener import Listener

pytestmark = [pytest.mark.ros, pytest.mark.slow]

ACCURACY = re.compile(r'accuracy: [\d.]+ % \((\d+)/(\d+)\)')


def mlkm(repo: Path, *args: str) -> str:
    exe = repo / 'ros2_ws' / 'install' / 'mlkm_assoc' / 'lib' / 'mlkm_assoc' / 'mlkm'
    run = subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return run.stdout


@pytest.fixture(scope='module')
def network_log(repo_root, tmp_path_factory) -> tuple[Path, Path]:
    out = tmp_path_factory.mktemp('network_log')
    log, layout = out / 'interchange.csv', out / 'interchange.layout.yaml'
    mlkm(
        repo_root,
        *('sumo', '--network', 'interchange', '--seed', '2', '--vehicles', '80'),
        *('--output', str(log), '--layout', str(layout), '--cache-dir', str(out / 'cache')),
    )
    return log, layout


@pytest.fixture
def listener(rclpy_context):
    lst = Listener(rclpy_context, 'network_test_listener')
    yield lst
    lst.close()


def test_network_log_live_equals_offline_cli(
    ros_process, listener, spin_until, tmp_path, repo_root, network_log
) -> None:
    log, layout = network_log
    printed = mlkm(
        repo_root,
        *('associate', '--input', str(log), '--layout', str(layout)),
        *('--output', str(tmp_path / 'tracks.csv'), '--method', 'assignment'),
    )
    m = ACCURACY.search(printed)
    assert m, printed
    correct, total = int(m.group(1)), int(m.group(2))
    # the tracks wait for the scorer's reader (a busy machine may match it late)
    assoc = ros_process(
        'mlkm_assoc', 'association_node', '--ros-args', '-p', 'method:=assignment',
        '-p', 'wait_for_track_subscribers:=1',
    )  # fmt: skip
    scorer = ros_process('mlkm_assoc', 'scorer_node')
    source = ros_process(
        'road_sensors',
        'log_source',
        '--ros-args',
        *('-p', f'log:={log}', '-p', f'layout:={layout}', '-p', 'mode:=episodes'),
        *('-p', 'wait_for_subscribers:=1', '-p', 'wait_for_truth_subscribers:=1'),
        *('-p', 'keep_running:=true'),  # the listener may match the latched topics late
    )
    done = spin_until(
        listener.executor,
        lambda: 0 in listener.scores and listener.ended() and listener.layout,
        120.0,
    )
    assert done, source.output() + assoc.output() + scorer.output()
    source.proc.send_signal(signal.SIGINT)
    assert source.proc.wait(30) == 0, source.output()
    live = listener.scores[0]
    assert (live.correct, live.total) == (correct, total)
    assert live.truth_complete and live.method == 'assignment'
    assert 0.5 * total < correct < total  # a real association, not a perfect one by accident
    (lay,) = listener.layout
    assert lay.road_length == 0.0 and len(lay.link_ids) == 6  # the network form
    assert 'a road network of 6 links' in assoc.output()
    assert 'WARN' not in assoc.output() + scorer.output()
