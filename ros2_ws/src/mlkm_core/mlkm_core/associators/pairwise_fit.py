"""The pairwise model's parameters, fitted under its own likelihood.

``kalman_fit.fit_motion`` fits the fluctuation and noise parameters (sigma, L, sigma_t,
sigma_v, speed jumps) under the Kalman model's marginal likelihood. That model credits every
vehicle with a cruise speed it returns to; the pairwise model (``motion.PairwiseModel``: a
track is its last detection) knows nothing of it, and where traffic has no such persistence
(stop-and-go: a vehicle's deviations from the traffic around it are uncorrelated from one
station gap to the next, on NGSIM I-80 r = -0.2 to 0.13) the values the Kalman likelihood
prefers make the pairwise cost expect the wrong scatter of the travel time and the speed
change: on NGSIM I-80 at five loops 100 m apart, sigma 7.9 m/s over L 7 km, whose variance per
metre (sigma^2 / L) is a third of what the links show. ``fit_pairwise`` maximises the pairwise
model's own likelihood of the links of a pass instead and keeps the result beside the Kalman
fit (``MotionParams.pairwise_fit``), so that each model links with its own parameters.

Where the traffic does have that persistence (the product's simulator, free-flowing SUMO
traffic), the Kalman model predicts the links better (``kalman_lead`` < 0) and its values are
the traffic's own; the pairwise model, an approximation of it, links better with them than
with its own fit (on the simulator's clutter, 200 targets x 50 sensors, 97.7 % against
97.6 %). ``own_fit`` keeps them there.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mlkm_core.associators.likelihood import sequence_nll, track_sequences
from mlkm_core.model.motion import MotionParams, PairwiseModel
from mlkm_core.types import Detections, Layout, link_pairs

#: the fields fitted (those the pairwise cost reads besides the gate and the delays)
FIELDS = ('sigma', 'length', 'stamp_noise', 'velocity_noise')
JUMP_FIELDS = ('jump_rate', 'jump_sigma')
#: fewest links on which the two models' predictions are compared (``kalman_lead``)
MIN_LEAD_LINKS = 10
#: most links scored per candidate (a seeded sample beyond)
MAX_LINKS = 20_000
#: fewest links the six parameters are fitted on (below, the Kalman fit's values stay): fitted
#: on the few links of the stream's first windows when a bag is replayed at full speed, the
#: model left 160 of 359 detections of a ``make demo-stream`` bag unassigned; every batch
#: input of the benchmarks has several hundred links
MIN_LINKS = 100


def _links(
    layout: Layout, d: Detections, labels: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(x, t, u) of both ends of the links of ``labels`` (a seeded sample of ``MAX_LINKS``)."""
    a, b = link_pairs(d, labels)
    if a.size > MAX_LINKS:
        keep = np.sort(np.random.default_rng(0).choice(a.size, MAX_LINKS, replace=False))
        a, b = a[keep], b[keep]
    x = layout.positions
    u = 1.0 / d.velocity
    return x[d.sensor_index[a]], d.stamp[a], u[a], x[d.sensor_index[b]], d.stamp[b], u[b]


def pairwise_nll(links: tuple[np.ndarray, ...], p: MotionParams) -> float:
    """Summed pairwise NLL of ``links`` (``_links``) under ``p``, each link's squared distance
    capped at 4 gates as in the likelihood of tracks, so the first pass's few wrong links do
    not decide."""
    xa, ta, ua, xb, tb, ub = links
    m = PairwiseModel(replace(p, cues=None, pairwise_fit=None))
    rows = np.arange(xa.size)
    m.grow(xa.size)
    m.start(rows, xa, ta, ua)
    with np.errstate(all='ignore'):
        nll, d2 = m.cost(m.predict(rows, xb), tb, ub)
        total = float(np.sum(nll - 0.5 * np.maximum(d2 - 4 * p.gate, 0.0)))
    return total if np.isfinite(total) else np.inf


def _coordinates(
    links: tuple[np.ndarray, ...],
    p: MotionParams,
    names: tuple[str, ...],
    factors: tuple[np.ndarray, ...],
    bounds: dict[str, tuple[float, float]],
) -> MotionParams:
    for f in factors:
        for name in names:
            vals = np.clip(getattr(p, name) * f, *bounds[name])
            scores = [pairwise_nll(links, replace(p, **{name: float(v)})) for v in vals]
            p = replace(p, **{name: float(vals[int(np.argmin(scores))])})
    return p


def fit_pairwise(
    layout: Layout,
    d: Detections,
    labels: np.ndarray,
    p: MotionParams,
    bounds: dict[str, tuple[float, float]],
    factors: tuple[np.ndarray, ...],
    jump_grid: tuple[tuple[float, float], ...],
    penalty: float,
) -> MotionParams:
    """``p`` with ``pairwise_fit``: the pairwise model's own fit (``fit_links``) on the links
    of ``labels``. Fewer than ``MIN_LINKS`` links leave ``p`` as it is."""
    fit = fit_links(_links(layout, d, labels), p, bounds, factors, jump_grid, penalty)
    return p if fit is None else replace(p, pairwise_fit=fit)


