"""Detections CSV files: strict reading with line-precise errors.

A file has a header with the columns ``sensor_id,position_m,stamp_s,velocity_mps`` and
optionally ``target_id`` (ground truth, -1 = false alarm), ``lane`` (index from the right,
-1 or empty = unknown) and ``length_m`` (vehicle length [m], empty or ``nan`` = unknown), in
any order. Other columns are copied to the output untouched; one whose name is close to a
known one is likely a typo and is named in the error when a required column is missing
(``unknown column 'velocty_mps'``), else in ``CsvDetections.unknown``. Blank lines are
ignored. A file's stamps are not ROS times: negative seconds (relative to an event) are
fine (the default bounds are :data:`~mlkm_core.bounds.OFFLINE`); positions lie on the road,
>= 0.

Two kinds of problems:

- The file's structure is wrong (header, field count, encoding, a sensor at two positions,
  two sensors at one position): :class:`InputError` at once, naming the line.
- A row is invalid (a field that is not a number, a value outside the physical
  :class:`~mlkm_core.bounds.Bounds`, a duplicate of an earlier row by
  :func:`~mlkm_core.types.duplicate_key`: same sensor, lane and stamp, and with the lane
  unknown the same velocity too): every such row is collected as a :class:`RowProblem`.
  By default the file is refused with :class:`InvalidRows` (all of them counted, the first
  ``MAX_LISTED`` listed); with ``skip_invalid`` the valid rows are associated and the
  invalid ones are written back with track -1 and their reason, so that nothing is lost.

The rows themselves are not kept in memory: :func:`mlkm_core.csvout.write_tracks` reads the
input again and copies each row verbatim, after checking that the file has not changed in
between.
"""

from __future__ import annotations

import csv
import difflib
import io
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mlkm_core.bounds import OFFLINE, Bounds
from mlkm_core.network import RoadNetwork
from mlkm_core.network_csv import position_problem, station_indexes
from mlkm_core.types import UNKNOWN_LANE, Detections, Layout, duplicate_key

REQUIRED = ('sensor_id', 'position_m', 'stamp_s', 'velocity_mps')
TRUTH = 'target_id'
LANE = 'lane'
LENGTH = 'length_m'
OPTIONAL = (TRUTH, LANE, LENGTH)
KNOWN = (*REQUIRED, *OPTIONAL)
TRACK = 'track_id'
REJECTED = 'rejected'
#: Reasons of an invalid row beside the physical ones of ``mlkm_core.bounds.REASONS``.
ROW_REASONS = ('malformed', 'duplicate')
#: How many invalid rows an error message lists (all are counted).
MAX_LISTED = 20
ENCODING = 'utf-8-sig'  # UTF-8, with or without a byte order mark

#: Called as progress(bytes_read) while reading and progress(rows_written) while writing.
Progress = Callable[[int], None]


class InputError(ValueError):
    """A malformed input file; the message names the file and line."""


@dataclass(frozen=True)
class RowProblem:
    line: int  # 1-based line of the file
    reason: str  # one of bounds.REASONS or ROW_REASONS
    message: str  # for users: the field, the value and what is expected


class InvalidRows(InputError):
    """Rows of a file that cannot be associated; ``problems`` holds all of them."""

    def __init__(self, path: Path, problems: list[RowProblem]) -> None:
        self.path = path
        self.problems = problems
        n = len(problems)
        lines = [f'{path}: {n} invalid row{"s" if n != 1 else ""}:']
        lines += [f'  line {p.line}: {p.message}' for p in problems[:MAX_LISTED]]
        if n > MAX_LISTED:
            lines.append(f'  ... and {n - MAX_LISTED} more')
        super().__init__('\n'.join(lines))


@dataclass
class CsvDetections:
    """What :func:`read_detections` found in a file."""

    path: Path
    header: list[str]
    layout: Layout | None  # None on a road network (its stations are the network's)
    detections: Detections  # the valid rows, in file order
    row_detection: np.ndarray  # per data row: its index in ``detections``, or -1 if invalid
    problems: dict[int, RowProblem] = field(default_factory=dict)  # data row -> problem
    signature: tuple[int, int] = (0, 0)  # (size, mtime_ns) of the file when read
    # other columns (copied to the output) -> the known column each resembles, or None
    unknown: dict[str, str | None] = field(default_factory=dict)
    track: np.ndarray | None = None  # tracks=True: per detection, its track_id (-1 = none)

    @property
    def n_rows(self) -> int:
        return int(self.row_detection.size)


