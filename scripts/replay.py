#!/usr/bin/env python3
"""`make replay BAG=<dir>`: replay a recorded bag into fresh association and scorer nodes.

Plays the bag's layout, episode, sensor and ground-truth topics (never its recorded tracks,
scores or diagnostics) with ``rosbag_mcap bag_player`` into a new ``association_node`` and
``scorer_node``, each a separate process on loopback DDS in a ROS domain of its own (or
$ROS_DOMAIN_ID), and prints the accuracy of each episode and the mean. When the bag also
holds the scores of the run that recorded it, they are compared: a replay reproduces them.
The replayed tracks are drawn as a time-space diagram beside the bag,
``<bag>_replay_timespace.png`` (``mlkm plot``; the bag's layout and ground truth).

A bag of an open road (no EpisodeInfo in it, e.g. from ``make demo-stream``) is replayed into
nodes in stream mode: the script prints the score of every window with the rolling accuracy
and revision rate, and compares them with the recorded window scores.

A damaged bag (truncated file, corrupt chunks) is replayed as far as it is readable, with a
warning naming the damage; its accuracy is not compared with the recorded run (messages are
missing) and the exit status is 3.

Usage: python scripts/replay.py <bag dir or .mcap> [--method M] [--rate R] [--lag S]
Exit status: 0 replayed; 1 failed (unreadable bag, no complete episode, a node failed or
timed out); 2 bad arguments; 3 the bag is damaged: only its readable part was replayed.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

from mlkm_assoc.timespace_plot import plot_beside_bag
from mlkm_ros.domains import domain
from mlkm_ros.processes import Graph, ScoreCollector, format_scores, start_association
from mlkm_ros.qos import REPLAY_INCLUDE_REGEX

EXIT_DAMAGED = 3  # as bag_player: the readable part of a damaged bag was replayed


def recorded_episodes(bag: Path) -> tuple[int, dict[int, float], list[str]]:
    """(number of ENDED episodes, {episode: recorded accuracy}, damage found) read from the
    bag; the damage list is empty for an intact bag."""
    ended, _, recorded, damage = inspect_bag(bag)
    return ended, {k: s.accuracy for k, s in recorded.items()}, damage


def inspect_bag(bag: Path) -> tuple[int, int, dict, list[str]]:
    """(ENDED episodes, EpisodeInfo messages, {episode or window: recorded AssociationScore},
    damage found) read from the bag; the damage list is empty for an intact bag."""
    from rclpy.serialization import deserialize_message

    from road_sensor_msgs.msg import EpisodeInfo
    from rosbag_mcap.reader import BagReader

    reader = BagReader(bag)
    ended: set[int] = set()
    infos = 0
    recorded: dict = {}
    for message in reader.messages(topics=['/road/episode', '/mlkm/score']):
        if message.topic == '/road/episode':
            infos += 1
            info = deserialize_message(message.data, EpisodeInfo)
            if info.status == EpisodeInfo.STATUS_ENDED:
                ended.add(info.episode_id)
        elif message.topic == '/mlkm/score':
            score = _recorded_score(message.data)
            if score.total > 0:  # an older scorer published unscorable ones as NaN
                recorded[score.episode_id] = score
    return len(ended), infos, recorded, bag_damage(reader)


def bag_damage(reader) -> list[str]:
    """What the reader found missing or unreadable (read after iterating its messages)."""
    damage = list(reader.problems) if reader.damaged else []
    expected = reader.expected_message_count
    readable = reader.readable_message_count
    if expected is not None and readable < expected:
        damage.append(f'{readable} of the {expected} recorded messages are readable')
    return damage


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('bag', type=Path, help='bag directory (or a lone .mcap file)')
    p.add_argument(
        '--method',
        default=None,
        help='associator (default: the one that produced the recorded scores, else mlkm)',
    )
    p.add_argument(
        '--rate',
        type=float,
        default=0.0,
        help='playback rate; 0 = as fast as the nodes take it (default)',
    )
    p.add_argument(
        '--timeout',
        type=float,
        default=120.0,
        help='give up this long after the player started playing [s] (120); the nodes and the '
        'player may take as long as they need to come up',
    )
    p.add_argument(
        '--lag',
        type=float,
        default=None,
        help="stream bags: commit lag [s] (default: the recording node's, from the bag's "
        '/diagnostics, else 15)',
    )
    args = p.parse_args(argv)
    bag = args.bag.resolve()
    if not bag.exists():
        print(f'replay: {bag} does not exist', file=sys.stderr)
        return 2
    try:
        episodes, infos, scores, damage = inspect_bag(bag)
    except Exception as exc:  # noqa: BLE001 - any unreadable bag: say why and stop
        print(f'replay: cannot read {bag}: {exc}', file=sys.stderr)
        return 1
    if infos == 0:
        return replay_stream(bag, args, scores, damage)
    recorded = {k: s.accuracy for k, s in scores.items()}
    if episodes == 0:
        print(
            f'replay: {bag} holds no complete episode (no ENDED on /road/episode)', file=sys.stderr
        )
        return 1
    method = args.method or _recorded_method(bag) or 'mlkm'
    if damage:
        print(
            f'replay: WARNING: {bag} is damaged; replaying only its readable part:\n  '
            + '\n  '.join(damage),
            file=sys.stderr,
        )
    log_dir = Path(tempfile.mkdtemp(prefix='mlkm_replay_'))
    t0 = time.monotonic()
    with domain() as domain_id:
        print(
            f'replay: {bag} ({episodes} episodes), method {method}, '
            f'ROS_DOMAIN_ID={domain_id}; logs in {log_dir}'
        )
        collector = ScoreCollector(domain_id)
        tracks = replayed_tracks(collector)
        graph = Graph(domain_id, log_dir)
        try:
            # No time limit on the start: a busy machine only makes it slower; a node that
            # fails ends the wait.
            start_association(graph, collector, method, timeout=math.inf)
            # The player waits, without a time limit, until every volatile topic it plays has
            # a subscriber: the association node subscribes to the sensor topics once it
            # learned the layout, the scorer to ground truth.
            graph.start('bag_player', 'rosbag_mcap', 'bag_player', *_player_args(bag, args))
            why = collector.spin_until(
                lambda: len(collector.scores) >= episodes,
                timeout=math.inf,
                abort=_abort_after_playing(graph, args.timeout),
            )
            if why:
                raise RuntimeError(f'not every episode was scored: {why}')
        except (RuntimeError, KeyboardInterrupt) as exc:
            collector.close()
            return graph.report_failure('replay', exc)
        codes = graph.stop_all()
        collector.close()
    print(format_scores(collector.scores, f'\nreplayed association ({method}):'))
    print(plot_beside_bag(bag, tracks))
    if damage:
        print(
            'recorded run: not compared, the bag is damaged (messages are missing, so the '
            'accuracy can differ from the recorded run)'
        )
        print(
            f'replay: done in {time.monotonic() - t0:.1f} s with a DAMAGED bag '
            f'(exit {EXIT_DAMAGED}); exit codes {codes}'
        )
        return EXIT_DAMAGED
    if recorded:
        same = all(
            abs(collector.scores[e].accuracy - a) < 1e-12
            for e, a in recorded.items()
            if e in collector.scores
        )
        print(
            'recorded run: '
            + (
                'same accuracy per episode'
                if same
                else 'DIFFERENT accuracy: '
                + ', '.join(f'{e}: {a:.4f}' for e, a in sorted(recorded.items()))
            )
        )
    print(f'replay: done in {time.monotonic() - t0:.1f} s; exit codes {codes}')
    return 0


def replay_stream(bag: Path, args: argparse.Namespace, scores: dict, damage: list[str]) -> int:
    """A bag of an open road: nodes in stream mode, scores per window."""
    from demo_stream import all_scored, format_stream_scores, scoring_state, start_stream_graph

    recorded = {k: s for k, s in scores.items() if s.mode == s.MODE_STREAM}
    settings = _recorded_stream_settings(bag)
    method = args.method or settings.get('stream.method') or 'multiframe'
    args.lag = args.lag or float(settings.get('stream.lag') or 15.0)
    window = 60.0
    for s in recorded.values():
        length = _seconds(s.window_end) - _seconds(s.window_start)
        window = length if length > 0 else window
        break
    if damage:
        print(
            f'replay: WARNING: {bag} is damaged; replaying only its readable part:\n  '
            + '\n  '.join(damage),
            file=sys.stderr,
        )
    log_dir = Path(tempfile.mkdtemp(prefix='mlkm_replay_'))
    t0 = time.monotonic()
    with domain() as domain_id:
        print(
            f'replay: {bag} (a stream: no EpisodeInfo), method {method}, lag {args.lag:g} s, '
            f'window {window:g} s, ROS_DOMAIN_ID={domain_id}; logs in {log_dir}'
        )
        collector = ScoreCollector(domain_id, diagnostics=True)
        tracks = replayed_tracks(collector)
        graph = Graph(domain_id, log_dir)
        try:
            start_stream_graph(graph, collector, method, args.lag, window, timeout=math.inf)
            graph.start('bag_player', 'rosbag_mcap', 'bag_player', *_player_args(bag, args))
            why = collector.spin_until(
                lambda: (
                    'playback done' in graph.procs['bag_player'].output() and all_scored(collector)
                ),
                timeout=math.inf,
                abort=_abort_after_playing(graph, args.timeout + args.lag),
            )
            if why:
                raise RuntimeError(
                    f'the stream was not scored to the end: {why} ({scoring_state(collector)})'
                )
            collector.spin_until(lambda: False, timeout=0.5)
        except (RuntimeError, KeyboardInterrupt) as exc:
            collector.close()
            return graph.report_failure('replay', exc)
        codes = graph.stop_all()
        collector.close()
    print(format_stream_scores(collector.scores, f'\nreplayed stream association ({method}):'))
    print(plot_beside_bag(bag, tracks))
    if damage:
        print('recorded run: not compared, the bag is damaged (messages are missing)')
        print(f'replay: done in {time.monotonic() - t0:.1f} s with a DAMAGED bag; {codes}')
        return EXIT_DAMAGED
    if recorded:
        # The committed tracks, hence the accuracy, depend on the detections alone; the
        # revisions depend on the order they arrived in, which a replay does not repeat.
        same = set(recorded) == set(collector.scores) and all(
            _same(collector.scores[k].accuracy, s.accuracy)
            and (collector.scores[k].correct, collector.scores[k].total) == (s.correct, s.total)
            for k, s in recorded.items()
        )
        print(
            'recorded run: '
            + (
                'same accuracy per window (revisions depend on the arrival order)'
                if same
                else 'DIFFERENT: recorded '
                + ', '.join(f'{k}: {s.accuracy:.4f}' for k, s in sorted(recorded.items()))
            )
        )
    print(f'replay: done in {time.monotonic() - t0:.1f} s; exit codes {codes}')
    return 0


def replayed_tracks(collector: ScoreCollector) -> list:
    """The TrackArray messages the replayed association node publishes, collected while
    ``collector`` spins, for the time-space diagram of the replay."""
    from mlkm_ros import qos
    from road_sensor_msgs.msg import TrackArray

    tracks: list = []
    collector.node.create_subscription(TrackArray, qos.TRACKS_TOPIC, tracks.append, qos.TRACKS_QOS)
    return tracks


def _recorded_stream_settings(bag: Path) -> dict[str, str]:
    """The recording association node's stream settings (stream.lag, stream.method) from
    the /diagnostics it published into the bag; empty when there are none."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.serialization import deserialize_message

    from rosbag_mcap.reader import BagReader

    for message in BagReader(bag).messages(topics=['/diagnostics']):
        for status in deserialize_message(message.data, DiagnosticArray).status:
            values = {kv.key: kv.value for kv in status.values}
            if 'stream.lag' in values:
                return values
    return {}


