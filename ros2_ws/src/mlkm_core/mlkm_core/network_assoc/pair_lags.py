"""The time lost at each junction before any link is made: from every pair of detections across it.

A first pass needs a time lost per connection to gate and cost its links with. A generous
generic one (``junctions.GENERIC_LOSS``: a wait of up to 90 s) cuts out no vehicle held at a
red light, but on a long, busy input it lets every detection compete with hundreds of others
across a junction: the pass links most crossings wrongly, and the fits that follow learn
from those links and do not get back.

The counts carry the estimate without links. Take every pair (i at the station before the
connection, j at the one after it, later) of the hop that crosses that connection alone, and
its excess travel time over the generic motion model's prediction (``pair_excess``). The
pairs of two different vehicles spread smoothly over the excess; those of one vehicle pile
up at its time lost. In ``BIN`` bins over ``RANGE`` (``peak_loss``):

* **The background** is the least-squares line through the bins every pair can reach, away
  from the highest bin and ``TAIL`` either side of it, and the counts' dispersion about it
  over Poisson's (a signal's platoons make the background wave).
* **The peak** is the highest bin where a background that even holds would reach its count
  with a chance below ``PEAK_CHANCE`` in some bin (quasi-Poisson: counts scaled down by the
  dispersion); it grows over the neighbouring bins that still stand ``GROW_SIGMAS`` out. Its
  counts above the background give the time lost's mean and variance (which hold the motion
  model's own scatter too: a first pass's gate is the wider for it).
* **Waiters.** A red light holds some vehicles for up to its red: they fill a stretch beside
  the peak of those that arrived on green. Where the bins from the peak out to some bin up
  to ``TAIL`` away on either side stand more than ``TAIL_SIGMAS`` standard deviations above
  the background, the peak is not the whole of the time lost; and where that test could not
  have seen as many waiters as the peak holds vehicles spread over ``POWER_SPAN`` (a red of a
  minute), a quiet junction is not known to have none. In both cases the connection keeps
  the generic time lost, as does one where no peak stands out.
"""

from __future__ import annotations

import math

import numpy as np

from mlkm_core.associators.gating import runs
from mlkm_core.model.motion import MotionParams, trapezoid_residual
from mlkm_core.network import RoadNetwork
from mlkm_core.network_assoc.hops import Hops
from mlkm_core.network_assoc.junctions import JunctionModel, generic_junctions
from mlkm_core.types import Detections

#: width of the excess's bins [s]
BIN = 2.0
#: range of the excess searched [s]: from a vehicle faster than predicted to a long wait
RANGE = (-60.0, 300.0)
#: largest chance that the background reaches the peak bin's count in some bin
PEAK_CHANCE = 1e-6
#: a neighbouring bin joins the peak where it stands this many background sigmas out
GROW_SIGMAS = 2.0
#: extent [s] either side of the peak searched for a red light's waiters
TAIL = 120.0
#: waiters beside the peak of this many sigmas of the background keep the generic loss
TAIL_SIGMAS = 4.0
#: [s] over which the waiters test must have seen as many waiters as the peak's vehicles
POWER_SPAN = 60.0


def pair_excess(hops: Hops, d: Detections, h: int) -> tuple[np.ndarray, np.ndarray]:
    """(excess [s], its predicted travel time [s]) of every pair across hop ``h`` inside
    ``RANGE``: detection i at its source station, j at its destination, later than i."""
    p = MotionParams()
    a = np.flatnonzero(d.sensor_index == hops.src[h])
    b = np.flatnonzero(d.sensor_index == hops.dst[h])
    if a.size == 0 or b.size == 0:
        return np.zeros(0), np.zeros(0)
    b = b[np.argsort(d.stamp[b], kind='stable')]
    tb = d.stamp[b]
    dx = float(hops.distance[h])
    u = 1.0 / d.velocity
    slow = dx * (u[a] + u[b].max()) / 2 + p.extra_time(0.0, dx)
    lo = np.searchsorted(tb, d.stamp[a], 'right')
    hi = np.searchsorted(tb, d.stamp[a] + slow + RANGE[1], 'right')
    rows, j = runs(lo, hi, b)
    i = a[rows]
    zero = np.zeros(i.size)
    e, _ = trapezoid_residual(p, zero, zero + dx, d.stamp[i], d.stamp[j], u[i], u[j])
    pred = d.stamp[j] - d.stamp[i] - e
    keep = (e >= RANGE[0]) & (e < RANGE[1])
    return e[keep], pred[keep]


def _log_tail(k: float, lam: float) -> float:
    """log P(X >= k) for X Poisson(lam), k > lam (the first term and a geometric bound)."""
    log_pmf = k * math.log(lam) - lam - math.lgamma(k + 1.0)
    return log_pmf - math.log1p(-lam / (k + 1.0))


