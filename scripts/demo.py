#!/usr/bin/env python3
"""`make demo`: the live node graph on the embedded default scenario.

Starts, as separate processes (what a user starts in separate terminals):
  mlkm_assoc association_node, mlkm_assoc scorer_node, rosbag_mcap bag_recorder, and
  road_sensors sensor_sim (a few episodes of the paper's Simulation 2: 50 targets, 20 sensors,
  real_time_factor 0),
on loopback DDS in a ROS domain of its own (or $ROS_DOMAIN_ID). Prints the accuracy of each
episode and the mean (from /mlkm/score), leaves the bag under bags/ with its time-space
diagram beside it (<bag>_timespace.png, as `mlkm plot` draws it), stops every process and
exits 0 (nonzero when something failed). Logs go to <bag>/../logs/<bag name>/.

Usage: python scripts/demo.py [--episodes N] [--seed S] [--method M] [--bag-dir DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from mlkm_assoc.timespace_plot import plot_beside_bag
from mlkm_ros.domains import domain
from mlkm_ros.processes import (
    Graph,
    ScoreCollector,
    format_scores,
    recorder_args,
    replay_hint,
    start_association,
)

ROOT = Path(__file__).resolve().parents[1]


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--episodes', type=int, default=4, help='episodes to simulate (4)')
    p.add_argument('--seed', type=int, default=0, help='simulator seed (0)')
    p.add_argument('--method', default='mlkm', help='associator (mlkm)')
    p.add_argument('--targets', type=int, default=50, help='targets per episode (50)')
    p.add_argument('--sensors', type=int, default=20, help='sensors (20)')
    p.add_argument(
        '--bag-dir',
        type=Path,
        default=None,
        help='bag directory to write (default bags/demo_<UTC time>)',
    )
    p.add_argument('--timeout', type=float, default=100.0, help='give up after [s] (100)')
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    bag_dir = args.bag_dir or ROOT / 'bags' / time.strftime('demo_%Y%m%d_%H%M%S', time.gmtime())
    bag_dir = bag_dir.resolve()
    if bag_dir.exists():
        print(f'demo: {bag_dir} exists already; choose another --bag-dir', file=sys.stderr)
        return 2
    log_dir = bag_dir.parent / 'logs' / bag_dir.name
    t0 = time.monotonic()
    with domain() as domain_id:
        print(f'demo: ROS_DOMAIN_ID={domain_id}, loopback DDS; logs in {log_dir}')
        collector = ScoreCollector(domain_id)
        graph = Graph(domain_id, log_dir)
        try:
            start_association(
                graph,
                collector,
                args.method,
                ('bag_recorder', 'rosbag_mcap', 'bag_recorder', *recorder_args(bag_dir)),
            )
            graph.start(
                'sensor_sim',
                'road_sensors',
                'sensor_sim',
                '--ros-args',
                '-p',
                f'episodes:={args.episodes}',
                '-p',
                f'seed:={args.seed}',
                '-p',
                f'n_targets:={args.targets}',
                '-p',
                f'n_sensors:={args.sensors}',
                '-p',
                'real_time_factor:=0.0',
                '-p',
                'wait_for_subscribers:=2',  # association node + recorder
                '-p',
                'wait_for_truth_subscribers:=2',
            )  # scorer + recorder
            why = collector.spin_until(
                lambda: len(collector.scores) >= args.episodes,
                timeout=args.timeout,
                abort=graph.failed,
            )
            if why:
                raise RuntimeError(f'not every episode was scored: {why}')
            if graph.procs['sensor_sim'].wait(30.0) != 0:
                raise RuntimeError(graph.failed() or 'sensor_sim did not finish')
            # The recorder may still be working off its backlog (it takes the messages that
            # DDS already acknowledged at its own pace): wait until it is idle, then stop it
            # with SIGINT so that it closes the bag cleanly.
            collector.spin_until(lambda: False, timeout=0.3)
            graph.close_recorder('demo')
        except (RuntimeError, KeyboardInterrupt) as exc:
            collector.close()
            return graph.report_failure('demo', exc)
        codes = graph.stop_all()
        collector.close()
    print(
        format_scores(
            collector.scores,
            f'\nlive association ({args.method}), '
            f'{args.targets} targets x {args.sensors} sensors:',
        )
    )
    print(replay_hint(bag_dir, ROOT))
    print(plot_beside_bag(bag_dir))
    print(f'demo: done in {time.monotonic() - t0:.1f} s; exit codes {codes}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
