"""The tracker's own use of the motion model: the immediate link, the end of a track and the
calibration on the stream's history (pairwise model, ``mlkm_core.model.motion``)."""

from __future__ import annotations

import bisect
import math

import numpy as np

from mlkm_core.associators.calibration import estimate_params
from mlkm_core.model.motion import (
    FLOOR_T,
    FLOOR_V,
    LOG2PI,
    MotionParams,
    PairwiseModel,
)
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


class LinkCost:
    """The pairwise model's weight of one link, in plain floats (``PairwiseModel.cost`` for a
    single pair: the immediate link scores a handful of candidates per detection, where
    numpy's per-call cost would dominate)."""

    def __init__(self, p: MotionParams, layout: Layout) -> None:
        p = p.for_pairwise()
        self.p = p
        self.positions = [float(x) for x in layout.positions]
        self.noise_t2 = 2 * max(p.stamp_noise, FLOOR_T) ** 2
        self.noise_v = max(p.velocity_noise, FLOOR_V)
        self.miss = p.miss_cost
        self.delay = None
        if p.delay is not None:
            self.delay = tuple(
                [float(v) for v in a] for a in (p.delay.positions, p.delay.time, p.delay.var)
            )

    def _extra(self, x1: float, x2: float) -> tuple[float, float]:
        """Mean [s] and variance [s^2] of the extra time from x1 to x2 (``GapDelays``)."""
        if self.delay is None:
            return 0.0, 0.0
        pos, time, var = self.delay
        top = len(pos) - 1
        k1 = min(max(bisect.bisect_right(pos, x1) - 1, 0), top)
        k2 = min(max(bisect.bisect_right(pos, x2) - 1, 0), top)
        return time[k2] - time[k1], abs(var[k2] - var[k1])

    def weight(
        self,
        tail: tuple[int, float, float],
        sensor: int,
        stamp: float,
        velocity: float,
        birth: float,
    ) -> float:
        """Weight of linking a detection (sensor, stamp, velocity) to a track whose latest
        detection is ``tail`` (sensor, stamp, velocity): the pairwise NLL plus the miss cost
        of skipped stations, minus the cost of the alternatives (a miss, and a birth costing
        ``birth``); < 0 is worth linking, inf outside the gate."""
        p = self.p
        x1, x2 = self.positions[tail[0]], self.positions[sensor]
        dx = x2 - x1
        u1, u = 1.0 / tail[2], 1.0 / velocity
        su2 = (p.sigma * u1 * u) ** 2
        vn1, vn2 = (self.noise_v * u1 * u1) ** 2, (self.noise_v * u * u) ** 2
        extra_t, extra_var = self._extra(x1, x2)
        e_t = stamp - tail[1] - dx * (u1 + u) / 2 - extra_t
        var_t = (
            self.noise_t2 + dx * dx * (vn1 + vn2) / 4 + su2 * dx**3 / (6 * p.length) + extra_var
        )
        e_u = u - u1
        var_u = vn1 + vn2 + 2 * su2 * (1 - math.exp(-dx / p.length))
        try:
            d2 = e_t * e_t / var_t + e_u * e_u / var_u
            nll = 0.5 * (d2 + math.log(var_t * var_u)) + LOG2PI
            if p.jump_rate > 0:
                vj = (p.jump_sigma * u1 * u) ** 2
                vt1, vu1 = var_t + vj * dx * dx / 12, var_u + vj
                d21 = e_t * e_t / vt1 + e_u * e_u / vu1
                nll1 = 0.5 * (d21 + math.log(vt1 * vu1)) + LOG2PI
                pj = -math.expm1(-p.jump_rate * dx)
                a = math.log1p(-pj) - nll if pj < 1 else -math.inf
                b = math.log(pj) - nll1 if pj > 0 else -math.inf
                top = max(a, b)
                nll = -(top + math.log(math.exp(a - top) + math.exp(b - top)))
                d2 = min(d2, d21)
        except (ValueError, ZeroDivisionError, OverflowError):
            return math.inf
        w = nll + (sensor - 2 - tail[0]) * self.miss - birth
        return w if d2 <= p.gate and math.isfinite(w) else math.inf

    def due(self, tail: tuple[int, float, float], to: int) -> float:
        """Stamp after which a vehicle last seen at ``tail`` (sensor, stamp, velocity) is past
        the gate of its passage at station ``to`` (``overdue_at`` in plain floats)."""
        p = self.p
        x1, x2 = self.positions[tail[0]], self.positions[to]
        dx = x2 - x1
        u = 1.0 / tail[2]
        vn = (self.noise_v * u * u) ** 2
        su2 = (p.sigma * u * u) ** 2
        var_du = 2 * vn + 2 * su2 * (1 - math.exp(-dx / p.length))
        var_t = self.noise_t2 + dx * dx * var_du + su2 * dx**3 / (6 * p.length)
        if p.jump_rate > 0:
            var_t += (p.jump_sigma * u * u) ** 2 * dx * dx
        extra_t, extra_var = self._extra(x1, x2)
        due = tail[1] + dx * u + extra_t + math.sqrt(p.gate * (var_t + extra_var))
        return due if math.isfinite(due) else tail[1]


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
    d = Detections(arr[:, 0].astype(np.int64), arr[:, 1], arr[:, 2])
    return estimate_params(layout, d, whole_passages=False)  # rows cut out of a stream
