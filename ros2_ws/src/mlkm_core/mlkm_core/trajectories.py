"""Vehicle trajectories from files: the frames virtual loops are placed on (``mlkm_core.loops``).

Three formats, told apart by their first bytes and header:

- **trajectory CSV** (the format of the shipped NGSIM extract, ``.csv`` or ``.csv.gz``):
  ``vehicle_id,time_s,y_m,speed_mps,lane_id,length_m`` (any order, more columns ignored),
  SI units, ``lane_id`` counted from the left (1 = leftmost, as NGSIM counts; 0 or empty =
  unknown), an empty speed or length unknown;
- **NGSIM** as the program publishes it (``.csv``/``.txt``, comma- or whitespace-separated,
  with or without its header, whose names are matched without case since NGSIM's releases
  spell them differently, e.g. ``v_length``): ``Vehicle_ID``, ``Frame_ID`` (0.1 s frames),
  ``Local_Y`` [ft], ``v_Vel`` [ft/s], ``Lane_ID`` (1 = leftmost), ``v_Length`` [ft]. One
  location per file: vehicle ids repeat between NGSIM's locations;
- **SUMO FCD** (``--fcd-output``, XML): ``<timestep time>`` with ``<vehicle id x speed lane
  [length] [distance]>``; the position along the road is ``x`` (a straight road along x, as
  every network the product builds) or ``distance`` (``--fcd-output.distance``), the lane is
  the index at the end of the SUMO lane id (0 = rightmost). SUMO's FCD output has no
  vehicle length: a ``length`` attribute is read where a file has one (written by another
  tool), else the length is unknown.

Whatever the format, :class:`Trajectories` holds the frames sorted by vehicle and time, in
SI units, with the lane counted from the right (the product's convention,
``mlkm_core.types.Detections.lane``).
"""

from __future__ import annotations

import csv
import gzip
import io
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mlkm_core.types import UNKNOWN_LANE

FEET = 0.3048  # [m]
#: NGSIM's frame period [s].
NGSIM_FRAME = 0.1
#: Columns of the trajectory CSV.
CSV_COLUMNS = ('vehicle_id', 'time_s', 'y_m', 'speed_mps', 'lane_id', 'length_m')
#: NGSIM's columns, in the order of its published files (the product reads the ones it uses).
NGSIM_COLUMNS = (
    'Vehicle_ID', 'Frame_ID', 'Total_Frames', 'Global_Time', 'Local_X', 'Local_Y',
    'Global_X', 'Global_Y', 'v_Length', 'v_Width', 'v_Class', 'v_Vel', 'v_Acc', 'Lane_ID',
    'Preceding', 'Following', 'Space_Hdwy', 'Time_Hdwy',
)  # fmt: skip
NGSIM_USED = ('Vehicle_ID', 'Frame_ID', 'Local_Y', 'v_Vel', 'Lane_ID', 'v_Length')


class TrajectoryError(ValueError):
    """A trajectory file that cannot be read; the message names the file (and line)."""