def _player_args(bag: Path, args: argparse.Namespace) -> list[str]:
    return [
        '--ros-args',
        '-p',
        f'bag:={bag}',
        '-p',
        f'rate:={args.rate}',
        '-p',
        f'include_regex:={REPLAY_INCLUDE_REGEX}',
        '-p',
        'wait_for_subscribers:=1',
        '-p',
        'wait_timeout:=0.0',  # no limit: never play to nobody
        '-p',
        'linger:=-1.0',
    ]


def _abort_after_playing(graph: Graph, timeout: float):
    """``abort`` for ``spin_until``: why to stop, once a node failed or ``timeout`` seconds
    passed since the player started playing (its 'playing' log line), never before."""
    started: list[float] = []

    def why() -> str | None:
        failed = graph.failed(ignore=('bag_player',)) or _player_failed(graph)
        if failed:
            return failed
        if not started and 'playing ' in graph.procs['bag_player'].output():
            started.append(time.monotonic())
        if started and time.monotonic() - started[0] > timeout:
            return f'timed out {timeout:g} s after the player started playing'
        return None

    return why


def _seconds(t) -> float:
    return t.sec + t.nanosec / 1e9


def _same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or abs(a - b) < 1e-12


def _player_failed(graph: Graph) -> str | None:
    code = graph.procs['bag_player'].poll()
    if code not in (None, 0):
        return f'bag_player exited with code {code}; log {graph.procs["bag_player"].log_path}'
    return None


def _recorded_method(bag: Path) -> str | None:

    from rosbag_mcap.reader import BagReader

    for message in BagReader(bag).messages(topics=['/mlkm/score']):
        if message.topic == '/mlkm/score':
            return _recorded_score(message.data).method
    return None


def _recorded_score(data: bytes):
    """An AssociationScore from a bag, also one recorded before the message gained its
    trailing fields (truth_complete, ...): CDR appends fields at the end, so the older
    encoding padded with zeros decodes, the newer fields at 0/False."""
    from rclpy.serialization import deserialize_message

    from road_sensor_msgs.msg import AssociationScore

    try:
        return deserialize_message(data, AssociationScore)
    except Exception:  # noqa: BLE001 - rclpy raises a generic RMWError on short data
        return deserialize_message(bytes(data) + bytes(96), AssociationScore)


if __name__ == '__main__':
    sys.exit(main())
