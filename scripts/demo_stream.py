#!/usr/bin/env python3
"""`make demo-stream`: the open-road graph, no episodes.

Starts, as separate processes (what a user starts in separate terminals):
  mlkm_assoc association_node (mode stream), mlkm_assoc scorer_node (mode stream),
  rosbag_mcap bag_recorder, and road_sensors sumo_sensors (mode continuous, SUMO scenario
  ramps, about two simulated minutes at real_time_factor 0; --source sim uses sensor_sim's
  continuous mode instead),
on loopback DDS in a ROS domain of its own (or $ROS_DOMAIN_ID). When the source is done the
association node flushes the quiet road (after ``--lag`` seconds), the scorer scores the
last window; the script prints every window's accuracy and revision rate with the rolling
(cumulative) figures, leaves the bag under bags/ with its time-space diagram beside it
(<bag>_timespace.png, as `mlkm plot` draws it), stops every process and exits 0 (nonzero
when something failed). Logs go to <bag>/../logs/<bag name>/.

Usage: python scripts/demo_stream.py [--duration S] [--stations N] [--seed S] [--method M]
       [--lag S] [--window S] [--source sumo|sim] [--bag-dir DIR]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from mlkm_assoc.timespace_plot import plot_beside_bag
from mlkm_ros.domains import domain
from mlkm_ros.processes import (
    Graph,
    ScoreCollector,
    recorder_args,
    replay_hint,
    start_association,
)

ROOT = Path(__file__).resolve().parents[1]
NS_PER_S = 1_000_000_000


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--duration', type=float, default=120.0, help='simulated seconds (120)')
    p.add_argument('--stations', type=int, default=10, help='sensor stations (10)')
    p.add_argument('--seed', type=int, default=1, help='seed of the source (1)')
    p.add_argument('--method', default='multiframe', help='stream associator (multiframe)')
    p.add_argument(
        '--lag',
        type=float,
        default=30.0,
        help='commit lag [s] (30: longer than a vehicle takes between two stations)',
    )
    p.add_argument('--window', type=float, default=30.0, help='scoring window [s] (30)')
    p.add_argument('--source', choices=('sumo', 'sim'), default='sumo', help='source (sumo)')
    p.add_argument('--scenario', default='ramps', help='SUMO scenario (ramps)')
    p.add_argument('--bag-dir', type=Path, default=None, help='bag to write')
    p.add_argument('--timeout', type=float, default=170.0, help='give up after [s] (170)')
    return p.parse_args(argv)


def start_stream_graph(
    graph: Graph,
    collector: ScoreCollector,
    method: str,
    lag: float,
    window: float,
    *also: tuple[str, ...],
    timeout: float = 60.0,
) -> None:
    """association_node and scorer_node in stream mode, then ``also``; returns once
    /mlkm/tracks is matched by the scorer and each of ``also`` (at most ``timeout`` [s]; a
    process that exits ends the wait at once)."""
    start_association(
        graph, collector, method, *also,
        association_params=('mode:=stream', f'stream_method:={method}', f'lag:={float(lag)}'),
        scorer_params=('mode:=stream', f'window:={float(window)}'),
        timeout=timeout,
    )  # fmt: skip


def latest_values(collector: ScoreCollector, name: str) -> dict[str, str]:
    """The newest /diagnostics key-values of node ``name`` the collector received."""
    for msg in reversed(collector.diagnostics):
        for status in msg.status:
            if status.name == name:
                return {kv.key: kv.value for kv in status.values}
    return {}


def all_scored(collector: ScoreCollector) -> bool:
    """The road was flushed and the scorer scored and forgot every detection."""
    assoc = latest_values(collector, '/association_node')
    scorer = latest_values(collector, '/scorer_node')
    return (
        assoc.get('stream.working_set') == '0'
        and int(assoc.get('stream.pushed', '0') or 0) > 0
        and scorer.get('stream_tracked_detections') == '0'
        and scorer.get('stream_buffered_truth') == '0'
        and int(scorer.get('stream_windows_published', '0') or 0) > 0
    )


def scoring_state(collector: ScoreCollector) -> str:
    """What the stream nodes last reported, for a message when the scoring did not finish."""
    assoc = latest_values(collector, '/association_node')
    scorer = latest_values(collector, '/scorer_node')
    keys = ('stream.pushed', 'stream.working_set', 'stream.detections_held', 'mode')
    keys2 = ('stream_tracked_detections', 'stream_buffered_truth', 'stream_windows_published')
    return (
        'association_node '
        + ', '.join(f'{k}={assoc.get(k)}' for k in keys)
        + '; scorer_node '
        + ', '.join(f'{k}={scorer.get(k)}' for k in keys2)
    )


def format_stream_scores(scores: dict, title: str) -> str:
    """One line per window and the rolling (cumulative) figures."""
    lines = [
        title,
        'window  start-end [s]    accuracy  correct/total  revision rate    '
        'cumulative accuracy  cumulative revision rate',
    ]
    last = None
    for k in sorted(scores):
        s = scores[k]
        a, b = _sec(s.window_start), _sec(s.window_end)
        lines.append(
            f'{k:6d}  {a:6.0f}-{b:<6.0f}  {s.accuracy:9.4f}  {s.correct:6d}/{s.total:<6d}'
            f'  {_rate(s.revision_rate)} ({s.links_revised}/{s.links_published})'
            f'  {s.mean_accuracy:19.4f}  {_rate(s.cumulative_revision_rate):>24s}'
        )
        last = s
    if last is not None:
        lines.append(
            f'rolling accuracy {last.mean_accuracy:.4f}, revision rate '
            f'{_rate(last.cumulative_revision_rate)} over {len(scores)} window(s)'
        )
    return '\n'.join(lines)


def _sec(t) -> float:
    return t.sec + t.nanosec / NS_PER_S


def _rate(x: float) -> str:
    return 'n/a' if math.isnan(x) else f'{x:.4f}'


def source_spec(args: argparse.Namespace) -> tuple[str, ...]:
    common = (
        '-p',
        f'duration:={float(args.duration)}',
        '-p',
        f'seed:={args.seed}',
        '-p',
        'real_time_factor:=0.0',
        '-p',
        'wait_for_subscribers:=2',  # association node + recorder
        '-p',
        'wait_for_truth_subscribers:=2',  # scorer + recorder
    )
    if args.source == 'sumo':
        return (
            'sumo_sensors',
            'road_sensors',
            'sumo_sensors',
            '--ros-args',
            '-p',
            'mode:=continuous',
            '-p',
            f'scenario:={args.scenario}',
            '-p',
            f'stations:={args.stations}',
            *common,
        )
    return (
        'sensor_sim',
        'road_sensors',
        'sensor_sim',
        '--ros-args',
        '-p',
        'mode:=continuous',
        '-p',
        f'n_sensors:={args.stations}',
        *common,
    )


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    stamp = time.strftime('demo_stream_%Y%m%d_%H%M%S', time.gmtime())
    bag_dir = (args.bag_dir or ROOT / 'bags' / stamp).resolve()
    if bag_dir.exists():
        print(f'demo-stream: {bag_dir} exists already; choose another --bag-dir', file=sys.stderr)
        return 2
    log_dir = bag_dir.parent / 'logs' / bag_dir.name
    t0 = time.monotonic()
    deadline = t0 + args.timeout
    with domain() as domain_id:
        print(f'demo-stream: ROS_DOMAIN_ID={domain_id}, loopback DDS; logs in {log_dir}')
        collector = ScoreCollector(domain_id, diagnostics=True)
        graph = Graph(domain_id, log_dir)
        source = source_spec(args)
        try:
            start_stream_graph(
                graph,
                collector,
                args.method,
                args.lag,
                args.window,
                ('bag_recorder', 'rosbag_mcap', 'bag_recorder', *recorder_args(bag_dir)),
            )
            proc = graph.start(*source)
            why = collector.spin_until(
                lambda: proc.poll() is not None,
                timeout=max(deadline - time.monotonic(), 1.0),
                abort=lambda: graph.failed(),
            )
            if why or proc.poll() != 0:
                raise RuntimeError(f'{source[0]} did not finish: {why or graph.failed()}')
            print(
                f'demo-stream: {source[0]} done after {time.monotonic() - t0:.1f} s; waiting '
                f'{args.lag:g} s for the quiet road to be flushed and scored'
            )
            why = collector.spin_until(
                lambda: all_scored(collector),
                timeout=max(deadline - time.monotonic(), 1.0),
                abort=graph.failed,
            )
            if why:
                raise RuntimeError(
                    f'the stream was not scored to the end: {why} ({scoring_state(collector)})'
                )
            collector.spin_until(lambda: False, timeout=0.5)  # the last scores
            graph.close_recorder('demo-stream')
        except (RuntimeError, KeyboardInterrupt) as exc:
            collector.close()
            return graph.report_failure('demo-stream', exc)
        codes = graph.stop_all()
        collector.close()
    what = f'SUMO {args.scenario}' if args.source == 'sumo' else 'sensor_sim'
    print(
        format_stream_scores(
            collector.scores,
            f'\nstream association ({args.method}, lag {args.lag:g} s), {what}, '
            f'{args.stations} stations, {args.duration:g} simulated s:',
        )
    )
    print(replay_hint(bag_dir, ROOT))
    print(plot_beside_bag(bag_dir))
    print(f'demo-stream: done in {time.monotonic() - t0:.1f} s; exit codes {codes}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
