#!/usr/bin/env python3
"""`make demo-shards`: a long road split over four association nodes, with track hand-off.

Starts, as separate processes (what a user starts in separate terminals, or on separate
hosts): four ``mlkm_assoc association_node`` shards in stream mode, shard k in namespace
/shard_k owning the k-th quarter of the stations; ``mlkm_assoc track_merge`` (one view of
their tracks on /mlkm/tracks); ``mlkm_assoc scorer_node`` (stream mode) scoring that view;
``rosbag_mcap bag_recorder``; and ``road_sensors sumo_sensors`` in continuous mode on the 5 km
SUMO highway with 40 stations (about five simulated minutes at real_time_factor 0), which
starts once every shard subscribed to its stations and its margins. Everything on loopback
DDS in a ROS domain of its own (or $ROS_DOMAIN_ID). Prints every window's accuracy, the
rolling accuracy, each shard's detections and hand-offs, leaves the bag under bags/ and exits
0 (nonzero when something failed). Logs go to <bag>/../logs/<bag name>/.

Usage: python scripts/demo_shards.py [--shards N] [--stations N] [--duration S] [--seed S]
       [--lag S] [--window S] [--bag-dir DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from demo_stream import format_stream_scores, latest_values

from mlkm_core.shards.regions import split_road
from mlkm_ros.domains import domain
from mlkm_ros.processes import Graph, ScoreCollector, recorder_args, replay_hint

ROOT = Path(__file__).resolve().parents[1]
METHOD = 'multiframe'


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--shards', type=int, default=4, help='association nodes (4)')
    p.add_argument('--stations', type=int, default=40, help='sensor stations (40)')
    p.add_argument('--duration', type=float, default=300.0, help='simulated seconds (300)')
    p.add_argument('--seed', type=int, default=1, help='seed of the source (1)')
    p.add_argument('--lag', type=float, default=30.0, help='commit lag [s] (30)')
    p.add_argument('--window', type=float, default=60.0, help='scoring window [s] (60)')
    p.add_argument('--bag-dir', type=Path, default=None, help='bag to write')
    p.add_argument('--timeout', type=float, default=400.0, help='give up after [s] (400)')
    return p.parse_args(argv)


def shard_name(k: int) -> str:
    return f'/shard_{k}/association_node'


def all_scored(collector: ScoreCollector, shards: int) -> bool:
    """Every shard flushed its quiet road and the scorer scored and forgot every detection."""
    scorer = latest_values(collector, '/scorer_node')
    for k in range(shards):
        values = latest_values(collector, shard_name(k))
        if values.get('stream.working_set') != '0' or not int(values.get('received', '0')):
            return False
    return (
        scorer.get('stream_tracked_detections') == '0'
        and scorer.get('stream_buffered_truth') == '0'
        and int(scorer.get('stream_windows_published', '0') or 0) > 0
    )


def start_graph(graph: Graph, collector: ScoreCollector, args, bag_dir: Path) -> None:
    """The shards, the merge, the scorer and the recorder; returns once /mlkm/tracks is
    matched by the scorer and the recorder."""
    for k in range(args.shards):
        graph.start(
            f'shard_{k}', 'mlkm_assoc', 'association_node', '--ros-args',
            '-r', f'__ns:=/shard_{k}', '-p', 'source_namespace:=/',
            '-p', 'mode:=stream', '-p', f'stream_method:={METHOD}', '-p', f'lag:={args.lag}',
            '-p', f'shard_count:={args.shards}', '-p', f'shard_index:={k}',
            '-p', 'wait_for_track_subscribers:=1',
        )  # fmt: skip
    graph.start(
        'track_merge', 'mlkm_assoc', 'track_merge', '--ros-args',
        '-p', f'shard_count:={args.shards}', '-p', 'wait_for_track_subscribers:=2',
    )  # fmt: skip
    graph.start(
        'scorer_node', 'mlkm_assoc', 'scorer_node', '--ros-args',
        '-p', 'mode:=stream', '-p', f'window:={args.window}',
    )  # fmt: skip
    graph.start('bag_recorder', 'rosbag_mcap', 'bag_recorder', *recorder_args(bag_dir))
    node = collector.node
    why = collector.spin_until(
        lambda: node.count_subscribers('/mlkm/tracks') >= 2,
        timeout=60.0,
        abort=graph.failed,
    )
    if why:
        raise RuntimeError(f'graph did not come up: {why}')


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    stamp = time.strftime('demo_shards_%Y%m%d_%H%M%S', time.gmtime())
    bag_dir = (args.bag_dir or ROOT / 'bags' / stamp).resolve()
    if bag_dir.exists():
        print(f'demo-shards: {bag_dir} exists already; choose another --bag-dir', file=sys.stderr)
        return 2
    log_dir = bag_dir.parent / 'logs' / bag_dir.name
    regions = split_road(args.stations, args.shards)
    # each shard subscribes to its own stations and its margins; the recorder to every one
    subscriptions = sum(len(r.stations) for r in regions) + args.stations
    t0 = time.monotonic()
    deadline = t0 + args.timeout
    with domain() as domain_id:
        print(f'demo-shards: ROS_DOMAIN_ID={domain_id}, loopback DDS; logs in {log_dir}')
        for r in regions:
            print(
                f'  shard {r.index}: stations {r.own[0]}..{r.own[-1]} '
                f'(+{len(r.margin)} before, +{len(r.after)} after)'
            )
        collector = ScoreCollector(domain_id, diagnostics=True)
        graph = Graph(domain_id, log_dir)
        try:
            start_graph(graph, collector, args, bag_dir)
            proc = graph.start(
                'sumo_sensors', 'road_sensors', 'sumo_sensors', '--ros-args',
                '-p', 'mode:=continuous', '-p', 'scenario:=highway',
                '-p', f'stations:={args.stations}', '-p', f'duration:={args.duration}',
                '-p', f'seed:={args.seed}', '-p', 'real_time_factor:=0.0',
                '-p', 'wait_for_subscribers:=2', '-p', 'wait_for_truth_subscribers:=2',
                '-p', f'wait_for_subscriptions:={subscriptions}',
            )  # fmt: skip
            why = collector.spin_until(
                lambda: proc.poll() is not None,
                timeout=max(deadline - time.monotonic(), 1.0),
                abort=graph.failed,
            )
            if why or proc.poll() != 0:
                raise RuntimeError(f'sumo_sensors did not finish: {why or graph.failed()}')
            print(
                f'demo-shards: sumo_sensors done after {time.monotonic() - t0:.1f} s; waiting '
                f'{args.lag:g} s for the quiet road to be flushed and scored'
            )
            why = collector.spin_until(
                lambda: all_scored(collector, args.shards),
                timeout=max(deadline - time.monotonic(), 1.0),
                abort=graph.failed,
            )
            if why:
                raise RuntimeError(f'the road was not scored to the end: {why}')
            collector.spin_until(lambda: False, timeout=1.0)  # the last scores, diagnostics
            graph.close_recorder('demo-shards')
        except (RuntimeError, KeyboardInterrupt) as exc:
            collector.close()
            return graph.report_failure('demo-shards', exc)
        codes = graph.stop_all()
        collector.close()
    print(
        format_stream_scores(
            collector.scores,
            f'\n{args.shards} shards ({METHOD}, lag {args.lag:g} s), SUMO highway, '
            f'{args.stations} stations, {args.duration:g} simulated s:',
        )
    )
    for k in range(args.shards):
        v = latest_values(collector, shard_name(k))
        print(
            f'shard {k}: {v.get("received")} detections taken, '
            f'{v.get("stream.handoff_offers", "0")} offered downstream, '
            f'{v.get("stream.handoff_accepts", "0")} tracks continued from upstream'
        )
    merge = latest_values(collector, '/track_merge')
    print(
        f'track_merge: {merge.get("continued")} continuations joined, '
        f'{merge.get("retired")} pieces retired into their upstream track'
    )
    print(replay_hint(bag_dir, ROOT))
    print(f'demo-shards: done in {time.monotonic() - t0:.1f} s; exit codes {codes}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
