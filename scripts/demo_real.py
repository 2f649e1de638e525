#!/usr/bin/env python3
"""`make demo-real`: the live graph on real traffic, replayed from a detector log.

1. Places virtual loops on the shipped NGSIM I-80 trajectories (``data/ngsim_i80``: 111 real
   vehicles, congested, stop-and-go) with ``mlkm loops``: 10 stations from 50 to 450 m, the
   closed road (the vehicles seen at every station). That writes the detector log (the
   detections CSV, ground truth = NGSIM vehicle id) and its layout file.
2. Associates the log offline with ``mlkm associate``.
3. Starts, as separate processes (what a user starts in separate terminals):
   mlkm_assoc association_node, mlkm_assoc scorer_node, rosbag_mcap bag_recorder, and
   road_sensors log_source (mode episodes: the whole log is one episode, real_time_factor 0),
   on loopback DDS in a ROS domain of its own (or $ROS_DOMAIN_ID); ``mlkm_ros.log_graph``.

Prints the live accuracy (from /mlkm/score) beside the offline one (the same method on the
same file; they are equal), leaves the bag under bags/ with its time-space diagram beside
it (<bag>_timespace.png, as `mlkm plot` draws it), stops every process and exits 0
(nonzero when something failed). The log, its layout file and the node logs go to
<bag>/../logs/<bag name>/.

The method is ``multiframe``, not the association node's default ``mlkm``: on real
stop-and-go traffic MLKM's clustering associates less than half of these detections, multiframe
(which also uses the lane and length the loops report) all of them.

Usage: python scripts/demo_real.py [--method M] [--stations N] [--start M] [--end M]
       [--open] [--bag-dir DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from mlkm_assoc.timespace_plot import plot_beside_bag
from mlkm_ros.log_graph import mlkm, offline, run_dirs, run_log_graph
from mlkm_ros.processes import format_scores, replay_hint

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / 'data' / 'ngsim_i80' / 'i80_trajectories_a.csv.gz'


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--method', default='multiframe', help='associator (multiframe)')
    p.add_argument('--stations', type=int, default=10, help='loop stations (10)')
    p.add_argument('--start', type=float, default=50.0, help='first station [m] (50)')
    p.add_argument('--end', type=float, default=450.0, help='last station [m] (450)')
    p.add_argument(
        '--open',
        action='store_true',
        help='keep every observed crossing (default: the closed road, vehicles seen at every '
        'station)',
    )
    p.add_argument('--input', type=Path, default=DATA, help='trajectories (NGSIM I-80 part A)')
    p.add_argument('--bag-dir', type=Path, default=None, help='bag to write')
    p.add_argument('--timeout', type=float, default=120.0, help='give up after [s] (120)')
    return p.parse_args(argv)


def build_log(args: argparse.Namespace, log: Path, layout: Path) -> str:
    """The detector log and its layout file from the trajectories; returns the summary."""
    run = mlkm(
        'loops',
        *('--input', str(args.input), '--stations', str(args.stations)),
        *('--start', f'{args.start:g}', '--end', f'{args.end:g}'),
        *([] if args.open else ['--closed']),
        *('--output', str(log), '--layout', str(layout)),
    )
    return run.stdout.strip()


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    dirs = run_dirs('demo-real', args.bag_dir, ROOT / 'bags')
    if dirs is None:
        return 2
    bag_dir, log_dir = dirs
    log, layout = log_dir / 'i80_loops.csv', log_dir / 'i80_loops.layout.yaml'
    t0 = time.monotonic()
    try:
        summary = build_log(args, log, layout)
        print(f'demo-real: {summary}')
        accuracy, correct, total = offline(log, args.method, log_dir / 'i80_loops.tracks.csv')
    except RuntimeError as exc:
        print(f'demo-real: FAILED: {exc}', file=sys.stderr)
        return 1
    run = run_log_graph('demo-real', log, layout, args.method, bag_dir, log_dir, args.timeout)
    if run is None:
        return 1
    road = 'open' if args.open else 'closed'
    print(
        format_scores(
            run.scores,
            f'\nlive association ({args.method}) of the NGSIM I-80 log, {args.stations} '
            f'stations {args.start:g}..{args.end:g} m, {road} road:',
        )
    )
    live = run.score
    same = (live.correct, live.total) == (correct, total)
    print(
        f'offline `mlkm associate --method {args.method}` on the same log: accuracy '
        f'{accuracy:.4f} ({correct}/{total}); live {"equals" if same else "DIFFERS FROM"} it'
    )
    print(replay_hint(bag_dir, ROOT))
    print(plot_beside_bag(bag_dir))
    print(f'demo-real: done in {time.monotonic() - t0:.1f} s; exit codes {run.codes}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
