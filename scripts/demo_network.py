#!/usr/bin/env python3
"""`make demo-network`: the live graph on a road network with junctions (a SUMO interchange).

1. Simulates a freeway interchange of the ``interchange`` family with SUMO (``mlkm sumo
   --network interchange``: two freeways, a diverge, a connector and a merge, drawn for the
   seed) and writes its detector log (the detections CSV, ground truth = SUMO vehicle) and its
   network layout file (links, junctions, stations on links).
2. Associates the log offline with ``mlkm associate --layout``, with the method and with
   ``gmlkm`` (the baseline in the spirit of the paper's graph-based follow-up).
3. Starts, as separate processes: mlkm_assoc association_node, mlkm_assoc scorer_node,
   rosbag_mcap bag_recorder and road_sensors log_source, which publishes the network layout
   (SensorLayout in its network form) and replays the log as one episode, on loopback DDS in a
   ROS domain of its own (``mlkm_ros.log_graph``).

Prints the live accuracy (from /mlkm/score) beside the offline one (the same method on the
same file; they are equal) and the baseline's, leaves the bag under bags/, stops every
process and exits 0 (nonzero when something failed). The log, its layout file and the node
logs go to <bag>/../logs/<bag name>/.

Usage: python scripts/demo_network.py [--method M] [--seed N] [--vehicles N] [--bag-dir DIR]
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
BASELINE = 'gmlkm'


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--method', default='assignment', help='network method (assignment)')
    p.add_argument('--seed', type=int, default=1, help='interchange drawn for this seed (1)')
    p.add_argument(
        '--vehicles', type=int, default=None, help='vehicles released (the family default)'
    )
    p.add_argument('--bag-dir', type=Path, default=None, help='bag to write')
    p.add_argument('--timeout', type=float, default=120.0, help='give up after [s] (120)')
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    dirs = run_dirs('demo-network', args.bag_dir, ROOT / 'bags')
    if dirs is None:
        return 2
    bag_dir, log_dir = dirs
    log, layout = log_dir / 'interchange.csv', log_dir / 'interchange.layout.yaml'
    t0 = time.monotonic()
    try:
        run = mlkm(
            'sumo',
            *('--network', 'interchange', '--seed', str(args.seed)),
            *([] if args.vehicles is None else ['--vehicles', str(args.vehicles)]),
            *('--output', str(log), '--layout', str(layout)),
        )
        print(f'demo-network: {run.stdout.strip()}')
        on_net = ('--layout', str(layout))
        accuracy, correct, total = offline(log, args.method, log_dir / 'tracks.csv', *on_net)
        base = offline(log, BASELINE, log_dir / f'tracks_{BASELINE}.csv', *on_net)
    except RuntimeError as exc:
        print(f'demo-network: FAILED: {exc}', file=sys.stderr)
        return 1
    live_run = run_log_graph(
        'demo-network', log, layout, args.method, bag_dir, log_dir, args.timeout
    )
    if live_run is None:
        return 1
    print(
        format_scores(
            live_run.scores,
            f'\nlive association ({args.method}) of the interchange (seed {args.seed}):',
        )
    )
    live = live_run.score
    same = (live.correct, live.total) == (correct, total)
    print(
        f'offline `mlkm associate --layout --method {args.method}` on the same log: accuracy '
        f'{accuracy:.4f} ({correct}/{total}); live {"equals" if same else "DIFFERS FROM"} it'
    )
    print(f'the baseline {BASELINE} offline: accuracy {base[0]:.4f} ({base[1]}/{base[2]})')
    print(replay_hint(bag_dir, ROOT))
    print(plot_beside_bag(bag_dir))  # of the route with the most stations
    print(f'demo-network: done in {time.monotonic() - t0:.1f} s; exit codes {live_run.codes}')
    return 0 if same else 1


if __name__ == '__main__':
    sys.exit(main())
