"""``mlkm bench``: accuracy grid, cost growth, Stone Soup side by side, live throughput.

Writes ``<out>/grid.json``, ``cost.json``, ``peer.json``, ``live.json``, ``summary.json``
(issue 4, section 5 targets: met or not, with the values), PNG plots and ``README.md``.
Never part of ``make test``. ``--quick`` runs a small version (for a smoke check).

* Accuracy grid: every registered method on (targets, sensors) in (10,10), (50,20), (200,50),
  (1000,100), in paper mode (the simulator's defaults) and clutter mode (5% misses, 0.05 false
  alarms per target per sensor, 0.2 s stamp noise, 0.5 m/s speed noise); the same seeded
  datasets for every method. Each (method, cell, mode) runs in a child process with a time
  budget; a method that exceeds it is stopped and the JSON/README say after how many datasets.
* Cost growth: each method on 20 sensors with 50 .. 10000 targets (1e3 .. 2e5 detections),
  one fresh process per point with one thread (OMP/BLAS/MKL = 1), runtime and peak memory of
  the association (peak resident set above the level at its start, Linux ``clear_refs`` /
  ``VmHWM``); a method is stopped at the first point that exceeds the time limit.
* Peer: Stone Soup (PyPI ``stonesoup``, installed into the running venv on demand, never a
  dependency of the nodes) on the first datasets of the 10/10 and 50/20 cells of both modes.
* Live: ``scripts/bench_live.py`` (association node vs a bare rclpy subscriber), when present.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import multiprocessing as mp
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mlkm_core.associators import available_methods, make_associator
from mlkm_core.metrics import score
from mlkm_core.simulator import SimConfig, simulate
from mlkm_core.types import Dataset, Detections, Layout

CLUTTER = dict(miss_probability=0.05, false_alarm_rate=0.05, stamp_noise=0.2, velocity_noise=0.5)
MODES = ('paper', 'clutter')
CELLS = ((10, 10), (50, 20), (200, 50), (1000, 100))
SEEDS_FULL = {(10, 10): 40, (50, 20): 30, (200, 50): 8, (1000, 100): 2}
SEEDS_QUICK = {(10, 10): 4, (50, 20): 3, (200, 50): 1, (1000, 100): 1}
# time budget [s] of one (method, cell, mode): all its datasets
BUDGET = {(10, 10): 60.0, (50, 20): 120.0, (200, 50): 150.0, (1000, 100): 120.0}
COST_TARGETS = (50, 150, 500, 1500, 5000, 10000)  # x 20 sensors = 1e3 .. 2e5 detections
COST_LIMIT = 45.0  # [s] per point
PEER_SEEDS = {(10, 10): 10, (50, 20): 5}
BEST = 'multiframe'
BASELINE = 'assignment'
ONE_THREAD = {
    'OMP_NUM_THREADS': '1',
    'OPENBLAS_NUM_THREADS': '1',
    'MKL_NUM_THREADS': '1',
    'NUMEXPR_NUM_THREADS': '1',
    'VECLIB_MAXIMUM_THREADS': '1',
}


def sim_config(mode: str, n_targets: int, n_sensors: int) -> SimConfig:
    extra = CLUTTER if mode == 'clutter' else {}
    return SimConfig(n_targets=n_targets, n_sensors=n_sensors, **extra)


def dataset_seed(n_targets: int, n_sensors: int, k: int) -> int:
    return 1000 * n_targets + 10 * n_sensors + k  # distinct per cell, same for every method


def _score_row(ds: Dataset, labels: np.ndarray, seconds: float) -> dict:
    s = score(ds.detections, labels)
    row = asdict(s)
    row['seconds'] = seconds
    row['detections'] = len(ds.detections)
    return {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in row.items()}


# ----------------------------------------------------------------------------- grid


def _grid_child(method: str, mode: str, cell: tuple[int, int], seeds: list[int], conn) -> None:
    for k, v in ONE_THREAD.items():
        os.environ.setdefault(k, v)
    assoc = make_associator(method)
    for seed in seeds:
        ds = simulate(sim_config(mode, *cell), seed)
        t0 = time.perf_counter()
        labels = assoc.associate(ds.layout, ds.detections, ds.n_targets)
        conn.send(_score_row(ds, labels, time.perf_counter() - t0))
    conn.send(None)
    conn.close()


def run_budgeted(
    method: str, mode: str, cell: tuple[int, int], seeds: list[int], budget: float
) -> tuple[list[dict], str]:
    """Run ``method`` on the datasets in a child process; stop it when the budget is spent."""
    ctx = mp.get_context('fork')
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_grid_child, args=(method, mode, cell, seeds, child))
    proc.start()
    child.close()
    rows: list[dict] = []
    status = 'ok'
    deadline = time.monotonic() + budget
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not parent.poll(left):
                status = (
                    f'stopped at the {budget:.0f} s time limit after {len(rows)} of '
                    f'{len(seeds)} datasets'
                )
                break
            try:
                msg = parent.recv()
            except EOFError:
                status = f'crashed after {len(rows)} datasets (exit {proc.exitcode})'
                break
            if msg is None:
                break
            rows.append(msg)
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join()
    return rows, status


def summarise(rows: list[dict]) -> dict:
    if not rows:
        return {'n': 0}
    acc = np.array([r['accuracy'] for r in rows])
    return {
        'n': len(rows),
        'accuracy_mean': float(acc.mean()),
        'accuracy_min': float(acc.min()),
        'accuracy_max': float(acc.max()),
        'link_precision': float(np.mean([r['link_precision'] for r in rows])),
        'link_recall': float(np.mean([r['link_recall'] for r in rows])),
        'identity_switches': float(np.mean([r['identity_switches'] for r in rows])),
        'adjusted_rand_index': float(np.mean([r['adjusted_rand_index'] for r in rows])),
        'seconds_mean': float(np.mean([r['seconds'] for r in rows])),
        'detections_mean': float(np.mean([r['detections'] for r in rows])),
    }


def run_grid(methods: list[str], seeds_per_cell: dict, log) -> dict:
    out: dict = {
        'cells': [],
        'clutter': CLUTTER,
        'budget_s': {f'{a}x{b}': v for (a, b), v in BUDGET.items()},
    }
    for cell in CELLS:
        n = seeds_per_cell[cell]
        seeds = [dataset_seed(*cell, k) for k in range(n)]
        for mode in MODES:
            entry = {
                'targets': cell[0],
                'sensors': cell[1],
                'mode': mode,
                'seeds': seeds,
                'methods': {},
            }
            for m in methods:
                t0 = time.monotonic()
                rows, status = run_budgeted(m, mode, cell, seeds, BUDGET[cell])
                entry['methods'][m] = {'summary': summarise(rows), 'status': status, 'runs': rows}
                s = entry['methods'][m]['summary']
                log(
                    f'grid {cell[0]}/{cell[1]} {mode:7s} {m:12s} '
                    f'{s.get("accuracy_mean", float("nan")) * 100:7.3f}% '
                    f'n={s["n"]} {status} ({time.monotonic() - t0:.1f} s)'
                )
            out['cells'].append(entry)
    return out


# ----------------------------------------------------------------------------- cost growth

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


def run_cost(methods: list[str], targets: tuple[int, ...], limit: float, log) -> dict:
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


# ----------------------------------------------------------------------------- Stone Soup


STONESOUP = 'stonesoup==1.9.1'  # the version the committed results/bench was measured with


def ensure_stonesoup(log) -> bool:
    try:
        import stonesoup  # noqa: F401

        return True
    except ImportError:
        pass
    log(f'installing {STONESOUP} into this venv for the benchmark (not a node dependency)')
    # The project's pins constrain whatever Stone Soup pulls in, so the bench never moves a
    # package the nodes use.
    pins = Path(__file__).resolve().parents[4] / 'requirements.txt'
    with tempfile.NamedTemporaryFile('w', suffix='.txt') as constraints:
        if pins.is_file():  # pip constraints take no extras: 'pkg[extra]==v' -> 'pkg==v'
            constraints.write(re.sub(r'\[[^\]]*\]', '', pins.read_text()))
            constraints.flush()
        res = subprocess.run(
            [sys.executable, '-m', 'pip', 'install', '--quiet', STONESOUP, '-c', constraints.name],
            capture_output=True,
            text=True,
        )
    if res.returncode != 0:
        log('stonesoup install failed: ' + res.stderr.strip()[-500:])
        return False
    try:
        import stonesoup  # noqa: F401

        return True
    except ImportError:
        return False


@dataclass(frozen=True)
class PeerConfig:
    """Stone Soup setup (see ``stonesoup_associate``)."""

    q: float = 20.0  # CV accel. noise [m^2/s^3]; model 2 sigma^2 v / L ~ 8; best of 2, 8, 20
    gate: float = 4.0  # Mahalanobis gate (missed_distance), in sigmas
    v_nominal: float = 50.0  # [m/s], converts the stamp noise to position noise
    floor_position: float = 0.5  # [m] measurement noise floor (exact data in paper mode)
    floor_velocity: float = 0.05  # [m/s]
    delete_after: float = 12.0  # [s] without update (> the longest gap between two sensors)
    min_points: int = 2  # MultiMeasurementInitiator confirmation


def stonesoup_associate(
    layout: Layout,
    det: Detections,
    stamp_noise: float,
    velocity_noise: float,
    cfg: PeerConfig = PeerConfig(),
) -> np.ndarray:
    """Stone Soup as an expert would set it up for this problem.

    Detections are processed in time order, one scan per detection (two sensors can be a
    fraction of a second apart). State: (position along the road, speed); a 1-D
    ``ConstantVelocity`` transition in time; each detection measures (sensor position, speed)
    with ``LinearGaussian`` noise (position noise = nominal speed x the stamp noise it is told,
    speed noise as told); Kalman predictor/updater; ``DistanceHypothesiser`` with the
    Mahalanobis measure and a 4-sigma gate; ``GNNWith2DAssignment``; ``MultiMeasurementInitiator``
    (2 points to confirm) and ``UpdateTimeDeleter``. Labels come from the detection behind
    every update of every track ever held; detections in unconfirmed tracks are UNASSIGNED.
    """
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.deleter.time import UpdateTimeDeleter
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.measures import Mahalanobis
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import ConstantVelocity
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.tracker.simple import MultiTargetTracker
    from stonesoup.types.array import CovarianceMatrix, StateVector
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import KalmanUpdater

    sx = max(cfg.v_nominal * stamp_noise, cfg.floor_position)
    sv = max(velocity_noise, cfg.floor_velocity)
    mm = LinearGaussian(ndim_state=2, mapping=(0, 1), noise_covar=np.diag([sx**2, sv**2]))
    predictor = KalmanPredictor(ConstantVelocity(cfg.q))
    updater = KalmanUpdater(mm)
    hyp = DistanceHypothesiser(predictor, updater, measure=Mahalanobis(), missed_distance=cfg.gate)
    assoc = GNNWith2DAssignment(hyp)
    base = dt.datetime(2000, 1, 1)
    pos = layout.positions[det.sensor_index]
    scans = []
    for i in np.argsort(det.stamp, kind='stable').tolist():
        ts = base + dt.timedelta(seconds=float(det.stamp[i]))
        scans.append(
            (
                ts,
                {
                    Detection(
                        StateVector([[pos[i]], [det.velocity[i]]]),
                        timestamp=ts,
                        measurement_model=mm,
                        metadata={'index': i},
                    )
                },
            )
        )
    gap = dt.timedelta(seconds=cfg.delete_after)
    prior = GaussianState(
        StateVector([[0.0], [cfg.v_nominal]]), CovarianceMatrix(np.diag([sx**2, sv**2]))
    )
    init = MultiMeasurementInitiator(
        prior_state=prior,
        measurement_model=mm,
        deleter=UpdateTimeDeleter(gap),
        data_associator=assoc,
        updater=updater,
        min_points=cfg.min_points,
    )
    tracker = MultiTargetTracker(
        initiator=init,
        deleter=UpdateTimeDeleter(gap),
        detector=scans,
        data_associator=assoc,
        updater=updater,
    )
    seen: set = set()
    for _, tracks in tracker:
        seen |= tracks
    labels = np.full(len(det), -1, dtype=np.int64)
    for k, tr in enumerate(sorted(seen, key=lambda t: t.states[0].timestamp)):
        for st in tr.states:
            h = getattr(st, 'hypothesis', None)
            m = getattr(h, 'measurement', None)
            if m is not None and 'index' in m.metadata:
                labels[m.metadata['index']] = k
    return labels


def run_peer(seeds_per_cell: dict, log) -> dict:
    out: dict = {'config': asdict(PeerConfig()), 'cells': []}
    if not ensure_stonesoup(log):
        out['error'] = 'stonesoup could not be installed'
        return out
    import stonesoup

    out['stonesoup_version'] = stonesoup.__version__
    best = make_associator(BEST)
    for cell, n in seeds_per_cell.items():
        for mode in MODES:
            cfg = sim_config(mode, *cell)
            rows_p, rows_b = [], []
            for k in range(n):
                ds = simulate(cfg, dataset_seed(*cell, k))
                t0 = time.perf_counter()
                lab = stonesoup_associate(
                    ds.layout, ds.detections, cfg.stamp_noise, cfg.velocity_noise
                )
                rows_p.append(_score_row(ds, lab, time.perf_counter() - t0))
                t0 = time.perf_counter()
                lab = best.associate(ds.layout, ds.detections, ds.n_targets)
                rows_b.append(_score_row(ds, lab, time.perf_counter() - t0))
            sp, sb = summarise(rows_p), summarise(rows_b)
            det = sum(r['detections'] for r in rows_p)
            entry = {
                'targets': cell[0],
                'sensors': cell[1],
                'mode': mode,
                'n': n,
                'stonesoup': sp,
                BEST: sb,
                'stonesoup_s_per_1000_det': 1000 * sum(r['seconds'] for r in rows_p) / det,
                'speedup': (
                    sum(r['seconds'] for r in rows_p)
                    / max(sum(r['seconds'] for r in rows_b), 1e-9)
                ),
                'runs_stonesoup': rows_p,
                'runs_best': rows_b,
            }
            out['cells'].append(entry)
            log(
                f'peer {cell[0]}/{cell[1]} {mode:7s} stonesoup {sp["accuracy_mean"] * 100:.3f}% '
                f'{BEST} {sb["accuracy_mean"] * 100:.3f}% speedup {entry["speedup"]:.0f}x'
            )
    return out


# ----------------------------------------------------------------------------- live


def run_live(root: Path, out_dir: Path, log) -> dict:
    """``scripts/bench_live.py --out <out_dir>`` (NODES helper) writes live.json and live.md."""
    script = root / 'scripts' / 'bench_live.py'
    if not script.exists():
        return {'status': 'scripts/bench_live.py not present; live figures not measured'}
    env = dict(os.environ)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    target = out_dir / 'live.json'
    try:
        res = subprocess.run(
            [sys.executable, str(script), '--out', str(out_dir)],
            capture_output=True,
            text=True,
            timeout=1200,
            env=env,
            cwd=root,
        )
    except subprocess.TimeoutExpired:
        return {'status': 'bench_live.py exceeded 1200 s'}
    if res.returncode != 0 or not target.exists():
        return {
            'status': f'bench_live.py failed (exit {res.returncode})',
            'stderr': res.stderr[-2000:],
        }
    data = json.loads(target.read_text())
    data['status'] = 'ok'
    a = data.get('association_node', {})
    log(
        f'live: ingest ratio {data.get("ingest_ratio")} p50 {a.get("latency_p50")} s '
        f'p95 {a.get("latency_p95")} s'
    )
    return data


# ----------------------------------------------------------------------------- targets


def _cell(grid: dict, t: int, s: int, mode: str) -> dict | None:
    for c in grid.get('cells', []):
        if (c['targets'], c['sensors'], c['mode']) == (t, s, mode):
            return c
    return None


def _acc(
    grid: dict, t: int, s: int, mode: str, m: str, key: str = 'accuracy_mean'
) -> float | None:
    c = _cell(grid, t, s, mode)
    if not c or m not in c['methods']:
        return None
    return c['methods'][m]['summary'].get(key)


def evaluate_targets(grid: dict, cost: dict, peer: dict, live: dict) -> list[dict]:
    out = []

    def check(name: str, ok: bool | None, value: str) -> None:
        out.append({'target': name, 'met': ok, 'value': value})

    def fmt(x: float | None) -> str:
        return 'n/a' if x is None else f'{100 * x:.3f}%'

    a, lo = _acc(grid, 50, 20, 'paper', BEST), _acc(grid, 50, 20, 'paper', BEST, 'accuracy_min')
    check('paper 50/20: best mean >= 99.9%', None if a is None else a >= 0.999, fmt(a))
    check('paper 50/20: no dataset < 99.5%', None if lo is None else lo >= 0.995, fmt(lo))
    a = _acc(grid, 200, 50, 'paper', BEST)
    check('paper 200/50: best >= 99.7%', None if a is None else a >= 0.997, fmt(a))
    a = _acc(grid, 1000, 100, 'paper', BEST)
    check('paper 1000/100: best >= 99.0%', None if a is None else a >= 0.990, fmt(a))
    a = _acc(grid, 50, 20, 'clutter', BEST)
    check('clutter 50/20: best mean >= 99.3%', None if a is None else a >= 0.993, fmt(a))
    r, p = _acc(grid, 50, 20, 'clutter', 'mlkm_robust'), _acc(grid, 50, 20, 'clutter', 'mlkm')
    ok = None if r is None or p is None else r - p >= 0.10
    check(
        'clutter 50/20: mlkm_robust beats mlkm by >= 10 points',
        ok,
        f'{fmt(r)} vs {fmt(p)}' + ('' if ok is None else f' (+{100 * (r - p):.1f})'),
    )
    worse = []
    for c in grid.get('cells', []):
        b = c['methods'].get(BEST, {}).get('summary', {}).get('accuracy_mean')
        s = c['methods'].get(BASELINE, {}).get('summary', {}).get('accuracy_mean')
        if b is not None and s is not None and b < s:
            worse.append(f'{c["targets"]}/{c["sensors"]} {c["mode"]}: {fmt(b)} < {fmt(s)}')
    check(f'{BEST} >= {BASELINE} on every grid cell', not worse, '; '.join(worse) or 'all cells')
    if peer.get('cells'):
        bad = [
            f'{c["targets"]}/{c["sensors"]} {c["mode"]}'
            for c in peer['cells']
            if c[BEST]['accuracy_mean'] < c['stonesoup']['accuracy_mean']
        ]
        check(
            'vs Stone Soup: at least as accurate on every cell',
            not bad,
            '; '.join(
                f'{c["targets"]}/{c["sensors"]} {c["mode"]}: '
                f'{fmt(c[BEST]["accuracy_mean"])} vs '
                f'{fmt(c["stonesoup"]["accuracy_mean"])}'
                for c in peer['cells']
            ),
        )
        sp = min(c['speedup'] for c in peer['cells'])
        check('vs Stone Soup: >= 100x faster', sp >= 100, f'min speedup {sp:.0f}x')
    else:
        check('vs Stone Soup', None, peer.get('error', 'not run'))
    a = _cell(grid, 1000, 100, 'paper')
    sec = (
        None
        if a is None or BEST not in a['methods']
        else (a['methods'][BEST]['summary'].get('seconds_mean'))
    )
    check(
        'scale: 1000x100 (1e5 detections) < 30 s',
        None if sec is None else sec < 30,
        'n/a' if sec is None else f'{sec:.1f} s (grid run, child process)',
    )
    sl = cost.get('methods', {}).get(BEST, {}).get('time_slope')
    check(
        'scale: fitted log-log cost slope <= 1.5',
        None if sl is None else sl <= 1.5,
        'n/a' if sl is None else f'{sl:.2f}',
    )
    ratio = live.get('ingest_ratio')
    p95 = live.get('association_node', {}).get('latency_p95')
    check(
        'live: >= 70% of bare subscriber ingest',
        None if ratio is None else ratio >= 0.7,
        live.get('status', '') if ratio is None else f'{ratio:.2f}',
    )
    check(
        'live: p95 latency <= 100 ms',
        None if p95 is None else p95 <= 0.1,
        live.get('status', '') if p95 is None else f'{1000 * p95:.1f} ms',
    )
    return out


# ----------------------------------------------------------------------------- plots, README


def plot_all(out_dir: Path, grid: dict, cost: dict) -> list[str]:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    files = []
    for mode in MODES:
        cells = [c for c in grid.get('cells', []) if c['mode'] == mode]
        if not cells:
            continue
        methods = list(cells[0]['methods'])
        fig, ax = plt.subplots(figsize=(11, 4.5))
        width = 0.8 / max(len(methods), 1)
        for i, m in enumerate(methods):
            xs, mean, err_lo, err_hi = [], [], [], []
            for j, c in enumerate(cells):
                s = c['methods'][m]['summary']
                if s['n'] == 0:
                    continue
                xs.append(j + (i - len(methods) / 2 + 0.5) * width)
                mean.append(100 * s['accuracy_mean'])
                err_lo.append(100 * (s['accuracy_mean'] - s['accuracy_min']))
                err_hi.append(100 * (s['accuracy_max'] - s['accuracy_mean']))
            ax.bar(xs, mean, width, yerr=[err_lo, err_hi], capsize=2, label=m)
        ax.set_xticks(range(len(cells)))
        ax.set_xticklabels([f'{c["targets"]} targets / {c["sensors"]} sensors' for c in cells])
        ax.set_ylabel('accuracy [%] (bar: mean, whiskers: min..max)')
        ax.set_ylim(0, 101)
        ax.set_title(f'Accuracy grid, {mode} mode (missing bar: stopped at the time limit)')
        ax.legend(fontsize=7, ncol=5, loc='lower left')
        fig.tight_layout()
        name = f'grid_{mode}.png'
        fig.savefig(out_dir / name, dpi=110)
        plt.close(fig)
        files.append(name)
    for key, label, fname in (
        ('seconds', 'runtime [s]', 'cost_runtime.png'),
        ('peak_bytes', 'peak memory above start [MiB]', 'cost_memory.png'),
    ):
        fig, ax = plt.subplots(figsize=(8, 5.5))
        for m, rec in cost.get('methods', {}).items():
            pts = rec['points']
            if not pts:
                continue
            x = [p['detections'] for p in pts]
            y = [p[key] / (2**20 if key == 'peak_bytes' else 1) for p in pts]
            slope = rec['time_slope' if key == 'seconds' else 'memory_slope']
            tag = f'{m} (slope {slope:.2f})' if slope is not None else m
            if rec['stopped']:
                tag += ' [stopped at limit]'
            ax.loglog(x, np.maximum(y, 1e-3), 'o-', label=tag)
        if key == 'seconds':
            ax.axhline(cost.get('time_limit_s', COST_LIMIT), color='grey', ls=':', lw=1)
            ax.text(1000, cost.get('time_limit_s', COST_LIMIT) * 1.1, 'time limit', fontsize=8)
        ax.set_xlabel('detections (20 sensors, more targets)')
        ax.set_ylabel(label)
        ax.set_title(f'Cost growth, one core: {label}')
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out_dir / fname, dpi=110)
        plt.close(fig)
        files.append(fname)
    return files


def _pct(x: float | None) -> str:
    return '—' if x is None else f'{100 * x:.2f}'


def write_readme(
    out_dir: Path, grid: dict, cost: dict, peer: dict, live: dict, targets: list[dict], meta: dict
) -> None:
    L = [
        '# Benchmarks (`make bench`)',
        '',
        f'Generated by `mlkm bench --out {meta["out"]}`{" --quick" if meta["quick"] else ""}'
        f' on {meta["date"]}; total {meta["seconds"] / 60:.1f} min on a shared 2-core machine. '
        'Regenerate with `make bench` (about 20-25 min; `mlkm bench --quick` for a smoke '
        'run). Every figure below comes from the JSON files next to this README.',
        '',
        '## Section 5 targets',
        '',
        '| target | met | value |',
        '| --- | --- | --- |',
    ]
    for t in targets:
        met = {True: 'yes', False: '**no**', None: 'n/a'}[t['met']]
        L.append(f'| {t["target"]} | {met} | {t["value"]} |')
    L += [
        '',
        '## Accuracy grid',
        '',
        'Mean accuracy [%] (min..max) over seeded datasets; the same datasets for every '
        'method. Clutter mode: 5% misses, 0.05 false alarms per target per sensor, 0.2 s '
        'stamp noise, 0.5 m/s speed noise. Time budget per (method, cell, mode): '
        + ', '.join(f'{k}: {v:.0f} s' for k, v in grid.get('budget_s', {}).items())
        + '; a method over budget is stopped and marked.',
        '',
    ]
    for mode in MODES:
        cells = [c for c in grid.get('cells', []) if c['mode'] == mode]
        if not cells:
            continue
        L.append(f'### {mode} mode')
        L.append('')
        head = (
            '| method | '
            + ' | '.join(f'{c["targets"]}/{c["sensors"]} (n={len(c["seeds"])})' for c in cells)
            + ' |'
        )
        L += [head, '|' + ' --- |' * (len(cells) + 1)]
        for m in cells[0]['methods']:
            row = [m]
            for c in cells:
                s = c['methods'][m]['summary']
                if s['n'] == 0:
                    row.append('stopped (time limit)')
                    continue
                txt = (
                    f'{_pct(s["accuracy_mean"])} ({_pct(s["accuracy_min"])}..'
                    f'{_pct(s["accuracy_max"])}) {s["seconds_mean"]:.2f} s'
                )
                if c['methods'][m]['status'] != 'ok':
                    txt += f' [{s["n"]} of {len(c["seeds"])}: time limit]'
                row.append(txt)
            L.append('| ' + ' | '.join(row) + ' |')
        L.append('')
        L.append(f'Link precision / recall, identity switches, ARI ({mode}, 50/20):')
        L.append('')
        c = _cell(grid, 50, 20, mode)
        if c:
            L += [
                '| method | link precision | link recall | identity switches | ARI |',
                '| --- | --- | --- | --- | --- |',
            ]
            for m, r in c['methods'].items():
                s = r['summary']
                if s['n']:
                    L.append(
                        f'| {m} | {s["link_precision"]:.4f} | {s["link_recall"]:.4f} | '
                        f'{s["identity_switches"]:.2f} | {s["adjusted_rand_index"]:.4f} |'
                    )
        L.append('')
        L.append(f'![grid {mode}](grid_{mode}.png)')
        L.append('')
    L += [
        '## Cost growth (20 sensors, one core)',
        '',
        f'Fresh process per point, one thread; limit {cost.get("time_limit_s", 0):.0f} s per '
        'point. Slope: least-squares fit of log(runtime) on log(detections) over the points '
        'with >= 3000 detections.',
        '',
        '| method | detections reached | runtime at largest [s] | time slope | '
        'memory slope | peak memory at largest [MiB] | note |',
        '| --- | --- | --- | --- | --- | --- | --- |',
    ]
    for m, rec in cost.get('methods', {}).items():
        pts = rec['points']
        if pts:
            p = pts[-1]
            ts = '—' if rec['time_slope'] is None else f'{rec["time_slope"]:.2f}'
            ms = '—' if rec['memory_slope'] is None else f'{rec["memory_slope"]:.2f}'
            L.append(
                f'| {m} | {p["detections"]} | {p["seconds"]:.2f} | {ts} | {ms} | '
                f'{p["peak_bytes"] / 2**20:.1f} | {rec["stopped"] or ""} |'
            )
        else:
            L.append(f'| {m} | — | — | — | — | — | {rec["stopped"] or ""} |')
    L += [
        '',
        '![runtime](cost_runtime.png)',
        '',
        '![memory](cost_memory.png)',
        '',
        '## Stone Soup side by side',
        '',
    ]
    if peer.get('cells'):
        L += [
            f'Stone Soup {peer.get("stonesoup_version", "")}, set up in '
            '`mlkm_experiments.bench.stonesoup_associate` (1-D constant velocity, measurement of '
            'position and speed, Mahalanobis-gated `GNNWith2DAssignment`, '
            '`MultiMeasurementInitiator`, `UpdateTimeDeleter`, told the stamp and speed '
            f'noise); config `{json.dumps(peer["config"])}`. Same datasets (the first ones '
            'of each grid cell), same run.',
            '',
            f'| cell | mode | n | Stone Soup accuracy | {BEST} accuracy | Stone Soup s / 1000 '
            f'det | speedup of {BEST} |',
            '| --- | --- | --- | --- | --- | --- | --- |',
        ]
        for c in peer['cells']:
            L.append(
                f'| {c["targets"]}/{c["sensors"]} | {c["mode"]} | {c["n"]} | '
                f'{_pct(c["stonesoup"]["accuracy_mean"])} | '
                f'{_pct(c[BEST]["accuracy_mean"])} | '
                f'{c["stonesoup_s_per_1000_det"]:.2f} | {c["speedup"]:.0f}x |'
            )
    else:
        L.append(peer.get('error', 'not run'))
    L += ['', '## Live throughput', '']
    a = live.get('association_node')
    if a:
        sc = live.get('scenario', {})
        L += [
            f'`scripts/bench_live.py` (details: [live.md](live.md)): `sensor_sim` at '
            f'real_time_factor 0, {sc.get("targets")} targets x {sc.get("sensors")} sensors, '
            f'{sc.get("episodes")} episodes, method `{sc.get("method")}`; medians of '
            f'{sc.get("repeats")} interleaved runs.',
            '',
            '| figure | value |',
            '| --- | --- |',
            f'| bare rclpy subscriber ingest [msg/s] | {live["bare_subscriber"]["ingest_rate"]} |',
            f'| association node ingest [msg/s] | {a["ingest_rate"]} |',
            f'| ratio (target >= 0.70) | {live.get("ingest_ratio")} |',
            f'| latency p50, segment complete -> tracks [ms] | {1000 * a["latency_p50"]:.1f} |',
            f'| latency p95 (target <= 100 ms) [ms] | {1000 * a["latency_p95"]:.1f} |',
            f'| nothing lost | {live.get("nothing_lost")} |',
        ]
    else:
        L.append(str(live.get('status', 'not run')))
    L.append('')
    (out_dir / 'README.md').write_text('\n'.join(L) + '\n')


# ----------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog='mlkm bench', description=__doc__.splitlines()[0])
    ap.add_argument('--out', default='results/bench', help='output directory')
    ap.add_argument('--quick', action='store_true', help='small smoke version')
    ap.add_argument(
        '--only',
        choices=('grid', 'cost', 'peer', 'live'),
        action='append',
        help='run only these parts (repeatable); default: all',
    )
    ap.add_argument('--methods', help='comma-separated subset of methods (default: all)')
    args = ap.parse_args(argv)
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    root = Path(__file__).resolve()
    root = next((p for p in root.parents if (p / 'Makefile').exists()), Path.cwd())
    parts = set(args.only or ('grid', 'cost', 'peer', 'live'))
    methods = args.methods.split(',') if args.methods else available_methods()
    t_start = time.monotonic()
    logf = open(out_dir / 'bench.log', 'a')

    def log(msg: str) -> None:
        line = f'[{time.monotonic() - t_start:7.1f} s] {msg}'
        print(line, flush=True)
        logf.write(line + '\n')
        logf.flush()

    def load(name: str) -> dict:
        f = out_dir / name
        return json.loads(f.read_text()) if f.exists() else {}

    def save(name: str, data: dict) -> None:
        (out_dir / name).write_text(json.dumps(data, indent=1, default=float))

    seeds = SEEDS_QUICK if args.quick else SEEDS_FULL
    log(f'methods: {", ".join(methods)}')
    if 'grid' in parts:
        save('grid.json', run_grid(methods, seeds, log))
    if 'peer' in parts:
        pseeds = {c: min(n, seeds[c]) for c, n in PEER_SEEDS.items()}
        if args.quick:
            pseeds = {c: 1 for c in PEER_SEEDS}
        save('peer.json', run_peer(pseeds, log))
    if 'cost' in parts:
        targets = COST_TARGETS[:3] if args.quick else COST_TARGETS
        save('cost.json', run_cost(methods, targets, 20.0 if args.quick else COST_LIMIT, log))
    if 'live' in parts:
        save('live.json', run_live(root, out_dir, log))
    grid, cost, peer, live = (
        load('grid.json'),
        load('cost.json'),
        load('peer.json'),
        load('live.json'),
    )
    targets = evaluate_targets(grid, cost, peer, live)
    seconds = time.monotonic() - t_start
    meta = {
        'out': args.out,
        'quick': args.quick,
        'seconds': seconds,
        'date': dt.datetime.now(dt.UTC).strftime('%Y-%m-%d %H:%M UTC'),
        'parts': sorted(parts),
        'python': sys.version.split()[0],
    }
    save('summary.json', {'meta': meta, 'targets': targets})
    plot_all(out_dir, grid, cost)
    write_readme(out_dir, grid, cost, peer, live, targets, meta)
    for t in targets:
        log(f'target: {t["target"]}: {t["met"]} ({t["value"]})')
    log(f'done in {seconds / 60:.1f} min; wrote {out_dir}')
    logf.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