@dataclass(frozen=True)
class Trajectories:
    """Frames of many vehicles, sorted by vehicle, then time."""

    vehicle: np.ndarray  # vehicle id [-]
    time: np.ndarray  # [s]
    position: np.ndarray  # along the road, in the direction of travel [m]
    speed: np.ndarray  # [m/s]
    lane: np.ndarray  # index from the right, UNKNOWN_LANE = unknown [-]
    length: np.ndarray  # vehicle length, NaN = unknown [m]

    @staticmethod
    def build(vehicle, time, position, speed, lane, length, line=None) -> Trajectories:
        """Sorted by (vehicle, time); raises TrajectoryError on no frames, on vehicle ids that
        are not whole numbers, on non-finite times or positions and on a vehicle seen twice at
        one time. ``line``: the source line of each frame, named in that last error."""
        raw = np.asarray(vehicle)
        if raw.size == 0:
            raise TrajectoryError('no frames')
        if raw.dtype.kind == 'f' and not np.all(np.isfinite(raw) & (raw == np.round(raw))):
            raise TrajectoryError('every vehicle id must be a whole number')
        v = raw.astype(np.int64)
        t = np.asarray(time, float)
        cols = [np.asarray(c, float) for c in (position, speed)]
        lane = np.asarray(lane, np.int64)
        length = np.asarray(length, float)
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(cols[0]))):
            raise TrajectoryError('every frame needs a finite time and position')
        order = np.lexsort((t, v))
        v, t = v[order], t[order]
        same = (v[1:] == v[:-1]) & (t[1:] == t[:-1])
        if np.any(same):
            i = int(np.flatnonzero(same)[0])
            lines = ''
            if line is not None:
                a, b = sorted(int(line[order[j]]) for j in (i, i + 1))
                lines = f' (lines {a} and {b})'
            raise TrajectoryError(f'vehicle {v[i]} has two frames at {t[i]:g} s{lines}')
        return Trajectories(v, t, cols[0][order], cols[1][order], lane[order], length[order])

    def __len__(self) -> int:
        return int(self.vehicle.size)

    @property
    def n_vehicles(self) -> int:
        return int(np.unique(self.vehicle).size)


