"""The launch files under the real `ros2 launch`, and a launched graph under the real ros2 CLI.

The upstream Jazzy ros2cli, launch and launch_ros are not on PyPI: `make setup` installs them
from ../shared/vendor into build/ros2_tools, and scripts/ros2_tools.sh puts them on the paths of
these tests only (with /opt/ros/jazzy they come with it). Without that folder the tests skip and
say so; CI always has it.

Each launch file is started as a user would (`ros2 launch road_sensors <name>.launch.py
arg:=value`, its own ROS_DOMAIN_ID, loopback DDS), its graph's accuracy checked on /mlkm/score,
and it is stopped with Ctrl-C (SIGINT to the whole process group, as a terminal sends it): `ros2
launch` exits 0, every node finished cleanly and no process of the group is left. The demo
graph, while it runs, also answers `ros2 node list`, `ros2 topic echo /mlkm/tracks --once`,
`ros2 param list` and `ros2 param describe` (every parameter of the association node described,
numbers with a unit) and `ros2 interface show`; its bag is then replayed with replay.launch.py
to the same accuracy.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
from process_group import group

from mlkm_core.associators.base import AssociatorConfig, make_associator
from mlkm_core.metrics import accuracy
from mlkm_core.simulator import SimConfig, simulate_episodes
from mlkm_core.types import Detections
from mlkm_ros import conversions as conv
from mlkm_ros.processes import Proc, ScoreCollector

pytestmark = [pytest.mark.ros, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
VENDOR = Path(os.environ.get('MLKM_ROS2_VENDOR', REPO.parent / 'shared' / 'vendor'))
#: Parameters every rclpy node declares itself; not the product's.
ROS_OWN_PARAMETERS = {'use_sim_time', 'start_type_description_service'}


@pytest.fixture
def ros2_env(ros_env: dict[str, str], tmp_path: Path) -> dict[str, str]:
    """``ros_env`` with the real ros2 command-line tools on its paths (scripts/ros2_tools.sh)."""
    out = subprocess.run(
        ['bash', '-c', f'source {REPO / "scripts" / "ros2_tools.sh"} >/dev/null && env -0'],
        env=ros_env,
        capture_output=True,
    )
    if out.returncode != 0:
        why = out.stderr.decode().strip()
        if not list(VENDOR.glob('*.tar.gz')):
            pytest.skip(
                f'needs the real ros2 launch and ros2cli: {VENDOR}, the upstream sources '
                f'make setup installs them from, is absent (CI always has it); {why}'
            )
        pytest.fail(f'{VENDOR} is there but the ros2 tools are not installed; make setup: {why}')
    env = dict(item.split('=', 1) for item in out.stdout.decode().split('\0') if '=' in item)
    env['RCUTILS_COLORIZED_OUTPUT'] = '0'
    env['ROS_LOG_DIR'] = str(tmp_path / 'ros_log')  # launch's and the nodes' log files
    return env


def ros2_argv(env: dict[str, str], *args: str) -> list[str]:
    exe = shutil.which('ros2', path=env['PATH'])
    assert exe, 'ros2 not on the PATH of the tools environment'
    return [exe, *args]


def ros2(env: dict[str, str], *args: str, done=bool, timeout: float = 60.0) -> str:
    """Run a short ros2 command (never the daemon) until it succeeds with ``done(output)``;
    its output. A command without the daemon discovers the graph itself, which can miss a
    node on a busy machine ('Node not found'): it is repeated until ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        out = subprocess.run(
            ros2_argv(env, *args), env=env, capture_output=True, text=True, timeout=timeout
        )
        if out.returncode == 0 and done(out.stdout):
            return out.stdout
        assert time.monotonic() < deadline, (
            f'ros2 {" ".join(args)}: exit {out.returncode} after {timeout:g} s:\n'
            f'{out.stdout}{out.stderr}'
        )


def launch(env: dict[str, str], log_dir: Path, name: str, *args: str) -> Proc:
    """``ros2 launch road_sensors <name>.launch.py args...`` in its own process group."""
    argv = ros2_argv(env, 'launch', 'road_sensors', f'{name}.launch.py', *args)
    return Proc(name, argv, env, log_dir / f'{name}.launch.log')


def ctrl_c(proc: Proc, nodes: tuple[str, ...]) -> None:
    """Ctrl-C as a terminal sends it (SIGINT to the whole group): `ros2 launch` exits 0, each
    of ``nodes`` finished cleanly, and no process of the group is left."""
    os.killpg(proc.pid, signal.SIGINT)
    code = proc.wait(90.0)
    log = proc.output()
    assert code == 0, f'ros2 launch exited with {code} after Ctrl-C:\n{log[-3000:]}'
    for node in nodes:
        assert re.search(rf'\[{node}-\d+\]: process has finished cleanly', log), (
            f'{node} did not finish cleanly:\n{log[-3000:]}'
        )
    assert 'process has died' not in log, log[-3000:]
    deadline = time.monotonic() + 10.0
    while group(proc.pid):
        assert time.monotonic() < deadline, f'processes of the launch left: {group(proc.pid)}'
        time.sleep(0.1)
    proc.stop()


