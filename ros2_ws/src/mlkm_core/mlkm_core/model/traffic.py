"""The traffic's own speed at each station over time: what every vehicle's speed follows.

Where traffic enters a queue or leaves road works, every vehicle slows down or speeds up
between two stations by about the same amount. The motion models take a vehicle's speed as
returning to its own cruise speed, so a change shared by all vehicles looks to them like
noise, and the fitted speed noise grows until the speeds no longer tell vehicles apart (on
the work-zone family, 1.5 to 3.3 m/s against 0.03 m/s in free flow). ``TrafficSlowness``
is each station's median slowness [s/m] over time, a rolling median of its own detections,
so it needs no association; the models then expect a vehicle's slowness to change between
two stations as the traffic's did, and its deviation from the traffic to follow the
fluctuation model.

``estimate_traffic`` follows the field only over the gaps where the data show such a change:
the two stations' medians differ by far more than their own sampling error. Elsewhere the
medians' scatter would only add noise; and the traffic's median is no guide where vehicles'
speeds are correlated over shorter times than it spans (the stop-and-go waves of NGSIM I-80,
where the field over every gap cost up to 3 points).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mlkm_core.types import Detections, Layout

#: neighbours on each side in a station's time order that one rolling median takes
NEIGHBOURS = 15
#: a gap whose stations' medians differ by this many standard errors (root mean square over
#: the upstream station's detections) shows a change the traffic shares: the ends of road
#: works reach 20 to 45, the gaps of free flow stay below 6, those of NGSIM I-80 below 10
MIN_Z = 10.0
#: standard error of a median over that of a mean, for Gaussian scatter
MEDIAN_EFFICIENCY = math.sqrt(math.pi / 2)


@dataclass(frozen=True)
class TrafficSlowness:
    """Median slowness of the traffic at each station against time: station k's is
    piecewise linear through (``times[k]`` [s], ``slowness[k]`` [s/m]), constant beyond the
    ends. ``positions`` [m] are the stations' (increasing): a model position is a station's.
    ``gaps`` marks the gaps whose change the vehicles follow (elsewhere the medians differ by
    their sampling error only, and a vehicle keeps its speed level)."""

    positions: np.ndarray
    times: tuple[np.ndarray, ...]
    slowness: tuple[np.ndarray, ...]
    gaps: np.ndarray  # bool, one per gap

    def at(self, k: int, t: np.ndarray) -> np.ndarray:
        """The traffic's slowness [s/m] at station ``k`` at time(s) ``t``."""
        return np.interp(t, self.times[k], self.slowness[k])

    def change(
        self,
        x1: float | np.ndarray,
        t1: float | np.ndarray,
        x2: float | np.ndarray,
        t2: float | np.ndarray,
    ) -> np.ndarray:
        """How the traffic's slowness changes from (x1, t1) to (x2, t2) [s/m]: over each
        marked gap in between, the change from its upstream station's median to its
        downstream one's, each at the time the vehicle passes it (interpolated in position
        between t1 and t2)."""
        x1, t1, x2, t2 = np.broadcast_arrays(*(np.asarray(a, float) for a in (x1, t1, x2, t2)))
        out = np.zeros(x1.shape)
        pos = self.positions
        k1, k2 = np.searchsorted(pos, x1), np.searchsorted(pos, x2)
        for g in np.flatnonzero(self.gaps):
            rows = (k1 <= g) & (k2 > g)
            if not rows.any():
                continue
            a, b, ta, tb = x1[rows], x2[rows], t1[rows], t2[rows]
            span = np.where(b > a, b - a, 1.0)
            at_g = ta + (pos[g] - a) / span * (tb - ta)
            at_next = ta + (pos[g + 1] - a) / span * (tb - ta)
            out[rows] += self.at(g + 1, at_next) - self.at(g, at_g)
        return out


def _rolling_median(values: np.ndarray, k: int) -> np.ndarray:
    """Median of each value's window of ``k`` neighbours on each side (shifted inwards at
    the ends, so that every window holds 2k + 1 values when there are that many)."""
    n = values.size
    w = min(2 * k + 1, n)
    windows = np.lib.stride_tricks.sliding_window_view(values, w)
    med = np.median(windows, axis=1)
    first = np.clip(np.arange(n) - w // 2, 0, n - w)
    return med[first]


def estimate_traffic(
    layout: Layout, d: Detections, min_z: float = MIN_Z
) -> TrafficSlowness | None:
    """Each station's rolling median slowness (``NEIGHBOURS``), followed over the gaps whose
    change stands out from the medians' sampling error by ``min_z`` standard errors (root
    mean square over the upstream station's detections; 0: over every gap); None where no gap
    does or a station has fewer than three detections."""
    n = layout.n_sensors
    if n < 2 or len(d) == 0:
        return None
    u = 1.0 / d.velocity
    times, medians, errors = [], [], []
    for s in range(n):
        idx = np.flatnonzero(d.sensor_index == s)
        if idx.size < 3:
            return None
        order = np.argsort(d.stamp[idx], kind='stable')
        t, us = d.stamp[idx][order], u[idx][order]
        times.append(t)
        medians.append(_rolling_median(us, NEIGHBOURS))
        spread = 1.4826 * float(np.median(np.abs(us - np.median(us))))
        errors.append(MEDIAN_EFFICIENCY * spread / math.sqrt(min(2 * NEIGHBOURS + 1, idx.size)))
    gaps = np.ones(n - 1, bool)
    if min_z > 0:
        for g in range(n - 1):
            shift = np.interp(times[g], times[g + 1], medians[g + 1]) - medians[g]
            rms = math.sqrt(float(np.mean(shift * shift)))
            gaps[g] = rms > min_z * max(math.hypot(errors[g], errors[g + 1]), 1e-12)
    if not gaps.any():
        return None
    return TrafficSlowness(np.asarray(layout.positions, float), tuple(times), tuple(medians), gaps)
