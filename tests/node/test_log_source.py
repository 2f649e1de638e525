"""log_source in process (private context): a hand-written detector log and layout file.

The layout message is the layout file; every valid row of the log arrives on its station's
topic decoded exactly as written (stamp, speed, lane, length), with its ground truth when the
log has target ids and no ground truth at all when it has none; invalid rows are counted and
left out; negative stamps are moved by whole seconds; a log that does not fit its layout
file, a missing file or a bad layout file is refused with one message and exit code 2.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from mlkm_ros import conversions as conv
from mlkm_ros import qos
from road_sensor_msgs.msg import Detection, EpisodeInfo, GroundTruth, SensorLayout
from road_sensors import log_source
from road_sensors.log_source import LogSourceError, LogSourceNode, load_replay

pytestmark = pytest.mark.ros

LAYOUT = """\
# three loop stations on 600 m, one on-ramp
road_length_m: 600.0
stations:
  - {id: 7, name: north, position_m: 450.0, lanes: 2}
  - {id: 3, name: middle, position_m: 250.5, lanes: 3}
  - {id: 12, position_m: 100.0}
entries_m: [300.0]
exits_m: []
"""
#: (sensor_id, position_m, stamp_s, velocity_mps, target_id, lane, length_m), out of order;
#: the row with velocity 0 and the one with a non-numeric stamp are invalid.
ROWS = [
    (3, '250.5', '20.125', '12.5', 1, '1', '4.5'),
    (12, '100.0', '5.000', '11.0', 1, '1', '4.5'),
    (12, '100.0', '7.250', '13.25', 2, '0', ''),
    (7, '450.0', '35.5', '12.0', 1, '', '4.5'),
    (3, '250.5', '19.0', '13.5', 2, '2', '7.25'),
    (12, '100.0', '9.0', '0', 3, '0', '5.0'),
    (7, '450.0', '30.0', '14.0', -1, '1', 'nan'),
    (3, '250.5', 'soon', '13.0', 4, '0', '4.0'),
]
INVALID_LINES = (7, 9)  # file lines of the invalid rows (the header is line 1)


def write_log(path: Path, rows, columns=('target_id', 'lane', 'length_m')) -> Path:
    keep = [0, 1, 2, 3] + [4 + ('target_id', 'lane', 'length_m').index(c) for c in columns]
    head = ['sensor_id', 'position_m', 'stamp_s', 'velocity_mps', *columns]
    lines = [','.join(head)] + [','.join(str(r[k]) for k in keep) for r in rows]
    path.write_text('\n'.join(lines) + '\n')
    return path


@pytest.fixture
def files(tmp_path):
    layout = tmp_path / 'road.yaml'
    layout.write_text(LAYOUT)
    return write_log(tmp_path / 'log.csv', ROWS), layout


class Listener:
    """Everything log_source publishes on the road of LAYOUT."""

    def __init__(self, context) -> None:
        self.node = Node('log_listener', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.layout: list[SensorLayout] = []
        self.infos: list[EpisodeInfo] = []
        self.truth: list[GroundTruth] = []
        self.detections: list[Detection] = []
        sub = self.node.create_subscription
        sub(SensorLayout, qos.LAYOUT_TOPIC, self.layout.append, qos.LAYOUT_QOS)
        sub(EpisodeInfo, qos.EPISODE_TOPIC, self.infos.append, qos.EPISODE_QOS)
        sub(GroundTruth, qos.GROUND_TRUTH_TOPIC, self.truth.append, qos.GROUND_TRUTH_QOS)
        for name in ('north', 'middle', 'sensor_12'):
            sub(Detection, qos.detections_topic(name), self.detections.append, qos.DETECTIONS_QOS)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.fixture
def listener(rclpy_context):
    lst = Listener(rclpy_context)
    yield lst
    lst.close()


def run_source(context, listener, spin_until, log: Path, layout: Path, *more: Parameter):
    """Start the node (waiting for the listener), spin until it is done; the node's replay."""
    node = LogSourceNode(
        context=context,
        parameter_overrides=[
            Parameter('log', value=str(log)),
            Parameter('layout', value=str(layout)),
            Parameter('wait_for_subscribers', value=1),
            Parameter('wait_for_truth_subscribers', value=1),
            Parameter('keep_running', value=True),  # it shares the listener's context
            *more,
        ],
    )
    try:
        assert spin_until(listener.executor, node._done.is_set, 30.0)
        assert node.error is None
        n = node._replay.station.size
        with_truth = node._replay.target is not None
        assert spin_until(
            listener.executor,
            lambda: (
                len(listener.detections) >= n
                and len(listener.truth) >= n * with_truth
                and listener.layout
            ),
            30.0,
        )
        spin_until(listener.executor, lambda: False, 0.3)  # anything extra would show now
        return node._replay
    finally:
        node.stop()
        node.destroy_node()


