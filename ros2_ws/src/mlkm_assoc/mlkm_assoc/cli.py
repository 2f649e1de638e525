"""``mlkm``: the offline command line (``associate``, and the commands other packages add).

``mlkm associate --input detections.csv --output tracks.csv [--method M] [--segment-size K]
[--targets N] [--seed S] [--entries X,..] [--exits X,..] [--skip-invalid] [--progress]``
reads detections (the format is described in ``mlkm_core.csvio``), associates them and writes
the same rows with a ``track_id`` column (-1 = unassigned). ``--entries`` / ``--exits`` are
the positions [m] of on- and off-ramps (``AssociatorConfig.entries`` / ``exits``). With ground
truth it prints the accuracy and the other metrics. A malformed file, or one with invalid
rows (values outside --min-speed/--max-speed/--min-stamp/--max-stamp, duplicates), is refused
with a message naming the lines, exit code 2, and nothing is written; ``--skip-invalid``
associates the valid rows instead and writes the invalid ones with track -1 and their reason
in a ``rejected`` column.

``--layout network.yaml`` reads the rows as stations of a road network and associates them
across its junctions (``mlkm_assoc.cli_network``).

``--stream [--lag S] [--entries X,..] [--exits X,..]`` associates as the live node does on
an open road: the rows are pushed in stamp order through ``mlkm_core.streaming`` (any
method; key = data row number), the committed labels are written, and the revision rate
(first-published links changed before their commit) and commit latency are printed.

Further subcommands come from the ``mlkm.commands`` entry points of the installed packages:
``mlkm loops`` (``mlkm_assoc.cli_loops``), ``mlkm simulate`` (``mlkm_assoc.cli_simulate``) and
``mlkm plot`` (``mlkm_assoc.cli_plot``: the time-space diagram of a tracks CSV or a bag, to
PNG) from this package, ``mlkm sumo`` from mlkm_sumo, ``mlkm paper`` and ``mlkm bench`` from
mlkm_experiments (``mlkm_experiments.commands``).
Each entry point ``name = module:function`` names a function that takes the arguments after
``mlkm <name>`` and returns the exit status; the first line of its docstring (else of its
module's) is its line in ``mlkm --help``. A Python warning raised while any subcommand runs
(a method's ``DegradedResultWarning``) prints as one line ``mlkm <command>: warning: ...``.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from mlkm_assoc.cli_network import associate as associate_on_network
from mlkm_assoc.cli_network import load_network, needs_network
from mlkm_assoc.cli_network import stream_config as network_stream_config
from mlkm_assoc.cli_plugins import (
    BUILTIN,
    one_line_warnings,
    plugin_commands,
    plugin_help,
)
from mlkm_assoc.cli_run import Progress, absolute, run_batch, run_stream
from mlkm_core.bounds import OFFLINE, Bounds
from mlkm_core.cli_args import finite_float, positive_int, seed
from mlkm_core.csvio import (
    ENCODING,
    LANE,
    LENGTH,
    MAX_LISTED,
    REJECTED,
    REQUIRED,
    TRUTH,
    InputError,
    InvalidRows,
)
from mlkm_core.csvio import read_detections as read_csv
from mlkm_core.csvout import write_tracks
from mlkm_core.types import Detections, Layout

#: Detections each method associates in well under a minute on one core (simulated data, 20
#: sensors; the timings are in docs/benchmarks.md#offline-cli-sizes, the growth of the cost
#: with the input in `mlkm bench --only cost`). Beyond COMFORT_FACTOR times this the CLI
#: suggests a faster method.
COMFORTABLE = {
    'assignment': 3_000_000,
    'multiframe': 3_000_000,
    'kmeans_p': 300_000,
    'kmeans_up': 300_000,
    'kmeans_pp': 100_000,
    'kmeans_pp_up': 150_000,
    'mlkm': 150_000,
    'mlkm_no_ec': 150_000,
    'mlkm_robust': 100_000,
}
COMFORT_FACTOR = 2
FAST = 'assignment'


def read_detections(path: str | Path) -> tuple[Layout, Detections, list[dict], list[str]]:
    """(layout, detections, rows as dicts, header) of a small, fully valid file."""
    data = read_csv(path)
    with open(data.path, newline='', encoding=ENCODING) as f:
        reader = csv.reader(f)
        next(reader)
        rows = [dict(zip(data.header, r)) for r in reader if r and any(c.strip() for c in r)]
    return data.layout, data.detections, rows, data.header


def _error(message: str) -> int:
    print(f'mlkm associate: error: {message}', file=sys.stderr)
    return 2


def _output_problem(output: Path, input_path: Path | None = None) -> str | None:
    """Why ``output`` cannot be written (or would overwrite ``input_path``), checked before
    any work is done; None if it can."""
    if output.is_dir():
        return f'{output}: --output is a directory; give a file name'
    try:
        if input_path and output.exists() and input_path.exists() and output.samefile(input_path):
            return f'{output}: --output is the input file; choose another name'
    except OSError:
        pass
    parent = output.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        return f'{output}: cannot create the output: {parent} is not a directory'
    if not os.access(parent, os.W_OK | os.X_OK):
        return f'{output}: cannot create the output: {parent} is not writable'
    return None


def _listing(problems) -> str:
    lines = [f'  line {p.line}: {p.message} [{p.reason}]' for p in problems[:MAX_LISTED]]
    if len(problems) > MAX_LISTED:
        lines.append(f'  ... and {len(problems) - MAX_LISTED} more')
    return '\n'.join(lines)


def cmd_associate(args: argparse.Namespace) -> int:
    from mlkm_core.associators import AssociatorConfig, make_associator
    from mlkm_core.metrics import score

    try:
        bounds = Bounds(args.min_speed, args.max_speed, args.min_stamp, args.max_stamp)
    except ValueError as exc:
        return _error(f'invalid bounds: {exc}')
    input_path, output = Path(args.input), Path(args.output)
    problem = _output_problem(output, input_path)
    if problem:
        return _error(problem)
    net = None
    try:
        if args.layout is not None:
            net, problem = load_network(args)
            if problem:
                return _error(problem)
            associator = None
            stream = network_stream_config(args) if args.stream else None
        elif needs_network(args.method):
            return _error(needs_network(args.method))
        else:
            config = AssociatorConfig(
                segment_size=args.segment_size,
                seed=args.seed,
                entries=args.entries,
                exits=args.exits,
            )
            associator = make_associator(args.method, config)
            stream = _stream_config(args) if args.stream else None
    except ValueError as exc:
        return _error(str(exc))
    progress = Progress(sys.stderr.isatty() if args.progress is None else args.progress)
    size = input_path.stat().st_size if input_path.is_file() else None
    bar = progress.bar('reading', total=size, unit='B', scale=True)
    failure = None
    try:
        data = read_csv(input_path, bounds, args.skip_invalid, absolute(bar), network=net)
    except InvalidRows as exc:
        n = len(exc.problems)
        failure = (
            f'{exc.path}: {n} invalid row{"s" if n != 1 else ""}; nothing was written. '
            'Correct or remove them, or pass --skip-invalid to associate the valid rows and '
            f'write these with track_id -1 and the reason in a {REJECTED} column:\n'
            + _listing(exc.problems)
        )
    except InputError as exc:
        failure = str(exc)
    finally:
        if bar is not None:
            bar.close()
    if failure:
        return _error(failure)
    dets = data.detections
    n_sensors = net.n_stations if net is not None else data.layout.n_sensors
    for name, like in data.unknown.items():
        if like is not None and like not in data.header:
            print(
                f'mlkm associate: warning: unknown column {name!r} is not read (copied to the '
                f'output); did you mean {like}?',
                file=sys.stderr,
            )
    rejected = [data.problems[k] for k in sorted(data.problems)]
    if rejected:
        print(
            f'mlkm associate: warning: {len(rejected)} invalid row(s) skipped, written with '
            f'track_id -1 and the reason in the {REJECTED} column:\n{_listing(rejected)}',
            file=sys.stderr,
        )
    comfortable = COMFORTABLE.get(args.method)
    if comfortable and len(dets) > COMFORT_FACTOR * comfortable:
        print(
            f'mlkm associate: warning: {len(dets)} detections is far beyond what {args.method} '
            f'handles in about a minute ({comfortable}); this can take very long. '
            f'--method {FAST} is much faster.',
            file=sys.stderr,
        )
    n_targets = args.targets or int(np.bincount(dets.sensor_index).max())
    t0 = time.perf_counter()
    try:
        if stream is not None:
            streamed = run_stream(data, stream, args.entries, args.exits, progress, net)
            labels = streamed.labels
        elif net is not None:
            labels = associate_on_network(net, dets, args.method, args.seed)
        else:
            labels = run_batch(associator, data, n_targets, progress)
    except ValueError as exc:
        return _error(f'{args.method} cannot associate this input: {exc}')
    elapsed = time.perf_counter() - t0
    bar = progress.bar('writing', total=data.n_rows, unit='row', scale=True)
    try:
        write_tracks(output, data, labels, args.skip_invalid, absolute(bar))
    except InputError as exc:
        failure = f'{exc}; nothing was written'
    except OSError as exc:
        failure = f'{output}: cannot write: {exc.strerror or exc}'
    finally:
        if bar is not None:
            bar.close()
    if failure:
        return _error(failure)
    n_tracks = np.unique(labels[labels >= 0]).size
    mode = f'stream, lag {stream.lag:g} s' if stream else f'{n_targets} targets'
    if net is not None:
        mode = f'road network of {len(net.links)} links' + (
            f', stream, lag {streamed.stats["lag"]:.0f} s' if stream else ''
        )
    print(
        f'{len(dets)} detections from {n_sensors} sensors -> {n_tracks} tracks '
        f'({args.method}, {mode}, {elapsed:.1f} s) written to {args.output}'
        + (f'; {len(rejected)} invalid rows written as rejected' if rejected else '')
    )
    if stream is not None:
        _print_stream(streamed)
    if dets.target is not None:
        s = score(dets, labels)
        print(f'accuracy: {100 * s.accuracy:.2f} % ({s.correct}/{s.total})')
        print(
            f'link precision: {100 * s.link_precision:.2f} %  '
            f'link recall: {100 * s.link_recall:.2f} %  '
            f'identity switches: {s.identity_switches}  '
            f'adjusted Rand index: {s.adjusted_rand_index:.4f}'
        )
    return 0


def _stream_config(args: argparse.Namespace):
    from mlkm_core.streaming import StreamConfig

    return StreamConfig(
        method=args.method, lag=args.lag, segment_size=args.segment_size, seed=args.seed
    )


def _print_stream(result) -> None:
    st = result.stats
    print(
        f'revision rate: {100 * st["revision_rate"]:.2f} % ({st["revised"]} of '
        f'{st["committed"]} first-published links changed before their commit)'
    )
    waited = result.latency[np.isfinite(result.latency)]
    if waited.size:
        print(
            f'commit latency (stamp time): median {np.median(waited):.1f} s, '
            f'max {waited.max():.1f} s; {st["false_alarms"]} false alarms, '
            f'{st["final_tracks"]} tracks'
        )


def _positions(text: str) -> tuple[float, ...]:
    values = tuple(finite_float(x) for x in text.split(',') if x.strip())
    if any(v < 0 for v in values):
        raise argparse.ArgumentTypeError('positions must be >= 0')
    return values


def build_parser() -> argparse.ArgumentParser:
    from mlkm_core.associators import AssociatorConfig, available_methods
    from mlkm_core.network_assoc import NETWORK_METHODS

    default_k = AssociatorConfig.segment_size
    parser = argparse.ArgumentParser(prog='mlkm', description=__doc__.split('\n\n')[0])
    sub = parser.add_subparsers(dest='command', required=True)
    a = sub.add_parser('associate', help='associate detections from a CSV file')
    a.add_argument(
        '--input',
        required=True,
        help='detections CSV: ' + ','.join(REQUIRED) + f'[,{TRUTH}][,{LANE}][,{LENGTH}]',
    )
    a.add_argument('--output', required=True, help='output CSV: the input plus track_id')
    a.add_argument(
        '--method',
        default='mlkm',
        choices=sorted({*available_methods(), *NETWORK_METHODS}),
        help='associator (default: mlkm; with --layout one of the network methods: '
        + ', '.join(sorted(NETWORK_METHODS))
        + ')',
    )
    a.add_argument(
        '--segment-size',
        type=positive_int,
        default=default_k,
        help=f'sensors per segment K (default: {default_k})',
    )
    a.add_argument(
        '--targets',
        type=positive_int,
        default=None,
        help='number of targets (default: the largest per-sensor count)',
    )
    a.add_argument(
        '--seed', type=seed, default=0, help='random seed of the method, 0 to 2^32-1 (default: 0)'
    )
    bounds = OFFLINE
    for flag, value, what in (
        ('--min-speed', bounds.min_speed, 'slowest accepted velocity [m/s]'),
        ('--max-speed', bounds.max_speed, 'fastest accepted velocity [m/s]'),
        ('--min-stamp', bounds.min_stamp, 'earliest accepted stamp [s]'),
        ('--max-stamp', bounds.max_stamp, 'latest accepted stamp [s]'),
    ):
        a.add_argument(flag, type=finite_float, default=value, help=f'{what} (default: {value:g})')
    a.add_argument(
        '--skip-invalid',
        action='store_true',
        help='associate the valid rows and write the invalid ones (bad values, duplicates) '
        f'with track_id -1 and the reason in a {REJECTED} column; without it an invalid row '
        'refuses the whole file (exit 2, the rows listed)',
    )
    a.add_argument(
        '--progress',
        action=argparse.BooleanOptionalAction,
        default=None,
        help='progress bars on stderr (default: only when stderr is a terminal)',
    )
    from mlkm_core.streaming import StreamConfig

    a.add_argument(
        '--stream',
        action='store_true',
        help='associate as a stream (pushes in stamp order, links committed after --lag; '
        'the number of targets of each window is its largest per-sensor count, not --targets)',
    )
    a.add_argument(
        '--lag',
        type=finite_float,
        default=StreamConfig.lag,
        help=f'with --stream: stamp time [s] a link may still be revised (default: '
        f'{StreamConfig.lag:g})',
    )
    for flag, what in (('--entries', 'on-ramps'), ('--exits', 'off-ramps')):
        a.add_argument(
            flag,
            type=_positions,
            default=(),
            help=f'positions [m] of {what} between stations, comma-separated (an open road: '
            'the batch associators and --stream use them)',
        )
    a.add_argument(
        '--layout',
        default=None,
        help='a network layout file (YAML, links: form): the rows are stations of that road '
        'network, associated across its junctions (--method assignment or gmlkm)',
    )
    a.set_defaults(func=cmd_associate)
    for name, entry in sorted(plugin_commands().items()):
        # their own parsers read their arguments (and --help): main() hands argv over
        sub.add_parser(name, help=plugin_help(entry), add_help=False)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = argv[0] if argv and not argv[0].startswith('-') else ''
    previous = warnings.showwarning
    warnings.showwarning = one_line_warnings(f'mlkm {command}'.strip())
    try:
        if argv and argv[0] not in BUILTIN:
            entry = plugin_commands().get(argv[0])
            if entry is not None:
                return int(entry.load()(argv[1:]) or 0)
        args = build_parser().parse_args(argv)
        return int(args.func(args))
    finally:
        warnings.showwarning = previous


if __name__ == '__main__':
    sys.exit(main())
