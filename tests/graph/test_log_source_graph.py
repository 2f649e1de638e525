"""``log_source``: a real detector log replayed into the graph, as real processes over loopback
DDS.

The log is the shipped NGSIM I-80 traffic (``data/ngsim_i80``) seen by virtual loops
(``mlkm_core.loops``: 10 stations from 50 to 450 m, the closed road), written as the product's
detections CSV with its layout file, as ``mlkm loops`` writes them. log_source (episodes mode)
feeds the association and scorer nodes; the live accuracy equals ``mlkm associate`` (the
offline CLI) on the same file with the same method: ``multiframe`` (the demo's) and ``mlkm``
(the association node's default, which gets a good part of this real traffic wrong, so that
equal means equal labels, not two perfect scores).
"""

from __future__ import annotations

import re
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest
from score_listener import Listener

from mlkm_core.csvout import write_detections
from mlkm_core.layout_file import RoadLayout, write_layout_file
from mlkm_core.loops import even_positions, virtual_loops
from mlkm_core.trajectories import read_trajectories
from mlkm_core.types import Layout
from road_sensor_msgs.msg import EpisodeInfo

pytestmark = [pytest.mark.ros, pytest.mark.slow]

STATIONS, START, END = 10, 50.0, 450.0
POSITION_DECIMALS = 3
DATA = Path(__file__).resolve().parents[2] / 'data' / 'ngsim_i80' / 'i80_trajectories_a.csv.gz'


@pytest.fixture
def listener(rclpy_context):
    lst = Listener(rclpy_context, 'log_test_listener')
    yield lst
    lst.close()


@pytest.fixture(scope='module')
def ngsim_log(tmp_path_factory) -> tuple[Path, Path, int]:
    """(log, layout file, detections) of the virtual loops on the NGSIM trajectories."""
    traj = read_trajectories(DATA)
    loops = virtual_loops(traj, even_positions(STATIONS, START, END), closed=True)
    ds = loops.dataset
    out = tmp_path_factory.mktemp('ngsim_log')
    log, layout = out / 'i80_loops.csv', out / 'i80_loops.layout.yaml'
    # the CSV's positions have 3 decimals; the layout file gives the same ones (as mlkm loops
    # writes it), so that the node and the CLI place the stations alike
    road = Layout(ds.layout.road_length, np.round(ds.layout.positions, POSITION_DECIMALS))
    write_detections(log, road, ds.detections, decimals=(POSITION_DECIMALS, 3, 3, 2))
    write_layout_file(layout, RoadLayout(road, np.full(STATIONS, loops.lanes)))
    return log, layout, len(ds.detections)


def offline_cli(repo: Path, log: Path, method: str, out: Path) -> tuple[int, int]:
    """(correct, total) of ``mlkm associate`` on the log."""
    mlkm = repo / 'ros2_ws' / 'install' / 'mlkm_assoc' / 'lib' / 'mlkm_assoc' / 'mlkm'
    run = subprocess.run(
        [str(mlkm), 'associate', '--input', str(log), '--output', str(out), '--method', method],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    m = re.search(r'accuracy: [\d.]+ % \((\d+)/(\d+)\)', run.stdout)
    assert m, run.stdout
    return int(m.group(1)), int(m.group(2))


@pytest.mark.parametrize('method', ['multiframe', 'mlkm'])
def test_ngsim_log_live_equals_offline_cli(
    ros_process, listener, spin_until, tmp_path, repo_root, ngsim_log, method
) -> None:
    log, layout, n = ngsim_log
    correct, total = offline_cli(repo_root, log, method, tmp_path / 'tracks.csv')
    assert total == n == 800  # 80 vehicles seen at all 10 stations
    # the tracks wait for the scorer's reader (a busy machine may match it late)
    assoc = ros_process(
        'mlkm_assoc', 'association_node', '--ros-args', '-p', f'method:={method}',
        '-p', 'wait_for_track_subscribers:=1',
    )  # fmt: skip
    scorer = ros_process('mlkm_assoc', 'scorer_node')
    source = ros_process(
        'road_sensors',
        'log_source',
        '--ros-args',
        *('-p', f'log:={log}', '-p', f'layout:={layout}', '-p', 'mode:=episodes'),
        *('-p', 'wait_for_subscribers:=1', '-p', 'wait_for_truth_subscribers:=1'),
        # the source stays up after its run: the listener, which it does not wait for, may
        # match its latched episode topic after the run on a busy machine
        *('-p', 'keep_running:=true'),
    )
    done = spin_until(
        listener.executor,
        # the latched layout may reach the listener last on a busy machine
        lambda: 0 in listener.scores and listener.ended() and listener.layout,
        90.0,
    )
    assert done, source.output() + assoc.output() + scorer.output()
    source.proc.send_signal(signal.SIGINT)
    assert source.proc.wait(30) == 0, source.output()
    live = listener.scores[0]
    assert (live.correct, live.total) == (correct, total)
    assert live.truth_complete and live.method == method
    if method == 'multiframe':
        assert correct == total  # every vehicle of the real traffic followed
    else:
        assert correct < 0.8 * total  # mlkm is not the method for stop-and-go traffic
    # one episode announced with the per-station counts; the layout of the layout file
    ended = [i for i in listener.infos if i.status == EpisodeInfo.STATUS_ENDED]
    assert [i.episode_id for i in ended] == [0] and sum(ended[0].detection_counts) == n
    (lay,) = listener.layout
    assert list(lay.sensor_ids) == list(range(STATIONS))
    assert list(lay.positions) == np.round(even_positions(STATIONS, START, END), 3).tolist()
    assert list(lay.lane_counts) == [3] * STATIONS
    out = source.output()
    assert 'published 800 detections of 800 rows in 1 episode' in out and 'WARN' not in out
