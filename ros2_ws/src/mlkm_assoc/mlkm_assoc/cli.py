"""``mlkm``: the offline command line (``associate``, ``paper``, ``bench``).

``mlkm associate --input detections.csv --output tracks.csv [--method M] [--segment-size K]
[--targets N] [--seed S]`` reads detections with the columns
``sensor_id,position_m,stamp_s,velocity_mps`` and optionally ``target_id`` (ground truth,
-1 = false alarm), associates them and writes the same rows with a ``track_id`` column
(-1 = unassigned). With ground truth it prints the accuracy and the other metrics. A malformed
file is rejected with a message naming the line, exit code 2, and nothing is written.

``mlkm paper`` reproduces the paper's experiments (see ``mlkm_experiments.paper``);
``mlkm bench ...`` hands its arguments to ``mlkm_experiments.bench.main``.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from mlkm_core.types import Detections, Layout

REQUIRED = ('sensor_id', 'position_m', 'stamp_s', 'velocity_mps')
TRUTH = 'target_id'


class InputError(ValueError):
    """A malformed input file; the message names the file and line."""


def read_detections(path: str | Path) -> tuple[Layout, Detections, list[dict], list[str]]:
    """Parse a detections CSV into (layout, detections, rows, header); raise InputError."""
    path = Path(path)
    try:
        f = open(path, newline='')
    except OSError as exc:
        raise InputError(f'{path}: cannot read: {exc.strerror}') from None
    with f:
        reader = csv.reader(f)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise InputError(
                f'{path}: line 1: empty file, expected a header {",".join(REQUIRED)}[,{TRUTH}]'
            ) from None
        except (csv.Error, UnicodeDecodeError) as exc:
            raise InputError(f'{path}: line 1: {exc}') from None
        missing = [c for c in REQUIRED if c not in header]
        if missing:
            raise InputError(
                f'{path}: line 1: missing column(s) {", ".join(missing)} '
                f'(header must contain {",".join(REQUIRED)}[,{TRUTH}])'
            )
        if len(set(header)) != len(header):
            raise InputError(f'{path}: line 1: duplicate column names')
        col = {name: header.index(name) for name in header}
        has_truth = TRUTH in col
        rows: list[dict] = []
        sensor, stamp, velocity, target = [], [], [], []
        position_of: dict[int, tuple[float, int]] = {}
        try:
            for row in reader:
                line = reader.line_num
                if not row or all(not c.strip() for c in row):
                    continue
                if len(row) != len(header):
                    raise InputError(
                        f'{path}: line {line}: expected {len(header)} fields, got {len(row)}'
                    )
                sid = _integer(row[col['sensor_id']], 'sensor_id', path, line, minimum=0)
                pos = _number(row[col['position_m']], 'position_m', path, line)
                t = _number(row[col['stamp_s']], 'stamp_s', path, line)
                v = _number(row[col['velocity_mps']], 'velocity_mps', path, line)
                if v <= 0:
                    raise InputError(f'{path}: line {line}: velocity_mps must be > 0, got {v}')
                if pos <= 0:
                    raise InputError(f'{path}: line {line}: position_m must be > 0, got {pos}')
                if sid in position_of and position_of[sid][0] != pos:
                    first_pos, first_line = position_of[sid]
                    raise InputError(
                        f'{path}: line {line}: sensor {sid} at position_m {pos}, but at '
                        f'{first_pos} on line {first_line}'
                    )
                position_of.setdefault(sid, (pos, line))
                if has_truth:
                    target.append(_integer(row[col[TRUTH]], TRUTH, path, line, minimum=-1))
                sensor.append(sid)
                stamp.append(t)
                velocity.append(v)
                rows.append(dict(zip(header, row)))
        except (csv.Error, UnicodeDecodeError) as exc:
            raise InputError(f'{path}: line {reader.line_num}: {exc}') from None
    if not rows:
        raise InputError(f'{path}: line 2: no detections after the header')
    ids = np.array(sorted(position_of, key=lambda s: position_of[s][0]), np.int64)
    pos = np.array([position_of[int(s)][0] for s in ids])
    dup = np.flatnonzero(np.diff(pos) == 0)
    if dup.size:
        a, b = int(ids[dup[0]]), int(ids[dup[0] + 1])
        raise InputError(
            f'{path}: line {position_of[b][1]}: sensors {a} and {b} share position_m {pos[dup[0]]}'
        )
    layout = Layout(float(pos[-1]) + 1.0, pos, ids)
    dets = Detections(
        layout.index_of(np.array(sensor)),
        np.array(stamp),
        np.array(velocity),
        np.array(target, np.int64) if has_truth else None,
    )
    return layout, dets, rows, header


def _number(text: str, name: str, path: Path, line: int) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(f'{path}: line {line}: {name} is not a number: {text!r}') from None
    if not math.isfinite(value):
        raise InputError(f'{path}: line {line}: {name} must be finite, got {text!r}')
    return value


def _integer(text: str, name: str, path: Path, line: int, minimum: int) -> int:
    try:
        value = int(text.strip())
    except ValueError:
        raise InputError(f'{path}: line {line}: {name} is not an integer: {text!r}') from None
    if value < minimum:
        raise InputError(f'{path}: line {line}: {name} must be >= {minimum}, got {value}')
    return value


def _write_atomic(path: Path, header: list[str], rows: list[dict], labels: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.', suffix='.tmp')
    try:
        with os.fdopen(fd, 'w', newline='') as f:
            w = csv.writer(f)
            w.writerow([*header, 'track_id'])
            for row, label in zip(rows, labels):
                w.writerow([*(row[h] for h in header), int(label)])
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def cmd_associate(args: argparse.Namespace) -> int:
    from mlkm_core.associators import AssociatorConfig, make_associator
    from mlkm_core.metrics import score

    try:
        layout, dets, rows, header = read_detections(args.input)
    except InputError as exc:
        print(f'mlkm associate: error: {exc}', file=sys.stderr)
        return 2
    if 'track_id' in header:
        print(
            f'mlkm associate: error: {args.input}: line 1: input already has a track_id column',
            file=sys.stderr,
        )
        return 2
    n_targets = args.targets or int(np.bincount(dets.sensor_index).max())
    try:
        associator = make_associator(
            args.method, AssociatorConfig(segment_size=args.segment_size, seed=args.seed)
        )
    except ValueError as exc:
        print(f'mlkm associate: error: {exc}', file=sys.stderr)
        return 2
    labels = associator.associate(layout, dets, n_targets)
    _write_atomic(Path(args.output), header, rows, labels)
    n_tracks = np.unique(labels[labels >= 0]).size
    print(
        f'{len(dets)} detections from {layout.n_sensors} sensors -> {n_tracks} tracks '
        f'({args.method}, {n_targets} targets) written to {args.output}'
    )
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


def cmd_paper(args: argparse.Namespace) -> int:
    from mlkm_experiments import paper

    return paper.main_args(
        args.datasets, args.out, args.jobs, args.dnn_datasets, args.segment_size
    )


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError('must be >= 1')
    return value


def build_parser() -> argparse.ArgumentParser:
    from mlkm_core.associators import AssociatorConfig, available_methods

    default_k = AssociatorConfig.segment_size
    parser = argparse.ArgumentParser(prog='mlkm', description=__doc__.split('\n\n')[0])
    sub = parser.add_subparsers(dest='command', required=True)
    a = sub.add_parser('associate', help='associate detections from a CSV file')
    a.add_argument(
        '--input', required=True, help='detections CSV: ' + ','.join(REQUIRED) + f'[,{TRUTH}]'
    )
    a.add_argument('--output', required=True, help='output CSV: the input plus track_id')
    a.add_argument(
        '--method', default='mlkm', choices=available_methods(), help='associator (default: mlkm)'
    )
    a.add_argument(
        '--segment-size',
        type=_positive,
        default=default_k,
        help=f'sensors per segment K (default: {default_k})',
    )
    a.add_argument(
        '--targets',
        type=_positive,
        default=None,
        help='number of targets (default: the largest per-sensor count)',
    )
    a.add_argument('--seed', type=int, default=0, help='random seed of the method')
    a.set_defaults(func=cmd_associate)
    p = sub.add_parser('paper', help="reproduce the paper's experiments")
    p.add_argument(
        '--datasets',
        type=_positive,
        default=100,
        help='seeded datasets per configuration (default: 100)',
    )
    p.add_argument(
        '--dnn-datasets',
        type=_positive,
        default=None,
        help='datasets per DNN split (default: min(datasets, 10))',
    )
    p.add_argument('--out', default='results/paper', help='output directory')
    p.add_argument('--jobs', type=_positive, default=2, help='worker processes (default: 2)')
    p.add_argument(
        '--segment-size',
        type=_positive,
        default=default_k,
        help=f'MLKM segment size K (default: {default_k})',
    )
    p.set_defaults(func=cmd_paper)
    sub.add_parser(
        'bench', help='benchmarks (arguments go to mlkm_experiments.bench)', add_help=False
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == 'bench':
        from mlkm_experiments import bench

        return int(bench.main(argv[1:]) or 0)
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == '__main__':
    sys.exit(main())
