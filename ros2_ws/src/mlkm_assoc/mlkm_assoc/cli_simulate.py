"""``mlkm simulate``: write a detections CSV from the product's road-traffic simulator.

``mlkm simulate --output DETECTIONS.csv [--layout LAYOUT.yaml] [--episodes N | --duration S]
[--vehicles N] [--stations N] [--road-length M] [--seed S] [--miss-rate P]
[--false-alarms-per-vehicle R] [--stamp-jitter S] [--speed-noise M/S] [--gap S]
[--arrival-rate R] [--progress]``

runs ``mlkm_core.simulator`` (the paper's model; the same seed gives the same detections as
``sensor_sim`` with the same parameters) and writes what the stations report as the CSV that
``mlkm associate --input`` reads, with the vehicle as ground truth (``target_id``, -1 for a
false alarm). ``--episodes N`` (default 1): N episodes of ``--vehicles`` vehicles on a closed
road, back to back ``--gap`` seconds apart on one layout (``simulate_episodes``); the
vehicles of episode k are numbered from k * ``--vehicles`` on, so every vehicle has an id of
its own. ``--duration S``: an open road for S seconds of passage time instead, vehicles
entering for ever (``simulate_stream``). ``--layout`` also writes the road as a layout file
(``mlkm_core.layout_file``) for the log source node. The simulator reports no lane and no
vehicle length (the columns stay -1 and empty). Positions are rounded to 1 mm, the precision
of the CSV, in both files.

Returns 0, or 2 with one line ``mlkm simulate: error: ...`` on bad flags; nothing is written
then.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from array import array
from dataclasses import replace
from pathlib import Path

import numpy as np

from mlkm_assoc.cli import _output_problem
from mlkm_assoc.cli_run import Progress, absolute
from mlkm_core.cli_args import (
    Refused,
    RefusingParser,
    non_negative_float,
    positive_float,
    positive_int,
    probability,
    refusing,
    renamed_option,
    seed,
)
from mlkm_core.csvout import POSITION_DECIMALS, write_detections
from mlkm_core.layout_file import LayoutFileError, RoadLayout, write_layout_file
from mlkm_core.simulator import SimConfig, iter_episodes, shift, stream_origin
from mlkm_core.simulator_stream import simulate_stream, stream_layout
from mlkm_core.types import FALSE_ALARM, Detections, Layout

PROG = 'mlkm simulate'
#: Stream detections between two updates of the progress bar [detections].
STREAM_TICK = 16_384


def build_parser() -> argparse.ArgumentParser:
    d = SimConfig()
    p = RefusingParser(
        prog=PROG,
        description="Simulate road traffic with the product's simulator (the paper's model) and "
        'write what the stations report as a detections CSV (sensor_id,position_m,stamp_s,'
        'velocity_mps,target_id,lane,length_m; target_id = the vehicle, -1 = false alarm), '
        'the input of mlkm associate.',
    )
    renamed_option(
        p,
        '--output',
        '--out',
        required=True,
        metavar='DETECTIONS.csv',
        help='detections CSV to write',
    )
    p.add_argument(
        '--layout', metavar='LAYOUT.yaml', help='also write the road as a layout file (YAML)'
    )
    length = p.add_mutually_exclusive_group()
    length.add_argument(
        '--episodes',
        type=positive_int,
        metavar='N',
        help='episodes of --vehicles vehicles on a closed road, back to back (default: 1)',
    )
    length.add_argument(
        '--duration',
        type=positive_float,
        metavar='S',
        help='instead: an open road, vehicles entering for ever, for this much passage time [s]',
    )
    p.add_argument(
        '--vehicles',
        type=positive_int,
        default=d.n_targets,
        metavar='N',
        help=f'vehicles (targets) per episode (default: {d.n_targets})',
    )
    p.add_argument(
        '--stations',
        type=positive_int,
        default=d.n_sensors,
        metavar='N',
        help=f'stations at random positions along the road (default: {d.n_sensors})',
    )
    p.add_argument(
        '--road-length',
        type=positive_float,
        default=d.road_length,
        metavar='M',
        help=f'road length [m] (default: {d.road_length:g})',
    )
    p.add_argument(
        '--seed', type=seed, default=0, help='seed of the layout and the traffic (default: 0)'
    )
    p.add_argument(
        '--gap',
        type=non_negative_float,
        default=10.0,
        metavar='S',
        help='passage time between two episodes [s] (default: 10)',
    )
    p.add_argument(
        '--arrival-rate',
        type=non_negative_float,
        default=0.0,
        metavar='R',
        help="with --duration: Poisson arrivals [vehicles/s]; 0 = the paper's entry spacing "
        f'U({d.start_increment_min:g}, {d.start_increment_max:g}) s (default: 0)',
    )
    m = p.add_argument_group('measurement model (all off by default)')
    m.add_argument(
        '--miss-rate', type=probability, default=0.0, help='P(passage not reported), in [0, 1)'
    )
    m.add_argument(
        '--false-alarms-per-vehicle',
        type=non_negative_float,
        default=0.0,
        metavar='R',
        help='expected false alarms per station per vehicle [-]',
    )
    m.add_argument(
        '--stamp-jitter', type=non_negative_float, default=0.0, help='time noise std [s]'
    )
    m.add_argument(
        '--speed-noise', type=non_negative_float, default=0.0, help='speed noise std [m/s]'
    )
    p.add_argument(
        '--progress',
        action=argparse.BooleanOptionalAction,
        default=None,
        help='progress bars on stderr (default: only when stderr is a terminal)',
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """write a detections CSV from the product's simulator (the paper's model)"""
    return refusing(PROG, _run, argv)


def _run(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    if args.duration is None and args.arrival_rate > 0:
        raise Refused('--arrival-rate needs --duration (an open road)')
    output = Path(args.output)
    if args.layout and output.resolve() == Path(args.layout).resolve():
        raise Refused('--output and --layout name the same file')
    for flag, out in (('--output', output), ('--layout', args.layout)):
        problem = out and _output_problem(Path(out))
        if problem:
            raise Refused(problem.replace('--output', flag))
    try:
        config = SimConfig(
            road_length=args.road_length,
            n_sensors=args.stations,
            n_targets=args.vehicles,
            miss_probability=args.miss_rate,
            false_alarm_rate=args.false_alarms_per_vehicle,
            stamp_noise=args.stamp_jitter,
            velocity_noise=args.speed_noise,
        )
    except ValueError as exc:
        raise Refused(str(exc)) from None
    progress = Progress(sys.stderr.isatty() if args.progress is None else args.progress)
    t0 = time.perf_counter()
    if args.duration is None:
        layout, det, what = _episodes(config, args, progress)
    else:
        layout, det, what = _stream(config, args, progress)
    try:
        layout = Layout(
            layout.road_length, np.round(layout.positions, POSITION_DECIMALS), layout.sensor_ids
        )
    except ValueError as exc:
        raise Refused(f'two stations within 1 mm: {exc}; choose another --seed') from None
    bar = progress.bar('writing', total=len(det), unit='row', scale=True)
    try:
        write_detections(output, layout, det, progress=absolute(bar))
        if args.layout:
            comment = f'{what}, seed {args.seed}\nwritten by: {PROG} {shlex.join(argv)}'
            try:
                write_layout_file(args.layout, RoadLayout(layout), comment)
            except (OSError, LayoutFileError):
                output.unlink(missing_ok=True)  # all or nothing: no CSV without its layout
                raise
    except (OSError, LayoutFileError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise Refused(f'cannot write: {reason}') from None
    finally:
        if bar is not None:
            bar.close()
    n_fa = int(np.sum(det.target == FALSE_ALARM))
    print(
        f'{len(det)} detections ({n_fa} false alarms) of {what} at {layout.n_sensors} stations '
        f'on {layout.road_length:g} m, seed {args.seed}, in {time.perf_counter() - t0:.1f} s, '
        f'written to {output}' + (f' and {args.layout}' if args.layout else '')
    )
    return 0


def _episodes(config: SimConfig, args: argparse.Namespace, progress: Progress):
    """(layout, detections, description) of ``--episodes`` closed-road episodes."""
    n = args.episodes or 1
    bar = progress.bar('simulating', total=n, unit='episode')
    datasets = []
    for k, ds in enumerate(iter_episodes(config, args.seed, n, args.gap)):
        if k == 0:  # stamps from t >= 0, as sensor_sim publishes them (ROS times)
            origin = stream_origin([ds])
        d = shift(ds, origin).detections
        # vehicle numbers of their own per episode (false alarms stay FALSE_ALARM)
        target = np.where(d.target == FALSE_ALARM, FALSE_ALARM, d.target + k * config.n_targets)
        datasets.append(Detections(d.sensor_index, d.stamp, d.velocity, target))
        if bar is not None:
            bar.update()
    if bar is not None:
        bar.close()
    what = f'{n} episode{"s" if n != 1 else ""} of {config.n_targets} vehicles'
    return ds.layout, Detections.concatenate(datasets), what


def _stream(config: SimConfig, args: argparse.Namespace, progress: Progress):
    """(layout, detections, description) of an open road for ``--duration`` seconds."""
    config = replace(config, n_targets=1)  # ignored by the stream
    bar = progress.bar('simulating', total=args.duration, unit='s')
    sensor, target = array('q'), array('q')
    stamp, velocity = array('d'), array('d')
    for n, det in enumerate(simulate_stream(config, args.seed, args.arrival_rate, args.duration)):
        sensor.append(det.sensor_index)
        stamp.append(det.stamp)
        velocity.append(det.velocity)
        target.append(det.target)
        if bar is not None and n % STREAM_TICK == 0:
            bar.update(min(det.stamp, args.duration) - bar.n)
    if bar is not None:
        bar.close()
    det = Detections(
        np.frombuffer(sensor, np.int64),
        np.frombuffer(stamp),
        np.frombuffer(velocity),
        np.frombuffer(target, np.int64),
    )
    vehicles = np.unique(det.target[det.target != FALSE_ALARM]).size
    what = f'{vehicles} vehicles in {args.duration:g} s (open road)'
    return stream_layout(config, args.seed), det, what


if __name__ == '__main__':
    sys.exit(main())
