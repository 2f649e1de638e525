"""Writing the product's CSV (the format ``mlkm_core.csvio`` reads): detections, and an
input file's rows with their tracks (``write_tracks``).

One row per detection, sorted by stamp (ties by station), written atomically: a temporary
file in the same folder renamed into place, so that a reader never sees half a file. Rows are
formatted a chunk at a time (``CHUNK`` rows), so that a file of a million detections takes a
few seconds, and ``progress(rows_written)`` is called after each chunk.
"""

from __future__ import annotations

import csv
import os
import secrets
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from mlkm_core.csvio import (
    LANE,
    LENGTH,
    REJECTED,
    REQUIRED,
    TRACK,
    TRUTH,
    CsvDetections,
    InputError,
    Progress,
    Rows,
    file_signature,
)
from mlkm_core.types import Detections, Layout

COLUMNS = (*REQUIRED, TRUTH, LANE, LENGTH)
#: Line end: the csv module's (RFC 4180), as every file the product wrote before.
EOL = '\r\n'
#: Rows formatted and written at a time [rows].
CHUNK = 65_536


#: Decimals of position_m [m], stamp_s [s], velocity_mps [m/s] and length_m [m] by default.
DECIMALS = (3, 3, 3, 2)
#: Decimals of a station position (1 mm): a layout written beside the CSV rounds to it.
POSITION_DECIMALS = DECIMALS[0]


def write_detections(
    path: str | Path,
    layout: Layout,
    det: Detections,
    decimals: tuple[int, int, int, int] = DECIMALS,
    progress: Callable[[int], None] | None = None,
) -> None:
    """Rows of ``det`` (with truth; lane -1 and length empty where unknown); ``decimals``
    of position_m, stamp_s, velocity_mps and length_m; ``progress(rows_written)`` after each
    chunk."""
    if det.target is None:
        raise ValueError('writing detections needs their ground truth (target)')
    dp, ds, dv, dl = decimals
    n = len(det)
    lane = det.lane if det.lane is not None else np.full(n, -1, np.int64)
    length = det.length if det.length is not None else np.full(n, np.nan)
    row = f'%d,%.{dp}f,%.{ds}f,%.{dv}f,%d,%d,%s{EOL}'
    order = np.lexsort((det.sensor_index, det.stamp))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # a new name of our own ('x'), created with the umask's mode as any new file
    tmp = path.parent / f'.{path.name}.{secrets.token_hex(6)}.tmp'
    try:
        with open(tmp, 'x', newline='', encoding='utf-8') as f:
            f.write(','.join(COLUMNS) + EOL)
            for start in range(0, n, CHUNK):
                k = order[start : start + CHUNK]
                s = det.sensor_index[k]
                lengths = [
                    '' if x != x else f'{x:.{dl}f}'  # x != x: NaN, the length is unknown
                    for x in length[k].tolist()
                ]
                columns = (
                    layout.sensor_ids[s].tolist(),
                    layout.positions[s].tolist(),
                    det.stamp[k].tolist(),
                    det.velocity[k].tolist(),
                    det.target[k].tolist(),
                    lane[k].tolist(),
                    lengths,
                )
                f.write(''.join(map(row.__mod__, zip(*columns))))
                if progress is not None:
                    progress(min(start + CHUNK, n))
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_tracks(
    path: str | Path,
    data: CsvDetections,
    labels: np.ndarray,
    with_reasons: bool = False,
    progress: Progress | None = None,
) -> None:
    """Write every row of the input plus ``track_id`` (and ``rejected``), atomically.

    Invalid rows get track -1 and, with ``with_reasons``, their reason in ``rejected``
    (empty for the associated rows). Raises InputError when the input changed since it was
    read, OSError when the output cannot be written; no partial output is left behind.
    """
    path = Path(path)
    labels = np.asarray(labels, np.int64)
    if file_signature(data.path) != data.signature:
        raise InputError(f'{data.path}: the file changed while it was being associated')
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.', suffix='.tmp')
    rows = Rows(data.path)
    try:
        with os.fdopen(fd, 'w', newline='', encoding='utf-8') as f:
            w = csv.writer(f)
            rows.next()
            w.writerow([*data.header, TRACK, *([REJECTED] if with_reasons else [])])
            k = 0
            while (row := rows.next()) is not None:
                if not row or all(not c.strip() for c in row):
                    continue
                if k >= data.n_rows:
                    raise InputError(f'{data.path}: the file changed while it was being written')
                det = int(data.row_detection[k])
                out = [*row, int(labels[det]) if det >= 0 else -1]
                if with_reasons:
                    problem = data.problems.get(k)
                    out.append(problem.reason if problem else '')
                w.writerow(out)
                k += 1
                if progress is not None and k % 8192 == 0:
                    progress(k)
            if k != data.n_rows:
                raise InputError(f'{data.path}: the file changed while it was being written')
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    finally:
        rows.close()