def decoded(msg: Detection) -> tuple:
    length = None if math.isnan(msg.length) else msg.length
    return (msg.sensor_id, msg.position, conv.time_to_ns(msg.header.stamp), msg.velocity,
            msg.lane, length)  # fmt: skip


def expected(rows, shift_s: int = 0, lanes: bool = True, lengths: bool = True) -> list[tuple]:
    out = []
    for sid, pos, t, v, _, lane, length in rows:
        size = float(length) if lengths and length and length != 'nan' else None
        ns = conv.seconds_to_ns(float(t)) + shift_s * conv.NS_PER_S
        out.append((sid, float(pos), ns, float(v), int(lane) if lanes and lane else -1, size))
    return sorted(out)


def valid(rows):
    return [r for k, r in enumerate(rows) if k + 2 not in INVALID_LINES]


def test_episode_layout_rows_and_truth(rclpy_context, listener, spin_until, files) -> None:
    log, layout = files
    replay = run_source(rclpy_context, listener, spin_until, log, layout)
    # the layout message is the file: stations by position, names, lanes, ramps
    (lay,) = listener.layout
    assert lay.road_length == 600.0
    assert list(lay.sensor_ids) == [12, 3, 7]
    assert list(lay.sensor_names) == ['sensor_12', 'middle', 'north']
    assert list(lay.positions) == [100.0, 250.5, 450.0]
    assert list(lay.lane_counts) == [0, 3, 2]
    assert list(lay.entry_positions) == [300.0] and list(lay.exit_positions) == []
    # each detection decoded equals its row; the invalid rows are counted, not published
    assert sorted(decoded(d) for d in listener.detections) == expected(valid(ROWS))
    assert [p.line for p in replay.problems] == list(INVALID_LINES)
    assert [p.reason for p in replay.problems] == ['zero_velocity', 'malformed']
    assert replay.rows == len(ROWS) and replay.shift_s == 0
    # every topic in stamp order; ground truth: one per detection, the log's target ids
    stamps = [conv.time_to_ns(t.header.stamp) for t in listener.truth]
    assert stamps == sorted(stamps)
    got = sorted((t.sensor_id, conv.time_to_ns(t.header.stamp), t.target_id, t.false_alarm)
                 for t in listener.truth)  # fmt: skip
    want = sorted(
        (sid, conv.seconds_to_ns(float(t)), g if g >= 0 else conv.FALSE_ALARM_ID, g < 0)
        for sid, _, t, _, g, _, _ in valid(ROWS)
    )
    assert got == want and {t.episode_id for t in listener.truth} == {0}
    # one episode: STARTED and ENDED with the window and the per-station counts
    started, ended = listener.infos
    assert (started.status, ended.status) == (EpisodeInfo.STATUS_STARTED, EpisodeInfo.STATUS_ENDED)
    assert started.episode_id == ended.episode_id == 0
    assert ended.num_targets == 2  # the most detections at one station (the CLI's default)
    assert conv.episode_counts(ended) == {12: 2, 3: 2, 7: 2}
    assert conv.time_to_ns(ended.start) == 5 * conv.NS_PER_S
    assert conv.time_to_ns(ended.end) == 35_500_000_000


