"""Cost growth: each method on 20 sensors with more and more targets, one fresh process per
point with one thread (OMP/BLAS/MKL = 1): runtime and peak memory of the association (peak
resident set above the level at its start, Linux ``clear_refs`` / ``VmHWM``). A method is
stopped at the first point that exceeds the time limit.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np

from .common import ONE_THREAD, Log

COST_TARGETS = (50, 150, 500, 1500, 5000, 10000)  # x 20 sensors = 1e3 .. 2e5 detections
COST_LIMIT = 45.0  # [s] per point

_COST_CHILD = r"""
import json, os, sys, time
import numpy as np
from mlkm_core.associators import make_associator
from mlkm_core.simulator import SimConfig, simulate
method, n_targets, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
ds = simulate(SimConfig(n_targets=n_targets, n_sensors=20), seed)
assoc = make_associator(method)
def status(key):
    with open('/proc/self/status') as f:
        for line in f:
            if line.startswith(key):
                return int(line.split()[1]) * 1024
    return 0
try:
    with open('/proc/self/clear_refs', 'w') as f:
        f.write('5')
    reset = True
except OSError:
    reset = False
base = status('VmRSS:')
t0 = time.perf_counter()
labels = assoc.associate(ds.layout, ds.detections, ds.n_targets)
sec = time.perf_counter() - t0
peak = status('VmHWM:')
print(json.dumps({'seconds': sec, 'peak_bytes': max(peak - base, 0), 'peak_reset': reset,
                  'detections': len(ds.detections)}))
"""


def run_cost(methods: list[str], targets: tuple[int, ...], limit: float, log: Log) -> dict:
    env = dict(os.environ, **ONE_THREAD)
    out: dict = {'sensors': 20, 'time_limit_s': limit, 'methods': {}}
    for m in methods:
        pts: list[dict] = []
        stopped = None
        for n in targets:
            try:
                res = subprocess.run(
                    [sys.executable, '-c', _COST_CHILD, m, str(n), '7'],
                    capture_output=True,
                    text=True,
                    timeout=limit + 30,
                    env=env,
                )
            except subprocess.TimeoutExpired:
                stopped = f'stopped: {n} targets ({20 * n} detections) exceeded {limit:.0f} s'
                break
            if res.returncode != 0:
                stopped = f'failed at {n} targets: {res.stderr.strip().splitlines()[-1:]}'
                break
            rec = json.loads(res.stdout.strip().splitlines()[-1])
            rec['targets'] = n
            pts.append(rec)
            log(
                f'cost {m:12s} {rec["detections"]:7d} det {rec["seconds"]:8.2f} s '
                f'{rec["peak_bytes"] / 2**20:8.1f} MiB'
            )
            if rec['seconds'] > limit:
                stopped = (
                    f'stopped after {n} targets ({rec["detections"]} detections): '
                    f'{rec["seconds"]:.0f} s > {limit:.0f} s'
                )
                break
        fit = _slope([p['detections'] for p in pts], [p['seconds'] for p in pts])
        mfit = _slope([p['detections'] for p in pts], [max(p['peak_bytes'], 1) for p in pts])
        out['methods'][m] = {
            'points': pts,
            'stopped': stopped,
            'time_slope': fit,
            'memory_slope': mfit,
        }
    return out


def _slope(x: list[float], y: list[float]) -> float | None:
    """Least-squares slope of log y on log x, over the points with >= 3e3 detections when
    there are at least two (fixed overheads dominate the smallest point)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    keep = x >= 3000
    if keep.sum() >= 2:
        x, y = x[keep], y[keep]
    if x.size < 2:
        return None
    return float(np.polyfit(np.log(x), np.log(np.maximum(y, 1e-9)), 1)[0])