def offline_accuracies(config: SimConfig, seed: int, episodes: int, gap: float) -> list[float]:
    """The offline core (mlkm) on the datasets sensor_sim publishes (stamps in whole ns)."""
    out = []
    for ds in simulate_episodes(config, seed, episodes, gap):
        d = ds.detections
        stamps = conv.ns_to_seconds(conv.seconds_to_ns_array(d.stamp))
        same = Detections(d.sensor_index, stamps, d.velocity, d.target)
        labels = make_associator('mlkm', AssociatorConfig()).associate(
            ds.layout, same, ds.n_targets
        )
        out.append(accuracy(labels, same.target).accuracy)
    return out


def described(output: str) -> dict[str, dict[str, str]]:
    """``ros2 param describe`` output: {name: {'Type': ..., 'Description': ..., 'Min value':
    ...}}."""
    params: dict[str, dict[str, str]] = {}
    current: dict[str, str] = {}
    for line in output.splitlines():
        key, _, value = line.strip().partition(': ')
        if key == 'Parameter name':
            current = params.setdefault(value, {})
        elif value:
            current[key] = value
    return params


def parameters_of(env: dict[str, str], node: str) -> dict[str, dict[str, str]]:
    """Every parameter of the running ``node`` (but ROS's own) as ``ros2 param describe``
    shows it."""
    names = ros2(env, 'param', 'list', '--no-daemon', node, done=str.strip).split()
    names = [n for n in names if not n.endswith(':') and n not in ROS_OWN_PARAMETERS]
    params = described(ros2(env, 'param', 'describe', '--no-daemon', node, *names))
    assert set(params) == set(names), f'described {sorted(params)}, listed {sorted(names)}'
    return params


def undescribed(params: dict[str, dict[str, str]]) -> list[str]:
    """Parameters without a description, and numbers without a unit."""
    bad = []
    for name, p in params.items():
        text = p.get('Description', '')
        if not text:
            bad.append(f'{name}: no description')
        elif p.get('Type') in ('double', 'integer') and not re.search(r'\[[^\]]+\]', text):
            bad.append(f'{name}: a number without a unit: {text!r}')
    return bad


def test_demo_launch_scores_answers_the_ros2_cli_stops_on_ctrl_c_and_replays(
    ros2_env, ros_domain_id, tmp_path
) -> None:
    episodes, seed, targets, sensors = 2, 3, 10, 6
    bag = tmp_path / 'demo_bag'
    collector = ScoreCollector(ros_domain_id)
    started: list[Proc] = []
    try:
        # A user's `ros2 topic echo` already waiting when the graph starts, counted in
        # track_subscribers: the association node holds its tracks until it matched the echo
        # (DDS discovery may take longer than both episodes), so the first TrackArray is its.
        echo_argv = ros2_argv(
            ros2_env,
            'topic', 'echo', '--no-daemon', '--once', '/mlkm/tracks',
            'road_sensor_msgs/msg/TrackArray',
        )  # fmt: skip
        echo = Proc('echo', echo_argv, ros2_env, tmp_path / 'echo.log')
        started.append(echo)
        node = collector.node
        assert not collector.spin_until(
            lambda: node.count_subscribers('/mlkm/tracks') >= 1, 60.0, abort=lambda: echo.poll()
        ), echo.output()

        demo = launch(
            ros2_env, tmp_path, 'demo',
            f'episodes:={episodes}', f'seed:={seed}', f'targets:={targets}',
            f'sensors:={sensors}', 'real_time_factor:=0.0', f'bag_dir:={bag}',
            'track_subscribers:=1',
        )  # fmt: skip
        started.append(demo)
        why = collector.spin_until(
            lambda: len(collector.scores) >= episodes,
            timeout=180.0,
            abort=lambda: demo.poll() is not None and demo.output()[-3000:],
        )
        assert not why, why
        live = [collector.scores[e].accuracy for e in range(episodes)]
        config = SimConfig(n_targets=targets, n_sensors=sensors)
        assert live == offline_accuracies(config, seed, episodes, 10.0)
        assert {collector.scores[e].method for e in range(episodes)} == {'mlkm'}

        # ros2 topic echo /mlkm/tracks --once: one TrackArray with its tracks.
        assert echo.wait(60.0) == 0, echo.output()
        text = echo.output()
        assert re.search(r'^episode_id: \d+$', text, re.M), text
        assert re.search(r'^- track_id: \d+$', text, re.M), text
        assert 'sensor_ids:' in text and 'velocities:' in text, text

        # ros2 node list: the graph's nodes (sensor_sim exits after its last episode).
        expected = {'/association_node', '/scorer_node', '/bag_recorder'}
        listed = lambda out: expected <= set(out.split())  # noqa: E731
        ros2(ros2_env, 'node', 'list', '--no-daemon', done=listed)

        # ros2 param list + describe: every parameter of the association node described as a
        # user sees it, every number with its unit, ranges where declared
        # (tests/node/test_param_files.py checks the declarations of every node).
        params = parameters_of(ros2_env, '/association_node')
        assert not undescribed(params), '\n'.join(undescribed(params))
        assert params['max_speed']['Type'] == 'double'
        assert params['max_speed']['Description'].endswith('[m/s]')
        assert float(params['max_speed']['Min value']) > 0
        assert float(params['max_speed']['Max value']) >= 150.0
        assert params['lag']['Description'].endswith('[s]')
        assert params['segment_size']['Type'] == 'integer'
        assert int(params['segment_size']['Min value']) == 1
        assert 'mlkm' in params['method']['Additional constraints']

        # ros2 interface show: the message definitions with their unit comments.
        text = ros2(ros2_env, 'interface', 'show', 'road_sensor_msgs/msg/Track')
        assert re.search(r'^# Passage time of each detection .*\[s\]\.$', text, re.M), text
        assert re.search(r'^#.*\[m/s\]', text, re.M), text
        assert re.search(r'^float64\[\] velocities$', text, re.M), text

        ctrl_c(demo, ('association_node', 'scorer_node', 'bag_recorder', 'sensor_sim'))
        assert (bag / 'metadata.yaml').is_file(), 'the recorder did not close its bag'

        # The bag replayed into fresh nodes: the same accuracy per episode.
        collector.scores.clear()
        replay = launch(ros2_env, tmp_path, 'replay', f'bag:={bag}', 'rate:=0.0')
        started.append(replay)
        why = collector.spin_until(
            lambda: len(collector.scores) >= episodes,
            timeout=180.0,
            abort=lambda: replay.poll() is not None and replay.output()[-3000:],
        )
        assert not why, why
        assert [collector.scores[e].accuracy for e in range(episodes)] == live
        ctrl_c(replay, ('association_node', 'scorer_node', 'bag_player'))
    finally:
        collector.close()
        for proc in reversed(started):
            proc.stop()


