"""Virtual loop detectors on vehicle trajectories: what a station at x would have reported.

A loop reports the moment a vehicle's front crosses it, the vehicle's speed, its lane and its
length. On trajectories (``mlkm_core.trajectories``) a crossing of station x is a pair of
consecutive frames k, k+1 of one observed stretch with p_k < x <= p_k+1:

- the stamp and the speed are interpolated linearly between the two frames at the fraction
  f = (x - p_k) / (p_k+1 - p_k); where the interpolated speed is below the slowest plausible
  passage (``Bounds.min_speed``: both frames at a standstill, yet the front moved across the
  loop), the speed reported is the mean over the frame interval, which is what a dual loop
  measures (distance between its loops over the time between them);
- the lane and the length are those of the frame nearer the crossing (at f = 0.5, the
  earlier frame);
- a vehicle is detected at most once per station: the first crossing counts. A stopped
  vehicle whose position jitters back and forth across a loop is one passage, as it is to a
  real loop (which holds its presence while the vehicle stands on it);
- a stretch ends where the frames have a gap (more than ``gap_factor`` times the file's usual
  frame step): a vehicle crossing a station between two stretches was not observed there.

**Open** loops report every observed crossing: a vehicle appears and disappears wherever its
observation starts and ends, as on a road with ramps. **Closed** loops keep only the vehicles
detected at every station, the paper's closed road (every target passes every sensor).

Stamps are rounded to 1 ms, speeds to 1 mm/s and lengths to 1 cm (what a loop controller
reports, and the decimals ``mlkm_core.csvout`` writes), so that the detections written to CSV
and read back are the ones associated in memory.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlkm_core.bounds import Bounds
from mlkm_core.trajectories import Trajectories
from mlkm_core.types import Dataset, Detections, Layout

#: The bounds a detection must pass (a live feed's: stamps >= 0 are checked by the node).
LIVE = Bounds()
#: Frames further apart than this many usual frame steps start a new observed stretch [-].
GAP_FACTOR = 1.5
STAMP_DECIMALS = 3  # 1 ms
SPEED_DECIMALS = 3  # 1 mm/s
LENGTH_DECIMALS = 2  # 1 cm


@dataclass(frozen=True)
class Loops:
    """Virtual loop detections: the dataset (truth = vehicle ids) and what they cover."""

    dataset: Dataset
    lanes: int  # lanes of the road (the largest lane index of any frame + 1), 0: unknown [-]
    closed: bool
    vehicles_seen: int  # vehicles in the trajectories [-]
    vehicles_detected: int  # of them, detected at least once (closed: at every station) [-]


def even_positions(count: int, start: float, end: float) -> np.ndarray:
    """``count`` stations evenly spaced from ``start`` to ``end`` [m], both included (one
    station: at ``start``)."""
    if count < 1:
        raise ValueError('need at least one station')
    if count > 1 and not end > start:
        raise ValueError(f'need end > start, got {start:g} .. {end:g} m')
    return np.linspace(start, end, count) if count > 1 else np.array([float(start)])


def covered_span(traj: Trajectories, margin: float = 0.05) -> tuple[float, float]:
    """The stretch of road the trajectories cover, ``margin`` of it trimmed at each end [m]."""
    lo, hi = float(traj.position.min()), float(traj.position.max())
    cut = margin * (hi - lo)
    return lo + cut, hi - cut


def frame_step(traj: Trajectories) -> float:
    """The usual time between two frames of one vehicle [s] (the median step)."""
    same = traj.vehicle[1:] == traj.vehicle[:-1]
    steps = np.diff(traj.time)[same]
    if steps.size == 0:
        raise ValueError('no vehicle has two frames: no crossing can be seen')
    return float(np.median(steps))


def virtual_loops(
    traj: Trajectories,
    positions: np.ndarray,
    closed: bool = False,
    road_length: float | None = None,
    gap_factor: float = GAP_FACTOR,
    bounds: Bounds = LIVE,
) -> Loops:
    """Detections of stations at ``positions`` [m] (strictly increasing) on ``traj``; see the
    module docstring. ``road_length`` defaults to the furthest of the positions and the
    trajectories' frames."""
    positions = np.asarray(positions, float)
    far = max(float(positions[-1]), float(traj.position.max()))
    layout = Layout(road_length if road_length is not None else far, positions)
    k = np.flatnonzero(
        (traj.vehicle[1:] == traj.vehicle[:-1])
        & (np.diff(traj.time) <= gap_factor * frame_step(traj))
    )  # frame pairs (k, k + 1) inside one observed stretch
    p0, p1 = traj.position[k], traj.position[k + 1]
    parts = []
    for s, x in enumerate(positions):
        hit = k[(p0 < x) & (p1 >= x)]
        if hit.size == 0:
            continue
        # the first crossing of each vehicle (frames are sorted by vehicle, then time)
        _, first = np.unique(traj.vehicle[hit], return_index=True)
        parts.append(_crossings(traj, hit[first], s, x, bounds))
    det = Detections.concatenate(parts)
    if closed and len(det):
        vehicles, counts = np.unique(det.target, return_counts=True)
        det = det.subset(np.isin(det.target, vehicles[counts == positions.size]))
    # the road's lanes, from every frame: the detections kept may not use all of them
    lanes = int(traj.lane.max()) + 1 if len(traj) and traj.lane.max() >= 0 else 0
    n = int(np.unique(det.target).size) if len(det) else 0
    order = np.lexsort((det.sensor_index, det.stamp))
    return Loops(Dataset(layout, det.subset(order), n), lanes, closed, traj.n_vehicles, n)


def _crossings(traj: Trajectories, k: np.ndarray, s: int, x: float, bounds: Bounds):
    t0, t1 = traj.time[k], traj.time[k + 1]
    p0, p1 = traj.position[k], traj.position[k + 1]
    f = (x - p0) / (p1 - p0)
    speed = traj.speed[k] + f * (traj.speed[k + 1] - traj.speed[k])
    mean = (p1 - p0) / (t1 - t0)
    speed = np.where(np.isfinite(speed) & (speed >= bounds.min_speed), speed, mean)
    near = np.where(f > 0.5, k + 1, k)
    return Detections(
        np.full(k.size, s, np.int64),
        np.round(t0 + f * (t1 - t0), STAMP_DECIMALS),
        np.maximum(np.round(speed, SPEED_DECIMALS), bounds.min_speed),
        traj.vehicle[k],
        traj.lane[near],
        np.round(traj.length[near], LENGTH_DECIMALS),
    )
