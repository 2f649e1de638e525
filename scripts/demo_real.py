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
   on loopback DDS in a ROS domain of its own (or $ROS_DOMAIN_ID).

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
import re
import subprocess
import sys
import time
from pathlib import Path

from mlkm_assoc.timespace_plot import plot_beside_bag
from mlkm_ros.processes import (
    Graph,
    ScoreCollector,
    domain,
    executable,
    format_scores,
    replay_hint,
    start_association,
)

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / 'data' / 'ngsim_i80' / 'i80_trajectories_a.csv.gz'
ACCURACY = re.compile(r'accuracy: ([\d.]+) % \((\d+)/(\d+)\)')


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


def recorder_args(bag_dir: Path) -> list[str]:
    """Record every topic of the graph but the ROS housekeeping ones."""
    return [
        '--ros-args',
        '-p',
        f'output:={bag_dir}',
        '-p',
        'exclude_regex:=^/(rosout|parameter_events)$',
    ]


def mlkm(*args: str) -> subprocess.CompletedProcess:
    """Run the installed ``mlkm`` command line; RuntimeError with its message on failure."""
    run = subprocess.run(
        [str(executable('mlkm_assoc', 'mlkm')), *args], capture_output=True, text=True
    )
    if run.returncode != 0:
        raise RuntimeError(f'mlkm {args[0]} failed ({run.returncode}): {run.stderr.strip()}')
    return run


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


def offline(args: argparse.Namespace, log: Path, out: Path) -> tuple[float, int, int]:
    """(accuracy, correct, total) of ``mlkm associate`` on the log with the same method."""
    run = mlkm('associate', '--input', str(log), '--output', str(out), '--method', args.method)
    m = ACCURACY.search(run.stdout)
    if m is None:
        raise RuntimeError(f'mlkm associate printed no accuracy:\n{run.stdout}')
    return float(m.group(1)) / 100.0, int(m.group(2)), int(m.group(3))


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    stamp = time.strftime('demo_real_%Y%m%d_%H%M%S', time.gmtime())
    bag_dir = (args.bag_dir or ROOT / 'bags' / stamp).resolve()
    if bag_dir.exists():
        print(f'demo-real: {bag_dir} exists already; choose another --bag-dir', file=sys.stderr)
        return 2
    log_dir = bag_dir.parent / 'logs' / bag_dir.name
    log_dir.mkdir(parents=True, exist_ok=True)
    log, layout = log_dir / 'i80_loops.csv', log_dir / 'i80_loops.layout.yaml'
    t0 = time.monotonic()
    try:
        summary = build_log(args, log, layout)
        print(f'demo-real: {summary}')
        expected = offline(args, log, log_dir / 'i80_loops.tracks.csv')
    except RuntimeError as exc:
        print(f'demo-real: FAILED: {exc}', file=sys.stderr)
        return 1
    with domain() as domain_id:
        print(f'demo-real: ROS_DOMAIN_ID={domain_id}, loopback DDS; logs in {log_dir}')
        collector = ScoreCollector(domain_id)
        graph = Graph(domain_id, log_dir)
        try:
            start_association(
                graph,
                collector,
                args.method,
                ('bag_recorder', 'rosbag_mcap', 'bag_recorder', *recorder_args(bag_dir)),
            )
            source = graph.start(
                'log_source',
                'road_sensors',
                'log_source',
                '--ros-args',
                *('-p', f'log:={log}', '-p', f'layout:={layout}', '-p', 'mode:=episodes'),
                *('-p', 'real_time_factor:=0.0'),
                *('-p', 'wait_for_subscribers:=2'),  # association node + recorder
                *('-p', 'wait_for_truth_subscribers:=2'),  # scorer + recorder
            )
            why = collector.spin_until(
                lambda: len(collector.scores) >= 1, timeout=args.timeout, abort=graph.failed
            )
            if why:
                raise RuntimeError(f'the log was not scored: {why}')
            if source.wait(30.0) != 0:
                raise RuntimeError(graph.failed() or 'log_source did not finish')
            # The recorder may still be working off its backlog: wait until it is idle, then
            # stop it with SIGINT so that it closes the bag cleanly.
            collector.spin_until(lambda: False, timeout=0.3)
            graph.close_recorder('demo-real')
        except (RuntimeError, KeyboardInterrupt) as exc:
            collector.close()
            return graph.report_failure('demo-real', exc)
        codes = graph.stop_all()
        collector.close()
    road = 'open' if args.open else 'closed'
    print(
        format_scores(
            collector.scores,
            f'\nlive association ({args.method}) of the NGSIM I-80 log, {args.stations} '
            f'stations {args.start:g}..{args.end:g} m, {road} road:',
        )
    )
    live = collector.scores[min(collector.scores)]
    accuracy, correct, total = expected
    same = (live.correct, live.total) == (correct, total)
    print(
        f'offline `mlkm associate --method {args.method}` on the same log: accuracy '
        f'{accuracy:.4f} ({correct}/{total}); live {"equals" if same else "DIFFERS FROM"} it'
    )
    print(replay_hint(bag_dir, ROOT))
    print(plot_beside_bag(bag_dir))
    print(f'demo-real: done in {time.monotonic() - t0:.1f} s; exit codes {codes}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