def file_signature(path: Path) -> tuple[int, int]:
    """(size, mtime_ns) of a file: whether it changed since it was read."""
    st = path.stat()
    return st.st_size, st.st_mtime_ns


def _utf8_error_line(path: Path) -> str:
    """Where the first byte sequence that is not UTF-8 sits: 'line L: ...'."""
    with open(path, 'rb') as f:
        for number, raw in enumerate(f, start=1):
            try:
                raw.decode(ENCODING if number == 1 else 'utf-8')
            except UnicodeDecodeError as exc:
                return (
                    f'line {number}: not UTF-8 text (byte 0x{raw[exc.start]:02x} '
                    f'at column {exc.start + 1})'
                )
    return 'line 1: not UTF-8 text'


class Rows:
    """csv rows of a file with their line numbers; decoding errors name the real line."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self._raw = open(path, 'rb')  # noqa: SIM115  (closed by close())
        except OSError as exc:
            raise InputError(f'{path}: cannot read: {exc.strerror}') from None
        self._text = io.TextIOWrapper(self._raw, encoding=ENCODING, newline='')
        self._reader = csv.reader(self._text)

    def close(self) -> None:
        self._text.close()

    @property
    def line(self) -> int:
        return self._reader.line_num

    @property
    def bytes_read(self) -> int:
        return self._raw.tell()

    def next(self) -> list[str] | None:
        try:
            return next(self._reader)
        except StopIteration:
            return None
        except UnicodeDecodeError:
            raise InputError(f'{self.path}: {_utf8_error_line(self.path)}') from None
        except csv.Error as exc:
            raise InputError(f'{self.path}: line {self._reader.line_num}: {exc}') from None


class _Bad(Exception):
    """One field of a row cannot be used; carries the problem."""

    def __init__(self, reason: str, message: str) -> None:
        self.reason = reason
        self.message = message


def _float(text: str, name: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise _Bad('malformed', f'{name} is not a number: {text!r}') from None


def _int(text: str, name: str, minimum: int) -> int:
    try:
        value = int(text.strip())
    except ValueError:
        raise _Bad('malformed', f'{name} is not an integer: {text!r}') from None
    if not minimum <= value < 2**63:
        raise _Bad('malformed', f'{name} must be in [{minimum}, 2^63), got {value}')
    return value


def _velocity_message(reason: str, v: float, bounds: Bounds) -> str:
    if reason in ('zero_velocity', 'negative_velocity'):
        return f'velocity_mps must be > 0, got {v!r}'
    if reason == 'speed_out_of_range':
        return (
            f'velocity_mps {v!r} is outside [{bounds.min_speed:g}, {bounds.max_speed:g}] m/s '
            '(--min-speed/--max-speed)'
        )
    return f'velocity_mps must be finite, got {v!r}'


def _read_header(rows: Rows, tracks: bool = False) -> list[str]:
    first = rows.next()
    expected = f'{",".join(REQUIRED)}[,{TRUTH}][,{LANE}][,{LENGTH}]'
    if first is None:
        raise InputError(f'{rows.path}: line 1: empty file, expected a header {expected}')
    header = [h.strip() for h in first]
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        unknown = _unknown_columns(header)
        named = ''.join(
            f'; unknown column {name!r}' + (f' (did you mean {like}?)' if like else '')
            for name, like in unknown.items()
        )
        raise InputError(
            f'{rows.path}: line 1: missing column(s) {", ".join(missing)}{named} '
            f'(header must contain {expected})'
        )
    if len(set(header)) != len(header):
        raise InputError(f'{rows.path}: line 1: duplicate column names')
    if TRACK in header and not tracks:
        raise InputError(f'{rows.path}: line 1: input already has a {TRACK} column')
    return header


def _unknown_columns(header: list[str]) -> dict[str, str | None]:
    """Each column that is not a known one -> the known column it resembles (a likely typo:
    'velocty_mps' -> 'velocity_mps'), or None."""
    return {
        name: next(iter(difflib.get_close_matches(name, KNOWN, n=1, cutoff=0.8)), None)
        for name in header
        if name not in KNOWN
    }


def read_detections(
    path: str | Path,
    bounds: Bounds | None = None,
    skip_invalid: bool = False,
    progress: Progress | None = None,
    tracks: bool = False,
    network: RoadNetwork | None = None,
) -> CsvDetections:
    """Parse a detections CSV; raise InputError (structure) or InvalidRows (rows).

    With ``network`` the rows' stations are that road network's (``mlkm_core.network_csv``):
    ``Detections.sensor_index`` indexes its station arrays and ``CsvDetections.layout`` is
    None; without it the positions of the file make a single road.

    With ``skip_invalid`` the invalid rows are returned in ``problems`` instead, as long as
    at least one row is valid. With ``tracks`` the file is a tracks CSV (what
    :func:`mlkm_core.csvout.write_tracks` writes): its ``track_id`` column, required, is read
    into ``CsvDetections.track``; a value that is not an integer >= -1 is an InputError.
    """
    path = Path(path)
    bounds = bounds or OFFLINE
    rows = Rows(path)
    try:
        signature = file_signature(path)
        header = _read_header(rows, tracks)
        if tracks and TRACK not in header:
            raise InputError(
                f'{path}: line 1: no {TRACK} column: not a tracks CSV (mlkm associate '
                '--output writes one)'
            )
        i_track = header.index(TRACK) if tracks else None
        width = len(header)
        i_sid, i_pos = header.index('sensor_id'), header.index('position_m')
        i_t, i_v = header.index('stamp_s'), header.index('velocity_mps')
        i_truth = header.index(TRUTH) if TRUTH in header else None
        i_lane = header.index(LANE) if LANE in header else None
        i_len = header.index(LENGTH) if LENGTH in header else None
        sensor, stamp, velocity, target, lane, length, line_of = [], [], [], [], [], [], []
        track: list[int] = []
        tie: list[float] = []  # the last element of each valid row's duplicate_key
        row_detection: list[int] = []
        problems: dict[int, RowProblem] = {}
        position_of: dict[int, tuple[float, int]] = {}
        while (row := rows.next()) is not None:
            line = rows.line
            if not row or all(not c.strip() for c in row):
                continue
            if progress is not None and len(row_detection) % 8192 == 0:
                progress(rows.bytes_read)
            if len(row) != width:
                raise InputError(f'{path}: line {line}: expected {width} fields, got {len(row)}')
            if i_track is not None:
                try:
                    track.append(_int(row[i_track], TRACK, -1))
                except _Bad as bad:
                    raise InputError(f'{path}: line {line}: {bad.message}') from None
            try:
                sid = _int(row[i_sid], 'sensor_id', 0)
                pos = _float(row[i_pos], 'position_m')
                if not math.isfinite(pos) or pos < 0:
                    raise InputError(
                        f'{path}: line {line}: position_m must be >= 0 (on the road) and '
                        f'finite, got {pos}'
                    )
                first = position_of.setdefault(sid, (pos, line))
                if first[0] != pos:
                    raise InputError(
                        f'{path}: line {line}: sensor {sid} at position_m {pos}, but at '
                        f'{first[0]} on line {first[1]}'
                    )
                t = _float(row[i_t], 'stamp_s')
                v = _float(row[i_v], 'velocity_mps')
                reason = bounds.refuse(t, v)
                if reason == 'stamp_out_of_range' and not math.isfinite(t):
                    raise _Bad(reason, f'stamp_s must be finite, got {row[i_t].strip()}')
                if reason == 'stamp_out_of_range':
                    raise _Bad(
                        reason,
                        f'stamp_s {row[i_t].strip()} is outside [{bounds.min_stamp:g}, '
                        f'{bounds.max_stamp:g}] s (--min-stamp/--max-stamp)',
                    )
                if reason is not None:
                    raise _Bad(reason, _velocity_message(reason, v, bounds))
                g = _int(row[i_truth], TRUTH, -1) if i_truth is not None else -1
                ln = UNKNOWN_LANE
                if i_lane is not None and row[i_lane].strip():
                    ln = _int(row[i_lane], LANE, UNKNOWN_LANE)
                size = math.nan
                if i_len is not None and row[i_len].strip():
                    size = _float(row[i_len], LENGTH)
                    if not (math.isnan(size) or 0 < size < math.inf):
                        raise _Bad('malformed', f'{LENGTH} must be > 0 or nan, got {size!r}')
            except _Bad as bad:
                problems[len(row_detection)] = RowProblem(line, bad.reason, bad.message)
                row_detection.append(-1)
                continue
            row_detection.append(len(sensor))
            tie.append(duplicate_key(sid, ln, t, v)[3])
            sensor.append(sid)
            stamp.append(t)
            velocity.append(v)
            target.append(g)
            lane.append(ln)
            length.append(size)
            line_of.append(line)
        if progress is not None:
            progress(rows.bytes_read)
    finally:
        rows.close()
    if not row_detection:
        raise InputError(f'{path}: line 2: no detections after the header')
    row_of = np.flatnonzero(np.array(row_detection) >= 0)
    det_of_row = np.array(row_detection, np.int64)
    dups = _duplicates(np.array(sensor, np.int64), np.array(lane), np.array(stamp), np.array(tie))
    for k, first_k in dups:
        same = (
            'sensor_id, stamp_s and velocity_mps, lane unknown'
            if lane[k] == UNKNOWN_LANE
            else 'sensor_id, lane and stamp_s'
        )
        problems[int(row_of[k])] = RowProblem(
            line_of[k], 'duplicate', f'duplicate of line {line_of[first_k]} (same {same})'
        )
        det_of_row[row_of[k]] = -1
    keep = np.flatnonzero(det_of_row >= 0)
    valid_dets = det_of_row[keep]
    det_of_row[keep] = np.arange(keep.size)
    layout = _layout(path, position_of) if position_of and network is None else None
    misplaced = None if network is None else position_problem(path, network, position_of)
    if misplaced:
        raise InputError(misplaced)
    if problems and (not skip_invalid or not keep.size):
        raise InvalidRows(path, [problems[k] for k in sorted(problems)])
    ids = np.array(sensor, np.int64)[valid_dets]
    dets = Detections(
        _index(layout, ids) if network is None else station_indexes(network, ids),
        np.array(stamp)[valid_dets],
        np.array(velocity)[valid_dets],
        np.array(target, np.int64)[valid_dets] if i_truth is not None else None,
        np.array(lane, np.int64)[valid_dets] if i_lane is not None else None,
        np.array(length)[valid_dets] if i_len is not None else None,
    )
    labels = np.array(track, np.int64)[row_of[valid_dets]] if tracks else None
    return CsvDetections(
        path,
        header,
        layout,
        dets,
        det_of_row,
        problems,
        signature,
        _unknown_columns(header),
        labels,
    )


def _duplicates(
    sensor: np.ndarray, lane: np.ndarray, stamp: np.ndarray, tie: np.ndarray
) -> list[tuple[int, int]]:
    """(index, index of its first occurrence) of every repeated
    :func:`~mlkm_core.types.duplicate_key` (sensor, lane, stamp, tie), grouped in arrays."""
    if sensor.size < 2:
        return []
    order = np.lexsort((np.arange(sensor.size), tie, stamp, lane, sensor))
    s, ln, t, x = sensor[order], lane[order], stamp[order], tie[order]
    same = (s[1:] == s[:-1]) & (ln[1:] == ln[:-1]) & (t[1:] == t[:-1]) & (x[1:] == x[:-1])
    if not same.any():
        return []
    starts = np.concatenate([[True], ~same])
    first = order[np.maximum.accumulate(np.where(starts, np.arange(order.size), 0))]
    dup = np.flatnonzero(~starts)
    return sorted(zip(order[dup].tolist(), first[dup].tolist(), strict=True))


def _layout(path: Path, position_of: dict[int, tuple[float, int]]) -> Layout:
    ids = np.array(sorted(position_of, key=lambda s: position_of[s][0]), np.int64)
    pos = np.array([position_of[int(s)][0] for s in ids])
    dup = np.flatnonzero(np.diff(pos) == 0)
    if dup.size:
        a, b = int(ids[dup[0]]), int(ids[dup[0] + 1])
        raise InputError(
            f'{path}: line {position_of[b][1]}: sensors {a} and {b} share position_m '
            f'{pos[dup[0]]} (stations of a road network: give its layout file, --layout)'
        )
    return Layout(float(pos[-1]) + 1.0, pos, ids)


def _index(layout: Layout, ids: np.ndarray) -> np.ndarray:
    """Layout index of each sensor id (every id is in the layout)."""
    by_id = np.argsort(layout.sensor_ids)
    return by_id[np.searchsorted(layout.sensor_ids[by_id], ids)]
