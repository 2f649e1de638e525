"""``mlkm loops``: place virtual loop detectors on vehicle trajectories and write the detections.

``mlkm loops --input TRAJ [--stations N | --stations-at X,Y,...] [--start M] [--end M] [--closed]
[--lanes N] [--fcd-position x|distance] --output DETECTIONS.csv [--layout LAYOUT.yaml]``

reads trajectories (trajectory CSV, NGSIM, SUMO FCD: ``mlkm_core.trajectories``), reports what
a loop at each station would have seen (``mlkm_core.loops``: the crossing time, speed, lane
and length of every vehicle, the vehicle id as ground truth) and writes it as the detections
CSV that ``mlkm associate --input`` reads; ``--layout`` also writes the road as a layout
file (``mlkm_core.layout_file``) for the log source node. Stations are ``--stations`` evenly
spaced from ``--start`` to ``--end`` (default: the covered span of the data, 5 % trimmed at
each end) or the positions of ``--stations-at``; positions are rounded to 1 mm, the precision the
detections CSV has. ``--closed`` keeps only the vehicles detected at every station.

Returns 0, or 2 with one line ``mlkm loops: error: ...`` on bad input (an unreadable
trajectory file, bad flags, a station off the road the trajectories cover, no detection at
all); nothing is written then.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

import numpy as np

from mlkm_assoc.cli import _output_problem
from mlkm_core.cli_args import (
    Refused,
    RefusingParser,
    finite_float,
    positive_int,
    refusing,
    renamed_option,
)
from mlkm_core.csvout import POSITION_DECIMALS, write_detections
from mlkm_core.layout_file import LayoutFileError, RoadLayout, write_layout_file
from mlkm_core.loops import covered_span, even_positions, virtual_loops
from mlkm_core.trajectories import TrajectoryError, read_trajectories

PROG = 'mlkm loops'
#: Stations when neither --stations nor --stations-at is given [-].
DEFAULT_STATIONS = 10


def _positions(text: str) -> list[float]:
    values = [finite_float(x.strip()) for x in text.split(',') if x.strip()]
    if not values:
        raise argparse.ArgumentTypeError('no position given')
    return values


def build_parser() -> argparse.ArgumentParser:
    p = RefusingParser(
        prog=PROG,
        description='Place virtual loop detectors on vehicle trajectories (trajectory CSV, '
        'NGSIM, SUMO FCD XML) and write what they report as a detections CSV '
        '(sensor_id,position_m,stamp_s,velocity_mps,target_id,lane,length_m; target_id = the '
        'vehicle id), the input of mlkm associate.',
    )
    p.add_argument(
        '--input',
        required=True,
        metavar='TRAJ',
        help='trajectories: trajectory CSV (vehicle_id,time_s,y_m,speed_mps,lane_id,length_m; '
        '.csv or .csv.gz), NGSIM (feet, with or without its header) or SUMO FCD XML',
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        '--stations',
        type=positive_int,
        metavar='N',
        help=f'this many stations evenly spaced from --start to --end (default: '
        f'{DEFAULT_STATIONS})',
    )
    renamed_option(
        p,
        '--stations-at',
        '--at',
        group=where,
        type=_positions,
        metavar='X,Y,...',
        help='station positions [m], e.g. 50,150,250',
    )
    p.add_argument(
        '--start',
        type=finite_float,
        metavar='M',
        help='first station [m] (default: start of the covered span)',
    )
    p.add_argument(
        '--end', type=finite_float, metavar='M', help='last station [m] (default: end of the span)'
    )
    p.add_argument(
        '--closed',
        action='store_true',
        help='keep only the vehicles detected at every station (a closed road); default: '
        'every observed crossing (an open road)',
    )
    p.add_argument(
        '--lanes',
        type=positive_int,
        metavar='N',
        help="lanes of the road, to count NGSIM's left-based lane ids from the right "
        '(default: the largest lane id in the file)',
    )
    p.add_argument(
        '--fcd-position',
        choices=('x', 'distance'),
        default='x',
        help='SUMO FCD attribute that is the position along the road (default: x; distance '
        'needs --fcd-output.distance)',
    )
    p.add_argument(
        '--output', required=True, metavar='DETECTIONS.csv', help='detections CSV to write'
    )
    renamed_option(
        p,
        '--layout',
        '--layout-out',
        metavar='LAYOUT.yaml',
        help='also write the road as a layout file (YAML)',
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """place virtual loop detectors on vehicle trajectories (NGSIM, SUMO FCD)"""
    return refusing(PROG, _run, argv)


def _run(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    if args.stations_at is not None and (args.start is not None or args.end is not None):
        raise Refused('--start and --end place --stations; --stations-at gives the positions')
    input_path, output = Path(args.input), Path(args.output)
    outputs = [output] + ([Path(args.layout)] if args.layout else [])
    if len(outputs) == 2 and outputs[0].resolve() == outputs[1].resolve():
        raise Refused('--output and --layout name the same file')
    for flag, out in zip(('--output', '--layout'), outputs, strict=False):
        problem = _output_problem(out, input_path)
        if problem:
            raise Refused(problem.replace('--output', flag))
    try:
        traj = read_trajectories(input_path, args.lanes, args.fcd_position)
    except TrajectoryError as exc:
        raise Refused(str(exc)) from None
    positions = _stations(args, traj)
    try:
        loops = virtual_loops(traj, positions, closed=args.closed)
    except ValueError as exc:
        raise Refused(f'{input_path}: {exc}') from None
    det, layout = loops.dataset.detections, loops.dataset.layout
    if len(det) == 0:
        where = 'every station (--closed)' if args.closed else 'any station'
        raise Refused(f'{input_path}: no vehicle is detected at {where} of {_listed(positions)} m')
    silent = np.setdiff1d(np.arange(layout.n_sensors), det.sensor_index)
    if silent.size:
        print(
            f'{PROG}: warning: no vehicle crosses the station(s) at '
            f'{_listed(positions[silent])} m; the detections CSV has no row for them',
            file=sys.stderr,
        )
    road = RoadLayout(layout, np.full(layout.n_sensors, loops.lanes, np.int64))
    variant = 'closed' if loops.closed else 'open'
    comment = (
        f'virtual loops ({variant} road) on {input_path}: {len(det)} detections of '
        f'{loops.vehicles_detected} of {loops.vehicles_seen} vehicles\n'
        f'written by: {PROG} {shlex.join(argv)}'
    )
    try:
        write_detections(output, layout, det)
    except OSError as exc:
        raise Refused(f'{output}: cannot write: {exc.strerror or exc}') from None
    if args.layout:
        try:
            write_layout_file(args.layout, road, comment)
        except (OSError, LayoutFileError) as exc:
            output.unlink(missing_ok=True)  # all or nothing: no CSV without its layout
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
            raise Refused(f'{args.layout}: cannot write: {reason}') from None
    print(
        f'{len(det)} detections of {loops.vehicles_detected} vehicles ({loops.vehicles_seen} '
        f'seen; {variant} road) at {layout.n_sensors} stations, {positions[0]:g} .. '
        f'{positions[-1]:g} m, {loops.lanes or "unknown"} lanes, written to {output}'
        + (f' and {args.layout}' if args.layout else '')
    )
    return 0


def _stations(args: argparse.Namespace, traj) -> np.ndarray:
    """The station positions of the flags [m], rounded to 1 mm, checked against the road."""
    lo, hi = float(traj.position.min()), float(traj.position.max())
    if args.stations_at is not None:
        positions = np.array(sorted(args.stations_at))
    else:
        start, end = covered_span(traj)
        start = start if args.start is None else args.start
        end = end if args.end is None else args.end
        try:
            positions = even_positions(args.stations or DEFAULT_STATIONS, start, end)
        except ValueError as exc:
            raise Refused(f'--start/--end: {exc}') from None
    positions = np.round(positions, POSITION_DECIMALS)
    if np.any(np.diff(positions) <= 0):
        raise Refused(f'two stations at one position (to 1 mm): {_listed(positions)} m')
    off = positions[(positions < max(lo, 0.0)) | (positions > hi)]
    if off.size:
        raise Refused(
            f'station(s) at {_listed(off)} m off the road the trajectories cover '
            f'({max(lo, 0.0):g} .. {hi:g} m)'
        )
    return positions


def _listed(positions) -> str:
    return ', '.join(f'{float(x):g}' for x in positions)


if __name__ == '__main__':
    sys.exit(main())