def test_no_truth_column_continuous_negative_stamps(
    rclpy_context, listener, spin_until, tmp_path, files
) -> None:
    _, layout = files
    rows = [(s, p, f'{float(t) - 30.0:g}', *rest) for s, p, t, *rest in valid(ROWS)]
    log = write_log(tmp_path / 'bare.csv', rows, columns=())
    replay = run_source(
        rclpy_context, listener, spin_until, log, layout, Parameter('mode', value='continuous')
    )
    # stamps from -25 s: every row 25 s later, time differences untouched
    assert replay.shift_s == 25 and replay.first_stamp == -25.0
    assert sorted(decoded(d) for d in listener.detections) == expected(
        rows, shift_s=25, lanes=False, lengths=False
    )
    assert min(conv.time_to_ns(d.header.stamp) for d in listener.detections) == 0
    # no target ids: no ground truth at all; a stream: no EpisodeInfo, not even its publisher
    assert replay.target is None and listener.truth == []
    assert listener.infos == [] and listener.node.count_publishers(qos.EPISODE_TOPIC) == 0


def test_load_replay_counts_invalid_rows_with_reasons(files) -> None:
    log, layout = files
    replay = load_replay(str(log), str(layout))
    text = log_source.describe_problems(replay.problems)
    assert text.startswith('2 invalid rows skipped (1 zero_velocity, 1 malformed): line 7: ')
    assert "line 9: stamp_s is not a number: 'soon'" in text
    assert replay.columns == ('target_id', 'lane', 'length_m')


@pytest.mark.parametrize(
    ('change', 'words'),
    [
        (
            lambda log, lay: write_log(log, [*ROWS, (5, '120.0', '3.0', '10.0', 1, '0', '4.0')]),
            'sensor id(s) 5 not in the layout file',
        ),
        (
            lambda log, lay: write_log(log, [(3, '251.5', '3.0', '10.0', 1, '0', '4.0')]),
            'sensor 3 is at position_m 251.5, the layout file',
        ),
        (lambda log, lay: log.unlink(), 'log.csv: cannot read: No such file or directory'),
        (lambda log, lay: lay.unlink(), 'road.yaml: No such file or directory'),
        (
            lambda log, lay: lay.write_text(LAYOUT.replace('lanes: 3', 'lane: 3')),
            "stations[1]: unknown key 'lane'",
        ),
        (
            lambda log, lay: write_log(log, [(3, '250.5', 'x', '10.0', 1, '0', '4.0')]),
            '1 invalid row',
        ),
    ],
    ids=['unknown_sensor', 'other_position', 'no_log', 'no_layout', 'bad_layout', 'no_valid'],
)
def test_refused_at_start_exit_2(rclpy_context, files, capsys, change, words) -> None:
    log, layout = files
    change(log, layout)
    with pytest.raises(LogSourceError, match=re.escape(words)):
        LogSourceNode(
            context=rclpy_context,
            parameter_overrides=[
                Parameter('log', value=str(log)),
                Parameter('layout', value=str(layout)),
            ],
        )
    # the executable's main: one line on stderr, exit code 2, no traceback
    status = log_source.main(['--ros-args', '-p', f'log:={log}', '-p', f'layout:={layout}'])
    err = capsys.readouterr().err
    assert status == 2
    assert err.startswith('log_source: error: ') and words in err and 'Traceback' not in err


def test_log_and_layout_are_required(rclpy_context, capsys) -> None:
    assert log_source.main([]) == 2
    err = capsys.readouterr().err
    assert err.strip() == (
        'log_source: error: parameter log is required: the path of the detections CSV '
        '(--ros-args -p log:=<path>)'
    )
