"""Writing detections to the product's CSV (the format ``mlkm_core.csvio`` reads).

One row per detection, sorted by stamp (ties by station), written atomically: a temporary
file in the same folder renamed into place, so that a reader never sees half a file. Rows are
formatted a chunk at a time (``CHUNK`` rows), so that a file of a million detections takes a
few seconds, and ``progress(rows_written)`` is called after each chunk.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from pathlib import Path

import numpy as np

from mlkm_core.csvio import LANE, LENGTH, REQUIRED, TRUTH
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
