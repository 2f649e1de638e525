"""The peer: Stone Soup (PyPI ``stonesoup``, pinned in requirements.txt for the benchmarks,
never a dependency of the nodes) set up for this problem, side by side with the best method
on the first datasets of the small grid cells of both modes."""

from __future__ import annotations

import datetime as dt
import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from mlkm_core.associators import make_associator
from mlkm_core.simulator import simulate
from mlkm_core.types import Detections, Layout

from .common import BEST, MODES, Log, dataset_seed, score_row, sim_config, summarise

PEER_SEEDS = {(10, 10): 10, (50, 20): 5}


def stonesoup_version() -> str | None:
    """The installed Stone Soup version, None when it is missing (run ``make setup``)."""
    try:
        import stonesoup
    except ImportError:
        return None
    return stonesoup.__version__


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


def config_for(layout: Layout, det: Detections, base: PeerConfig = PeerConfig()) -> PeerConfig:
    """The setup fitted to a road other than the simulator's (SUMO), from the detections
    alone: nominal speed = the median measured speed; a track is kept without update for
    1.5 x the longest station gap at the 5th-percentile speed (at least ``base.delete_after``),
    so that slow vehicles are not dropped between distant stations."""
    v = np.asarray(det.velocity, float)
    if v.size == 0:
        return base
    gap = float(np.max(np.diff(layout.positions), initial=0.0))
    slow = max(float(np.percentile(v, 5)), 0.1)
    return replace(
        base,
        v_nominal=float(np.median(v)),
        delete_after=max(base.delete_after, 1.5 * gap / slow),
    )


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
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.measures import Mahalanobis
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import ConstantVelocity
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.array import StateVector
    from stonesoup.types.detection import Detection
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
    return run_tracker(scans, len(det), mm, updater, assoc, cfg, sx, sv)


def run_tracker(scans, n: int, mm, updater, assoc, cfg: PeerConfig, sx: float, sv: float):
    """Stone Soup's multi-target tracker over ``scans`` ((time, {detection}) in time order,
    each detection's metadata holding its ``index`` among ``n``), with the two-point initiator
    and the deleter of ``cfg``; the label of each detection: the track whose update took it,
    numbered by their first update, -1 for detections in unconfirmed tracks."""
    from stonesoup.deleter.time import UpdateTimeDeleter
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.tracker.simple import MultiTargetTracker
    from stonesoup.types.array import CovarianceMatrix, StateVector
    from stonesoup.types.state import GaussianState

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
    labels = np.full(n, -1, dtype=np.int64)
    for k, tr in enumerate(sorted(seen, key=lambda t: t.states[0].timestamp)):
        for st in tr.states:
            m = getattr(getattr(st, 'hypothesis', None), 'measurement', None)
            if m is not None and 'index' in m.metadata:
                labels[m.metadata['index']] = k
    return labels


def run_peer(seeds_per_cell: dict, log: Log) -> dict:
    out: dict = {'config': asdict(PeerConfig()), 'cells': []}
    version = stonesoup_version()
    if version is None:
        out['error'] = 'stonesoup is not installed (make setup installs it)'
        log(out['error'])
        return out
    out['stonesoup_version'] = version
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
                rows_p.append(score_row(ds, lab, time.perf_counter() - t0))
                t0 = time.perf_counter()
                lab = best.associate(ds.layout, ds.detections, ds.n_targets)
                rows_b.append(score_row(ds, lab, time.perf_counter() - t0))
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