def all_scored(proc: Proc, collector: ScoreCollector, published: list[int]):
    """A condition: sumo_sensors (in ``proc``'s output) published its detections, their count
    appended to ``published``, and the scores cover them all."""

    def done() -> bool:
        if not published:
            m = re.search(r'\[sumo_sensors\]: published (\d+) detections', proc.output())
            if m:
                published.append(int(m.group(1)))
        return bool(published) and sum(s.total for s in collector.scores.values()) >= published[0]

    return done


def test_stream_launch_scores_every_detection_and_stops_on_ctrl_c(
    ros2_env, ros_domain_id, tmp_path
) -> None:
    collector = ScoreCollector(ros_domain_id)
    stream = None
    try:
        stream = launch(
            ros2_env, tmp_path, 'stream',
            'source:=sumo', 'scenario:=ramps', 'stations_at:=300,700,1100,1550',
            'duration:=60.0', 'lag:=10.0', 'quiet_flush:=2.0', 'window:=30.0', 'record:=false',
        )  # fmt: skip
        published: list[int] = []
        why = collector.spin_until(
            all_scored(stream, collector, published),
            timeout=240.0,
            abort=lambda: stream.poll() is not None and stream.output()[-3000:],
        )
        assert not why, why
        scores = list(collector.scores.values())
        assert {s.mode for s in scores} == {scores[0].MODE_STREAM}
        assert {s.method for s in scores} == {'multiframe'}
        assert sum(s.total for s in scores) == published[0] > 0
        # Only 60 s of traffic: most vehicles are still between stations when it ends.
        assert sum(s.correct for s in scores) / published[0] >= 0.5, [
            (s.correct, s.total) for s in scores
        ]
        ctrl_c(stream, ('association_node', 'scorer_node', 'sumo_sensors'))
    finally:
        collector.close()
        if stream is not None:
            stream.stop()


def test_shards_launch_merges_two_shards_scores_every_detection_and_stops_on_ctrl_c(
    ros2_env, ros_domain_id, tmp_path
) -> None:
    """shards.launch.py: two association nodes in /shard_0 and /shard_1, track_merge and the
    scorer under the real `ros2 launch`; every detection the source published is scored
    from the merged tracks, and Ctrl-C ends every node cleanly."""
    collector = ScoreCollector(ros_domain_id)
    shards = None
    try:
        shards = launch(
            ros2_env, tmp_path, 'shards',
            'shards:=2', 'stations:=10', 'duration:=60.0', 'lag:=10.0', 'quiet_flush:=2.0',
            'window:=30.0', 'record:=false',
        )  # fmt: skip
        published: list[int] = []
        why = collector.spin_until(
            all_scored(shards, collector, published),
            timeout=240.0,
            abort=lambda: shards.poll() is not None and shards.output()[-3000:],
        )
        assert not why, why
        scores = list(collector.scores.values())
        assert sum(s.total for s in scores) == published[0] > 0
        assert sum(s.correct for s in scores) / published[0] >= 0.5
        out = shards.output()
        assert '[shard_0.association_node]' in out and '[shard_1.association_node]' in out
        ctrl_c(shards, ('association_node', 'track_merge', 'scorer_node', 'sumo_sensors'))
    finally:
        collector.close()
        if shards is not None:
            shards.stop()