def _background(centre: np.ndarray, counts: np.ndarray, fit: np.ndarray):
    """The least-squares line through ``counts`` of the bins ``fit``: (its value per bin, the
    counts' dispersion over Poisson's, the covariance of its two coefficients, the design)."""
    x = np.column_stack([np.ones(centre.size), centre])
    xtx_inv = np.linalg.inv(x[fit].T @ x[fit])
    beta = xtx_inv @ (x[fit].T @ counts[fit])
    line = np.maximum(x @ beta, 0.5)
    phi = max(float(np.sum((counts[fit] - line[fit]) ** 2 / line[fit])) / (fit.sum() - 2), 1.0)
    return line, phi, xtx_inv * float(line[fit].mean()) * phi, x


def _waiters(excess: np.ndarray, noise: np.ndarray, x: np.ndarray, cov: np.ndarray) -> float:
    """The largest sum of the bins' ``excess`` over the background, in its standard
    deviations (the counts' variance ``noise`` and the line's own error, ``x`` its design
    and ``cov`` its coefficients' covariance), from the peak's edge out to each bin (in
    order away from the peak): a red light's waiters fill a stretch as long as its red."""
    s = np.cumsum(x, axis=0)
    var = np.cumsum(noise) + np.einsum('ij,jk,ik->i', s, cov, s)
    return float(np.max(np.cumsum(excess) / np.sqrt(var)))


def peak_loss(excess: np.ndarray, pred: np.ndarray) -> tuple[float, float] | None:
    """(mean [s], variance [s^2]) of the time lost at the peak of the pairs' ``excess`` [s]
    (``pred``: their predicted travel times [s]), or None: no peak stands out, waiters lie
    beside it, or too few pairs to tell (module docstring)."""
    if excess.size == 0:
        return None
    edges = np.arange(RANGE[0], RANGE[1] + BIN / 2, BIN)
    centre = (edges[:-1] + edges[1:]) / 2
    counts = np.histogram(excess, edges)[0].astype(float)
    # bins every pair can reach (a later detection: excess > -predicted travel time)
    feasible = edges[:-1] >= -float(pred.min())
    k = int(np.argmax(np.where(feasible, counts, -1.0)))
    lo, hi = k, k + 1
    tail = int(TAIL / BIN)
    for _ in range(2):  # the background without the peak and its tail, then the peak on it
        fit = feasible.copy()
        fit[max(lo - tail, 0) : hi + tail] = False
        if fit.sum() < 10:
            return None
        line, phi, cov, x = _background(centre, counts, fit)
        bar = line + GROW_SIGMAS * np.sqrt(phi * line)
        lo, hi = k, k + 1
        while lo > 0 and feasible[lo - 1] and counts[lo - 1] > bar[lo - 1]:
            lo -= 1
        while hi < counts.size and counts[hi] > bar[hi]:
            hi += 1
    if counts[k] <= line[k]:
        return None
    # quasi-Poisson: counts and background scaled down by the dispersion
    chance = _log_tail(counts[k] / phi, float(line[k]) / phi) + math.log(feasible.sum())
    if chance > math.log(PEAK_CHANCE):
        return None
    before = np.arange(lo - 1, max(lo - tail, 0) - 1, -1)
    sides = [before[feasible[before]], np.arange(hi, min(hi + tail, counts.size))]
    if any(
        _waiters(counts[s] - line[s], phi * line[s], x[s], cov) > TAIL_SIGMAS
        for s in sides
        if s.size
    ):
        return None
    w = counts[lo:hi] - line[lo:hi]
    # the waiters test must have been able to see as many waiters as the peak's vehicles
    span = slice(hi, min(hi + int(POWER_SPAN / BIN), counts.size))
    if w.sum() < TAIL_SIGMAS * math.sqrt(phi * float(line[span].sum())):
        return None
    mean = float(np.average(centre[lo:hi], weights=w))
    var = float(np.average((centre[lo:hi] - mean) ** 2, weights=w)) + BIN**2 / 12
    return mean, var


def pair_junctions(net: RoadNetwork, hops: Hops, d: Detections) -> JunctionModel:
    """The first pass's junction model: equal turn shares, and per connection the time lost
    at the peak of the pairs across the hop that crosses it alone, where one stands out, else
    the generic one (module docstring)."""
    model = generic_junctions(net)
    offsets, spreads = dict(model.offsets), dict(model.spreads)
    for h in range(hops.size):
        if hops.skipped[h] or len(hops.turns[h]) != 1:
            continue
        found = peak_loss(*pair_excess(hops, d, h))
        if found is not None:
            c = hops.turns[h][0]
            offsets[c], spreads[c] = found
    return JunctionModel(model.shares, offsets, spreads)
