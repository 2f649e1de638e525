"""Residuals of links under the calibrated model, to check how well it fits a data set.

``link_residuals`` takes tracks (the ground truth, or an associator's labels) and returns, for
every link between consecutive detections of a track, the residuals the pairwise cost is
built on: the travel-time residual e_t (trapezoid in slowness, minus the gap's extra time) and
the slowness change e_u, each also divided by its standard deviation under the nominal
(pure OU) component; the length difference and whether the lane changed.
"""

from __future__ import annotations

import numpy as np

from mlkm_core.model.motion import FLOOR_V, MotionParams, trapezoid_residual
from mlkm_core.types import Detections, Layout, link_pairs


def link_residuals(
    layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams
) -> dict[str, np.ndarray]:
    """Per link of ``labels``: dx [m], e_t [s], z_t, e_u [s/m], z_u, speed change [m/s],
    length difference [m] (NaN unknown), lane changed (-1 unknown), sensor gap index."""
    a, b = link_pairs(d, labels)
    pos = layout.positions
    xa, xb = pos[d.sensor_index[a]], pos[d.sensor_index[b]]
    ua, ub = 1.0 / d.velocity[a], 1.0 / d.velocity[b]
    params = params.for_pairwise()
    nominal = MotionParams(
        sigma=params.sigma,
        length=params.length,
        stamp_noise=params.stamp_noise,
        velocity_noise=params.velocity_noise,
        delay=params.delay,
    )
    dx = xb - xa
    e_t, var_t = trapezoid_residual(nominal, xa, xb, d.stamp[a], d.stamp[b], ua, ub)
    e_u = ub - ua
    # the nominal variances of the pairwise cost (motion.PairwiseModel.cost)
    su2 = (nominal.sigma * ua * ub) ** 2
    vn = (max(nominal.velocity_noise, FLOOR_V) * ua * ua) ** 2 + (
        max(nominal.velocity_noise, FLOOR_V) * ub * ub
    ) ** 2
    var_u = vn + 2 * su2 * (1 - np.exp(-dx / nominal.length))
    length = np.full(a.size, np.nan) if d.length is None else d.length[b] - d.length[a]
    if d.lane is None:
        lane = np.full(a.size, -1)
    else:
        known = (d.lane[a] >= 0) & (d.lane[b] >= 0)
        lane = np.where(known, (d.lane[a] != d.lane[b]).astype(int), -1)
    return {
        'dx': dx,
        'e_t': e_t,
        'z_t': e_t / np.sqrt(var_t),
        'e_u': e_u,
        'z_u': e_u / np.sqrt(var_u),
        'dv': d.velocity[b] - d.velocity[a],
        'length': length,
        'lane_changed': lane,
        'gap': d.sensor_index[a],
    }