def read_trajectories(
    path: str | Path, lanes: int | None = None, fcd_position: str = 'x'
) -> Trajectories:
    """Frames of ``path`` in any of the three formats (module docstring).

    ``lanes``: lanes of the road, to count NGSIM's left-based lane ids from the right
    (lane = lanes - lane_id); default the largest lane id in the file. ``fcd_position``:
    ``x`` or ``distance``, the FCD attribute that is the position along the road."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise TrajectoryError(f'{path}: {exc.strerror or exc}') from None
    if raw[:2] == b'\x1f\x8b':
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError) as exc:
            raise TrajectoryError(f'{path}: not a readable gzip file ({exc})') from None
    head = raw[:4096].lstrip()
    try:
        if head.startswith(b'<'):
            return _read_fcd(path, raw, fcd_position)
        text = raw.decode('utf-8-sig')
    except UnicodeDecodeError as exc:
        raise TrajectoryError(f'{path}: not UTF-8 text ({exc.reason})') from None
    first = [c.strip() for c in text.split('\n', 1)[0].split(',')]
    if CSV_COLUMNS[0] in first and 'frame_id' not in (c.lower() for c in first):
        return _read_csv(path, text, lanes)
    return _read_ngsim(path, text, lanes)


def _lanes_from_right(left: np.ndarray, lanes: int | None, path: Path) -> np.ndarray:
    known = left > 0
    if not np.any(known):
        return np.full(left.size, UNKNOWN_LANE, np.int64)
    n = int(left[known].max()) if lanes is None else lanes
    if int(left[known].max()) > n:
        raise TrajectoryError(f'{path}: lane id {int(left[known].max())} on a {n}-lane road')
    return np.where(known, n - left, UNKNOWN_LANE).astype(np.int64)


def _read_csv(path: Path, text: str, lanes: int | None) -> Trajectories:
    reader = csv.reader(io.StringIO(text))
    header = [c.strip() for c in next(reader)]
    missing = [c for c in CSV_COLUMNS if c not in header]
    if missing:
        raise TrajectoryError(f'{path}: missing column(s) {", ".join(missing)}')
    at = [header.index(c) for c in CSV_COLUMNS]
    rows, lines = [], []
    for line, row in enumerate(reader, start=2):
        if not row or not any(c.strip() for c in row):
            continue
        try:
            rows.append([float(row[i]) if row[i].strip() else math.nan for i in at])
        except (ValueError, IndexError):
            raise TrajectoryError(f'{path}, line {line}: not {len(header)} numbers') from None
        lines.append(line)
    a = np.array(rows, float).reshape(-1, len(CSV_COLUMNS))
    lane_id = np.nan_to_num(a[:, 4], nan=0).astype(np.int64)
    return _built(path, a[:, 0], a[:, 1], a[:, 2], a[:, 3], lane_id, a[:, 5], lanes, lines)


def _read_ngsim(path: Path, text: str, lanes: int | None) -> Trajectories:
    lines = [(n, ln) for n, ln in enumerate(text.splitlines(), start=1) if ln.strip()]
    if not lines:
        raise TrajectoryError(f'{path}: empty file')
    split = (lambda s: s.split(',')) if ',' in lines[0][1] else (lambda s: s.split())
    # matched without case: NGSIM's own releases spell some columns differently (v_length)
    first = [c.strip().lower() for c in split(lines[0][1])]
    if 'vehicle_id' in first:
        header, body = first, lines[1:]
    elif _numbers(first):
        header, body = [c.lower() for c in NGSIM_COLUMNS], lines
    else:
        raise TrajectoryError(
            f'{path}: neither a trajectory CSV ({",".join(CSV_COLUMNS)}) nor NGSIM '
            f'(Vehicle_ID, Frame_ID, Local_Y, v_Vel, Lane_ID, v_Length), nor SUMO FCD XML'
        )
    missing = [c for c in NGSIM_USED if c.lower() not in header]
    if missing:
        raise TrajectoryError(f'{path}: NGSIM file without column(s) {", ".join(missing)}')
    at = [header.index(c.lower()) for c in NGSIM_USED]
    rows = []
    for n, ln in body:
        cells = split(ln)
        try:
            rows.append([float(cells[i]) for i in at])
        except (ValueError, IndexError):
            raise TrajectoryError(f'{path}, line {n}: not an NGSIM row') from None
    a = np.array(rows, float).reshape(-1, len(NGSIM_USED))
    return _built(
        path, a[:, 0], a[:, 1] * NGSIM_FRAME, a[:, 2] * FEET, a[:, 3] * FEET,
        a[:, 4].astype(np.int64), a[:, 5] * FEET, lanes, [n for n, _ in body],
    )  # fmt: skip


def _numbers(cells: list[str]) -> bool:
    try:
        [float(c) for c in cells]
    except ValueError:
        return False
    return bool(cells)


def _built(path, vehicle, time, y, speed, lane_left, length, lanes, lines) -> Trajectories:
    try:
        return Trajectories.build(
            vehicle, time, y, speed, _lanes_from_right(lane_left, lanes, path), length, lines
        )
    except TrajectoryError as exc:
        raise TrajectoryError(f'{path}: {exc}') from None


_LANE_INDEX = re.compile(r'_(\d+)$')


def _read_fcd(path: Path, raw: bytes, position: str) -> Trajectories:
    if position not in ('x', 'distance'):
        raise TrajectoryError(f'fcd position must be x or distance, not {position!r}')
    ids: dict[str, int] = {}
    cols: list[list] = [[] for _ in range(6)]
    time = math.nan
    try:
        for event, el in ET.iterparse(io.BytesIO(raw), events=('start', 'end')):
            if event == 'start' and el.tag == 'timestep':
                time = float(el.get('time'))
            elif event == 'end' and el.tag == 'vehicle':
                pos = el.get(position)
                if pos is None:
                    raise TrajectoryError(
                        f'{path}: FCD vehicle without {position!r} '
                        '(SUMO writes distance with --fcd-output.distance)'
                    )
                match = _LANE_INDEX.search(el.get('lane') or '')
                length = el.get('length')
                for c, v in zip(
                    cols,
                    (
                        ids.setdefault(el.get('id'), len(ids)),
                        time,
                        float(pos),
                        float(el.get('speed')),
                        int(match.group(1)) if match else UNKNOWN_LANE,
                        float(length) if length is not None else math.nan,
                    ),
                    strict=True,
                ):
                    c.append(v)
                el.clear()
            elif event == 'end' and el.tag == 'timestep':
                el.clear()
    except TrajectoryError:
        raise
    except ET.ParseError as exc:
        raise TrajectoryError(f'{path}: not a SUMO FCD file ({exc})') from None
    except (TypeError, ValueError) as exc:
        raise TrajectoryError(f'{path}: FCD vehicle with a missing or bad value ({exc})') from None
    try:
        return Trajectories.build(*cols)
    except TrajectoryError as exc:
        raise TrajectoryError(f'{path}: {exc}') from None
