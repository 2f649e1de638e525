"""Writing detections to the product's CSV (the format ``mlkm_core.csvio`` reads).

One row per detection, sorted by stamp (ties by station), written atomically: a temporary
file in the same folder renamed into place, so that a reader never sees half a file.
"""

from __future__ import annotations

import csv
import os
import tempfile
from pathlib import Path

import numpy as np

from mlkm_core.csvio import LANE, LENGTH, REQUIRED, TRUTH
from mlkm_core.types import Detections, Layout

COLUMNS = (*REQUIRED, TRUTH, LANE, LENGTH)


def write_detections(
    path: str | Path,
    layout: Layout,
    det: Detections,
    decimals: tuple[int, int, int, int] = (3, 3, 3, 2),
) -> None:
    """Rows of ``det`` (with truth; lane -1 and length empty where unknown); ``decimals``
    of position_m, stamp_s, velocity_mps and length_m."""
    if det.target is None:
        raise ValueError('writing detections needs their ground truth (target)')
    dp, ds, dv, dl = decimals
    n = len(det)
    lane = det.lane if det.lane is not None else np.full(n, -1, np.int64)
    length = det.length if det.length is not None else np.full(n, np.nan)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.', suffix='.tmp')
    try:
        with os.fdopen(fd, 'w', newline='') as f:
            w = csv.writer(f)
            w.writerow(COLUMNS)
            for k in np.lexsort((det.sensor_index, det.stamp)):
                s = int(det.sensor_index[k])
                w.writerow(
                    [
                        int(layout.sensor_ids[s]),
                        f'{layout.positions[s]:.{dp}f}',
                        f'{det.stamp[k]:.{ds}f}',
                        f'{det.velocity[k]:.{dv}f}',
                        int(det.target[k]),
                        int(lane[k]),
                        '' if np.isnan(length[k]) else f'{length[k]:.{dl}f}',
                    ]
                )
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
