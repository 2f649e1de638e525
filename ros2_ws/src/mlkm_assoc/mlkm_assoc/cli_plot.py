"""``mlkm plot``: draw the time-space diagram of a tracks CSV or a recorded bag to PNG.

``mlkm plot --input TRACKS.csv|BAG --output FIGURE.png [--title TEXT] [--layout NETWORK.yaml]
[--route LINK,LINK,...]``

Time on x, the stations' positions on y (thin grey lines); each track a line through its
detections in one colour per track id, detections that no track took as grey crosses and,
where ground truth is known, the wrong links (two detections of different true targets, or
a false alarm, in one track) in red. The input is a tracks CSV as ``mlkm associate
--output`` writes it (the detections CSV plus ``track_id``; its ``target_id`` column is the
truth), or a bag directory (or .mcap) recorded by the product: its ``/mlkm/tracks`` (each
track's final version), ``/road/sensor_layout`` and ``/road/ground_truth``
(``mlkm_assoc.timespace_bag``). The figure's content is ``mlkm_core.timespace``.

On a road network (a tracks CSV with ``--layout`` naming its network layout file, or a bag of
a network run) the diagram is that of one route (``mlkm_core.network_route``): ``--route``
names its links, each joined to the one before by a connection; by default the route with
the most stations. The detections off the route are left out (counted in a warning).

Prints one line (detections, tracks, unassigned, links, wrong links) and the PNG's path.
Returns 0, or 2 with one line ``mlkm plot: error: ...`` on bad input (unreadable file, no
track_id column, a bag without tracks, an output that cannot be written); nothing is
written then.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from mlkm_assoc.cli import _output_problem
from mlkm_core.cli_args import Refused, RefusingParser, refusing

PROG = 'mlkm plot'


def build_parser() -> argparse.ArgumentParser:
    p = RefusingParser(
        prog=PROG,
        description='Draw the time-space diagram (stations against time; one line per track, '
        'unassigned detections as crosses, wrong links in red where ground truth is known) '
        'of a tracks CSV or a recorded bag, to PNG.',
    )
    p.add_argument(
        '--input',
        required=True,
        metavar='TRACKS.csv|BAG',
        help='tracks CSV written by mlkm associate --output (with target_id: wrong links '
        'in red), or a bag directory / .mcap recorded by the product (/mlkm/tracks, '
        '/road/sensor_layout, /road/ground_truth)',
    )
    p.add_argument('--output', required=True, metavar='FIGURE.png', help='PNG file to write')
    p.add_argument(
        '--layout',
        metavar='NETWORK.yaml',
        help='the network layout file of a tracks CSV written on a road network (mlkm '
        'associate --layout); a bag carries its layout',
    )
    p.add_argument(
        '--route',
        metavar='LINK,LINK,...',
        help='on a road network: the links of the route to draw (names or ids, each joined to '
        'the one before); default: the route with the most stations',
    )
    p.add_argument(
        '--title',
        help='figure title; {summary} in it stands for the counts (default: the input name '
        'and the counts)',
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """draw the time-space diagram of a tracks CSV or a bag to PNG"""
    return refusing(PROG, _run, argv)


def _run(argv: list[str]) -> int:
    from mlkm_assoc.timespace_plot import plot, read_tracks_csv

    args = build_parser().parse_args(argv)
    source, output = Path(args.input), Path(args.output)
    if output.suffix.lower() != '.png':
        raise Refused(f'{output}: --output must be a .png file')
    problem = _output_problem(output, source)
    if problem:
        raise Refused(problem)
    t0 = time.perf_counter()
    try:
        if source.is_dir() or source.suffix == '.mcap':
            from mlkm_assoc.timespace_bag import read_bag

            if args.layout:
                raise Refused('--layout is for a tracks CSV: a bag carries its layout')
            data = read_bag(source, route=args.route)
        else:
            network = None
            if args.layout:
                from mlkm_core.network_file import read_network_file

                network = read_network_file(args.layout)
            elif args.route:
                raise Refused('--route needs a road network: give the tracks CSV its --layout')
            data = read_tracks_csv(source, network, args.route)
    except (OSError, ValueError) as exc:  # InputError and BagError are ValueErrors
        raise Refused(str(exc)) from None
    for note in data.notes:
        print(f'{PROG}: warning: {note}', file=sys.stderr)
    output.parent.mkdir(parents=True, exist_ok=True)
    try:
        line = plot(data, output, args.title)
    except ValueError as exc:
        raise Refused(f'{source}: {exc}') from None
    except OSError as exc:
        raise Refused(f'{output}: cannot write: {exc.strerror or exc}') from None
    print(f'{line}; time-space diagram written to {output} ({time.perf_counter() - t0:.1f} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
