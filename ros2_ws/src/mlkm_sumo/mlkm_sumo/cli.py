"""``mlkm sumo``: run a SUMO scenario headless and write the detections as the product's CSV.

``--scenario`` runs one of the single-road scenarios; ``--network`` draws a road network of a
family (``network_families``: interchange, arterial, grid) for ``--seed``, runs it and writes
the detections CSV (positions along each station's link) and the network layout file
(``--layout``), which ``mlkm associate --layout`` reads. ``main(argv)`` returns the exit
code: 0 on success, 2 with a one-line message on bad input (unknown scenario or family, bad
layout, netconvert or SUMO failure); nothing is written then.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from mlkm_core.cli_args import renamed_option, seed
from mlkm_core.csvout import write_detections

from .api import SumoDataset, generate
from .measurement import CSV_DECIMALS, KIND_NAMES, MeasurementConfig
from .network import SumoError
from .network_families import NETWORK_FAMILIES
from .scenarios import SCENARIOS

DEFAULT_DURATION = 600.0


def _positions(text: str) -> list[float]:
    try:
        return [float(x) for x in text.replace(',', ' ').split()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f'expected positions in metres separated by commas, got {text!r}'
        ) from None


def _nonneg(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}') from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f'must be finite and >= 0, got {text!r}')
    return v


def build_parser() -> argparse.ArgumentParser:
    scenarios = '; '.join(f'{s.name}: {s.description}' for s in SCENARIOS.values())
    p = argparse.ArgumentParser(
        prog='mlkm sumo',
        description='Simulate road traffic with Eclipse SUMO (headless) and write the loop '
        'detections as a detections CSV (sensor_id,position_m,stamp_s,velocity_mps,target_id,'
        f'lane,length_m). Scenarios: {scenarios}.',
    )
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument('--scenario', help='single-road scenario name (see above)')
    what.add_argument(
        '--network',
        choices=sorted(NETWORK_FAMILIES),
        help='a road network of this family, drawn for --seed (needs --layout; --vehicles '
        'sets its vehicle count, --flow its demand; the station options do not apply)',
    )
    p.add_argument('--layout', help='with --network: the network layout file (YAML) to write')
    renamed_option(p, '--output', '--out', required=True, help='detections CSV to write')
    p.add_argument(
        '--vehicles',
        type=int,
        help='release this many vehicles and run until all left the road (default: continuous '
        'traffic for --duration)',
    )
    p.add_argument(
        '--duration',
        type=float,
        help=f'simulated seconds of continuous traffic (default {DEFAULT_DURATION:g}); with '
        '--vehicles an upper limit',
    )
    p.add_argument('--stations', type=int, default=20, help='number of stations (random)')
    p.add_argument(
        '--stations-at', type=_positions, help='station positions [m], e.g. 500,1200,2600'
    )
    p.add_argument(
        '--seed', type=seed, default=1, help='seed of SUMO, layout and measurement (default: 1)'
    )
    p.add_argument('--flow', type=float, help="demand [vehicles/h] (default: the scenario's)")
    p.add_argument('--step-length', type=float, default=0.2, help='SUMO step [s] (0.2)')
    p.add_argument('--cache-dir', help='network cache (default $XDG_CACHE_HOME/mlkm_sumo)')
    renamed_option(
        p, '--road', '--road-out', help='also write the road (lanes per station, ramps) as JSON'
    )
    m = p.add_argument_group('measurement model (all off by default)')
    m.add_argument('--stamp-jitter', type=_nonneg, default=0.0, help='time noise std [s]')
    m.add_argument('--speed-noise', type=_nonneg, default=0.0, help='speed noise std [m/s]')
    m.add_argument('--length-noise', type=_nonneg, default=0.0, help='length noise std [m]')
    m.add_argument('--miss-rate', type=_nonneg, default=0.0, help='P(passage not reported)')
    m.add_argument(
        '--false-alarm-rate', type=_nonneg, default=0.0, help='false alarms per station per hour'
    )
    m.add_argument(
        '--no-double-reports',
        action='store_true',
        help='remove the second report of a vehicle changing lane on top of a station',
    )
    return p


def write_csv(path: Path, ds: SumoDataset) -> None:
    """Rows sorted by stamp, written atomically (``mlkm_core.csvout``)."""
    write_detections(path, ds.layout, ds.detections, decimals=CSV_DECIMALS)


def road_json(ds: SumoDataset) -> dict:
    r = ds.road
    return {
        'scenario': r.scenario,
        'road_length_m': r.layout.road_length,
        'stations': [
            {'sensor_id': int(i), 'position_m': float(x), 'lanes': int(n)}
            for i, x, n in zip(r.layout.sensor_ids, r.layout.positions, r.lanes)
        ],
        'ramps': [{'kind': p.kind, 'edge': p.edge, 'position_m': p.position} for p in r.ramps],
        'enter_between': r.enter_between.tolist(),
        'leave_between': r.leave_between.tolist(),
        'stats': ds.stats,
    }


def _measurement(args: argparse.Namespace) -> MeasurementConfig:
    return MeasurementConfig(
        stamp_jitter=args.stamp_jitter,
        speed_noise=args.speed_noise,
        length_noise=args.length_noise,
        miss_rate=args.miss_rate,
        false_alarm_rate=args.false_alarm_rate,
        double_reports=not args.no_double_reports,
    )


def _network(args: argparse.Namespace, measurement: MeasurementConfig) -> int:
    """``--network``: draw, run and write a network family's dataset and its layout."""
    from .road_networks import draw_network, generate_network, write_network_dataset

    if args.layout is None:
        print('mlkm sumo: error: --network needs --layout (the file to write)', file=sys.stderr)
        return 2
    unused = [
        f'--{name.replace("_", "-")}'
        for name in ('duration', 'stations_at', 'road')
        if getattr(args, name) is not None
    ]
    if unused:
        print(f'mlkm sumo: error: {", ".join(unused)} do not apply to --network', file=sys.stderr)
        return 2
    overrides = {}
    if args.vehicles is not None:
        overrides['vehicles'] = args.vehicles
    if args.flow is not None:
        overrides['flow'] = args.flow
    try:
        draw = draw_network(args.network, args.seed, **overrides)
        ds = generate_network(draw, args.cache_dir, measurement, args.step_length)
    except (SumoError, ValueError) as exc:
        print(f'mlkm sumo: error: {exc}', file=sys.stderr)
        return 2
    if len(ds) == 0:
        print(
            f'mlkm sumo: error: no detections in {args.network} seed {args.seed}', file=sys.stderr
        )
        return 2
    write_network_dataset(ds, args.output, args.layout)
    s = ds.stats
    print(
        f'{len(ds)} detections of {ds.n_targets} vehicles at {len(ds.mapping["stations"])} '
        f'stations on {len(ds.mapping["links"])} links -> {args.output}, layout -> '
        f'{args.layout}\n{draw.family} seed {draw.seed}: {s["simulated_s"]:.0f} s simulated in '
        f'{s["wall_s"]:.1f} s, {s["vehicles_inserted"]} vehicles inserted, {s["teleports"]} '
        'teleports'
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse printed the usage and the problem
        return int(exc.code or 0)
    if args.stations_at is not None and not args.stations_at:
        print('mlkm sumo: error: --stations-at names no position', file=sys.stderr)
        return 2
    try:
        measurement = _measurement(args)
    except ValueError as exc:
        print(f'mlkm sumo: error: {exc}', file=sys.stderr)
        return 2
    if args.network is not None:
        return _network(args, measurement)
    if args.layout is not None:
        print('mlkm sumo: error: --layout goes with --network', file=sys.stderr)
        return 2
    duration = args.duration
    if args.vehicles is None and duration is None:
        duration = DEFAULT_DURATION
    try:
        ds = generate(
            args.scenario,
            n_vehicles=args.vehicles,
            n_stations=args.stations,
            seed=args.seed,
            duration=duration,
            stations_at=args.stations_at,
            measurement=measurement,
            progress=sys.stderr.isatty(),
            cache_dir=args.cache_dir,
            step_length=args.step_length,
            flow=args.flow,
        )
    except (SumoError, ValueError) as exc:
        print(f'mlkm sumo: error: {exc}', file=sys.stderr)
        return 2
    if len(ds.detections) == 0:
        print(
            f'mlkm sumo: error: no detections in {ds.stats["simulated_s"]:.0f} s of '
            f'{args.scenario}; run longer or with more vehicles',
            file=sys.stderr,
        )
        return 2
    out = Path(args.output)
    write_csv(out, ds)
    if args.road:
        Path(args.road).write_text(json.dumps(road_json(ds), indent=1) + '\n')
    s = ds.stats
    kinds = ', '.join(
        f'{int(np.sum(ds.kind == k))} {name}s' for k, name in enumerate(KIND_NAMES) if k
    )
    print(
        f'{len(ds.detections)} detections of {ds.n_targets} vehicles at '
        f'{ds.layout.n_sensors} stations ({kinds}, {s["missed"]} missed) -> {out}\n'
        f'{args.scenario}: {s["simulated_s"]:.0f} s simulated in {s["wall_s"]:.1f} s, '
        f'{s["vehicles_inserted"]} vehicles inserted, {s["teleports"]} teleports'
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