def fit_links(
    links: tuple[np.ndarray, ...],
    p: MotionParams,
    bounds: dict[str, tuple[float, float]],
    factors: tuple[np.ndarray, ...],
    jump_grid: tuple[tuple[float, float], ...],
    penalty: float,
) -> tuple[tuple[str, float], ...] | None:
    """The pairwise model's maximum-likelihood (sigma, L, sigma_t, sigma_v) and speed jumps, as
    (field, value) pairs, on ``links`` (x [m], t [s], u [s/m] of both ends, as ``_links`` gives
    them), by coordinate search from the values of ``p`` (``factors`` per pass, within
    ``bounds``). Speed jumps stay on where they gain more than ``penalty`` [nats] (two
    parameters) over the pure OU model with the same other parameters, as in the Kalman fit.
    None with fewer than ``MIN_LINKS`` links."""
    if links[0].size < MIN_LINKS:
        return None
    q = _coordinates(links, replace(p, jump_rate=0.0), FIELDS, factors, bounds)
    candidates = [(q.jump_rate, q.jump_sigma)] + list(jump_grid)
    if p.jump_rate > 0:
        candidates.append((p.jump_rate, p.jump_sigma))
    scores = [pairwise_nll(links, replace(q, jump_rate=r, jump_sigma=s)) for r, s in candidates]
    best = int(np.argmin(scores))
    if best > 0 and scores[0] - scores[best] > penalty:
        r, s = candidates[best]
        q = _coordinates(
            links, replace(q, jump_rate=r, jump_sigma=s), FIELDS + JUMP_FIELDS, factors, bounds
        )
    return tuple((name, float(getattr(q, name))) for name in FIELDS + JUMP_FIELDS)


def kalman_lead(layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams) -> float:
    """NLL per link [nats] of the Kalman model minus that of the pairwise model, each with its
    own parameters, on the links of ``labels`` (< 0: the Kalman model predicts them better;
    0 with fewer than ``MIN_LEAD_LINKS`` links).

    Both give the density of a track's next detection (stamp, slowness) given its earlier ones,
    so their summed log-likelihoods over the same links (capped as in ``sequence_nll``, lane
    and length left out: they are the same in both) are comparable; the Kalman model conditions
    on the whole history and wins where its structure (a cruise speed the target reverts to)
    holds.
    """
    return lead_per_link(kalman_evidence(layout, d, labels, params))


def lead_per_link(evidence: tuple[float, float]) -> float:
    """The Kalman model's lead per link [nats] of (summed lead [nats], links): 0 on fewer
    than ``MIN_LEAD_LINKS`` links."""
    total, links = evidence
    return total / links if links >= MIN_LEAD_LINKS else 0.0


def kalman_evidence(
    layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams
) -> tuple[float, float]:
    """(summed NLL [nats] of the Kalman model minus the pairwise model's, links) over the
    links of ``labels`` (``kalman_lead`` per link); (0, 0) with fewer than
    ``MIN_LEAD_LINKS``."""
    p = replace(params, cues=None)
    a, b = link_pairs(d, labels)
    if a.size < MIN_LEAD_LINKS:
        return 0.0, 0.0
    m = PairwiseModel(p)
    m.grow(a.size)
    rows = np.arange(a.size)
    x = layout.positions
    u = 1.0 / d.velocity
    m.start(rows, x[d.sensor_index[a]], d.stamp[a], u[a])
    nll, d2 = m.cost(m.predict(rows, x[d.sensor_index[b]]), d.stamp[b], u[b])
    pairwise = float(np.sum(nll - 0.5 * np.maximum(d2 - 4 * p.gate, 0.0)))
    seqs = track_sequences(d, labels, min_len=2)
    none = np.zeros(seqs.shape[0], bool)
    kalman = float(sequence_nll(layout, d, seqs, p, none, none).sum())
    skipped = float((d.sensor_index[b] - d.sensor_index[a] - 1).sum()) * p.miss_cost
    return kalman - skipped - pairwise, float(a.size)


def own_fit(
    layout: Layout, d: Detections, labels: np.ndarray, p: MotionParams, fitted: MotionParams
) -> MotionParams:
    """``fitted`` (``p`` with the pairwise model's own fit, ``fit_pairwise``) where the Kalman
    model does not predict the links of ``labels`` better than the pairwise model with that
    fit (``kalman_lead``); else ``p`` as it is: the Kalman fit is the traffic's."""
    with np.errstate(all='ignore'):
        lead = kalman_lead(layout, d, labels, fitted)
    return p if np.isfinite(lead) and lead < 0 else fitted
