"""The tracker's own use of the motion model: the immediate link, the end of a track and the
calibration on the stream's history (pairwise model, ``mlkm_core.associators.motion``)."""

from __future__ import annotations

import math

import numpy as np

from mlkm_core.associators.calibration import estimate_params
from mlkm_core.associators.motion import MotionParams, PairwiseModel
from mlkm_core.types import Detections, Layout

#: fewest detections the motion model is calibrated on (below, the last estimate is kept)
MIN_CALIBRATION = 20


def _model(p: MotionParams, layout: Layout, sensor, stamp, velocity) -> PairwiseModel:
    model = PairwiseModel(p)
    n = len(sensor)
    model.grow(n)
    model.start(
        np.arange(n),
        layout.positions[np.asarray(sensor, np.int64)],
        np.asarray(stamp, float),
        1.0 / np.asarray(velocity, float),
    )
    return model


def link_weights(
    p: MotionParams,
    layout: Layout,
    tails: tuple[list[int], list[float], list[float]],
    sensor: int,
    stamp: float,
    velocity: float,
    birth: float,
) -> np.ndarray:
    """Weight of linking a detection to each track ending on ``tails`` (sensors, stamps,
    speeds): the pairwise NLL plus the miss cost of skipped stations, minus the cost of the
    alternatives (a miss, and a birth costing ``birth``); < 0 is worth linking, inf outside
    the gate."""
    n = len(tails[0])
    model = _model(p, layout, *tails)
    pred = model.predict(np.arange(n), float(layout.positions[sensor]))
    with np.errstate(all='ignore'):
        nll, d2 = model.cost(pred, np.full(n, stamp), np.full(n, 1.0 / velocity))
    skipped = sensor - 1 - np.asarray(tails[0])
    w = nll + skipped * p.miss_cost - p.miss_cost - birth
    return np.where((d2 <= p.gate) & np.isfinite(w), w, np.inf)


def overdue_at(
    p: MotionParams, layout: Layout, sensor: int, stamp: float, velocity: float, to: int
) -> float:
    """Stamp after which a vehicle last seen at (sensor, stamp, velocity) is past the gate of
    its passage at station ``to``."""
    model = _model(p, layout, [sensor], [stamp], [velocity])
    with np.errstate(all='ignore'):
        centre, half = model.gate_window(
            model.predict(np.zeros(1, np.int64), layout.positions[to])
        )
    due = float(centre[0] + half[0])
    return due if math.isfinite(due) else stamp


def calibrate_on(layout: Layout, rows: list[tuple[int, float, float]]) -> MotionParams | None:
    """Motion parameters from (sensor, stamp, speed) rows; None if there are too few."""
    if len(rows) < MIN_CALIBRATION:
        return None
    arr = np.array(rows)
    return estimate_params(layout, Detections(arr[:, 0].astype(np.int64), arr[:, 1], arr[:, 2]))
