"""Self-calibration: the motion model's parameters estimated from the detections themselves.

The parameters are not given to the associators. Pass 1 links with generic parameters
(``MotionParams()``, pairwise model); from its tracks, ``calibrate`` takes moments: the speed
variogram gamma(h) = 0.5 E[(v(x + h) - v(x))^2] over pairs of detections of one track gives
sigma_v^2 (nugget), sigma^2 (sill) and L (range, by a grid search with non-negative least
squares); the trapezoid residuals of consecutive links give sigma_t; skipped sensors give
p_miss, singleton tracks the false-alarm density. ``kalman_fit.fit_motion`` then maximises the
Kalman marginal likelihood of those tracks over (sigma, L, sigma_t, sigma_v), adds speed jumps
and a drifting cruise speed where the tracks show them. ``estimate_params`` does all three,
with the extra travel time of the gaps the speeds do not explain (``delays``) before and after.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from mlkm_core.associators.count_curves import beside, with_count_curves
from mlkm_core.associators.delays import estimate_delay, estimate_gap_spread, gap_links
from mlkm_core.associators.entries import estimate_entries
from mlkm_core.associators.kalman_fit import (
    FIT_BOUNDS,
    FIT_FACTORS,
    JUMP_GRID,
    fit_motion,
    penalty_of,
)
from mlkm_core.associators.laneorder import restore_order
from mlkm_core.associators.linking import link, relabel
from mlkm_core.associators.merges import estimate_lane_delays, estimate_yields, mend_merges
from mlkm_core.associators.pairwise_fit import fit_pairwise, own_fit
from mlkm_core.associators.repair import repaired
from mlkm_core.model.catalogue import bind_cues, fit_cues, generic_cues, refined_kinds
from mlkm_core.model.gap_delays import GapDelays
from mlkm_core.model.motion import FLOOR_T, FLOOR_V, MotionParams
from mlkm_core.model.traffic import TrafficSlowness, estimate_traffic
from mlkm_core.progress import stage
from mlkm_core.types import Detections, Layout


def _variogram_fit(
    layout: Layout,
    d: Detections,
    labels: np.ndarray,
    traffic: TrafficSlowness | None = None,
    max_pairs: int = 200_000,
) -> tuple[float, float, float] | None:
    """(nugget sigma_v, sill sigma, range L) of the speed variogram over same-track pairs;
    of each speed's departure from the ``traffic``'s where it is given."""
    from scipy.optimize import nnls  # half a second to import: on first use

    keep = labels >= 0
    if keep.sum() < 10:
        return None
    lab, x, v = labels[keep], layout.positions[d.sensor_index[keep]], d.velocity[keep]
    t = d.stamp[keep]
    order = np.lexsort((x, lab))
    lab, x, v, t = lab[order], x[order], v[order], t[order]
    h_all, g_all = [], []
    n = lab.size
    for lag in range(1, 12):
        if lag >= n:
            break
        same = lab[lag:] == lab[:-lag]
        h_all.append((x[lag:] - x[:-lag])[same])
        ahead = v[:-lag][same]  # the speed the vehicle would have if it followed the traffic
        if traffic is not None:
            a = np.flatnonzero(same)
            b = a + lag
            ahead = 1.0 / (1.0 / ahead + traffic.change(x[a], t[a], x[b], t[b]))
        g_all.append(0.5 * (v[lag:][same] - ahead) ** 2)
    h = np.concatenate(h_all)
    g = np.concatenate(g_all)
    if h.size < 10:
        return None
    if h.size > max_pairs:
        sel = np.random.default_rng(0).choice(h.size, max_pairs, replace=False)
        h, g = h[sel], g[sel]
    # robust: drop gross outliers (wrong links) before fitting
    cut = np.quantile(g, 0.99)
    h, g = h[g <= cut], g[g <= cut]
    # bin by lag distance so that dense short lags do not dominate
    edges = np.unique(np.quantile(h, np.linspace(0, 1, 25)))
    if edges.size < 3:
        return None
    b = np.clip(np.searchsorted(edges, h, side='right') - 1, 0, edges.size - 2)
    cnt = np.bincount(b, minlength=edges.size - 1)
    ok = cnt > 0
    hb = np.bincount(b, h, edges.size - 1)[ok] / cnt[ok]
    gb = np.bincount(b, g, edges.size - 1)[ok] / cnt[ok]
    wb = np.sqrt(cnt[ok])
    best = None
    for L in np.geomspace(50, 20000, 40):
        A = np.column_stack([np.ones_like(hb), 1 - np.exp(-hb / L)]) * wb[:, None]
        coef, res = nnls(A, gb * wb)
        if best is None or res < best[0]:
            best = (res, coef, L)
    _, (nug, sill), L = best
    return math.sqrt(nug), math.sqrt(sill), float(L)


def calibrate(layout: Layout, d: Detections, raw: np.ndarray, base: MotionParams) -> MotionParams:
    """Moment estimates of the model parameters from the raw track ids of a first pass."""
    labels = relabel(raw)
    fit = _variogram_fit(layout, d, labels, base.traffic)
    p = base
    if fit is not None:
        nug, sill, L = fit
        p = replace(p, velocity_noise=max(nug, FLOOR_V), sigma=max(sill, 0.05), length=L)
    x = layout.positions[d.sensor_index]
    order = np.lexsort((x, labels))
    lab, xs, ts, us, ss = (
        labels[order],
        x[order],
        d.stamp[order],
        1 / d.velocity[order],
        d.sensor_index[order],
    )
    same = (lab[1:] == lab[:-1]) & (lab[1:] >= 0)
    if same.sum() >= 10:
        dx = (xs[1:] - xs[:-1])[same]
        e_t = (ts[1:] - ts[:-1])[same] - dx * (us[1:] + us[:-1])[same] / 2
        e_t = e_t - p.extra_time(xs[:-1][same], xs[1:][same], ts[:-1][same])
        u2 = (us[1:] * us[:-1])[same]
        known = dx * dx * (p.velocity_noise**2) * u2 * u2 / 2 + (p.sigma * u2) ** 2 * dx**3 / (
            6 * p.length
        )
        r2 = e_t * e_t
        cut = np.quantile(r2, 0.98)
        ok = r2 <= cut
        st2 = max(float(np.mean(r2[ok] - known[ok])) / 2, 0.0)
        # the 2% trim removes the tail of the Gaussian too: undo its shrinkage (chi2_1)
        st2 /= 0.80
        p = replace(p, stamp_noise=max(math.sqrt(st2), FLOOR_T))
        skipped = ((ss[1:] - ss[:-1])[same] - 1).sum()
        slots = (ss[1:] - ss[:-1])[same].sum() + np.unique(lab[lab >= 0]).size
        p = replace(p, p_miss=float(np.clip(skipped / max(slots, 1), 1e-3, 0.5)))
    n_single = int(((raw >= 0) & (labels < 0)).sum())
    n_s = layout.n_sensors
    span = np.ptp(d.stamp) if len(d) else 1.0
    u = 1 / d.velocity
    u_spread = math.sqrt(2 * math.pi) * max(float(np.std(u)), 1e-6)
    rate = max(n_single / n_s, 0.01)
    p = replace(p, clutter_density=rate / max(span, 1.0) / u_spread)
    return p


#: rounds of estimating each law of a merge and mending the tracks with it (the second
#: estimate, from tracks that follow the first, is the one kept)
LANE_ROUNDS = 2
#: share of ``estimate_params``' time that pass 1 takes (``mlkm_core.progress``; the rest, the
#: estimates and their passes, reports only its end) [-]
FIRST_PASS_SHARE = 0.5  # 0.33 measured on 10^5 detections, 0.63 on 10^6


def estimate_params(
    layout: Layout,
    d: Detections,
    openings: tuple[np.ndarray, np.ndarray] | None = None,
    whole_passages: bool = True,
) -> MotionParams:
    """Self-calibration: pass 1 with generic parameters, then moments, then maximum likelihood.

    With cues in the data (lane, length, ...), pass 1 uses them with generic parameters, their
    own parameters are fitted from its links (``model.catalogue.fit_cues``), and a second
    pairwise pass with everything calibrated gives the tracks of the final estimates; a cue
    learnt from the very tracks it changes (the order within a lane) is refined over its own
    rounds of link passes. Where the first pass shows a holdup that changes with time (a
    queue that builds and clears), the gap's extra time follows the stations' count curves
    (``count_curves``); ``openings`` (``MotionParams.road_openings``; None: a closed road) say
    between which stations vehicles enter or leave, where counts do not pair vehicles. Where
    the stations' median speeds show a change every vehicle shares (``model.traffic``: the
    end of road works), the models follow it from the moments on, once the gaps' extra times
    are settled (the first pass and the delays are chosen without it).

    ``whole_passages``: every vehicle in ``d`` is seen at every station it passes, so the
    stations' counts pair vehicles. False for a stream window: it cuts the vehicles in transit
    at both its ends, the k-th vehicle up a gap is not the k-th down it, and the count curves
    are left out.
    """
    base = MotionParams()
    cues = generic_cues(layout, d)
    if cues is not None:
        base = replace(base, cues=cues)
    with stage(0.0, FIRST_PASS_SHARE):
        raw = link(layout, d, base, 'pairwise')
    with stage(FIRST_PASS_SHARE, 1.0, detail=False):
        return _estimate_from(layout, d, base, cues, raw, openings, whole_passages)


def _estimate_from(
    layout: Layout,
    d: Detections,
    base: MotionParams,
    cues,
    raw: np.ndarray,
    openings: tuple[np.ndarray, np.ndarray] | None = None,
    whole_passages: bool = True,
) -> MotionParams:
    """``estimate_params`` after pass 1 (``raw``, with ``base``)."""
    if whole_passages:
        base, raw = with_count_curves(layout, d, base, raw, openings)
    delay = beside(estimate_delay(layout, d, relabel(raw)), base.delay)
    if delay is not None:
        # keep the extra time only in gaps where it lets clearly more tracks through (a delay
        # that changes with time, as in a growing queue, links no better)
        before = gap_links(layout, d, relabel(raw))
        trial = link(layout, d, replace(base, delay=delay), 'pairwise')
        gain = gap_links(layout, d, relabel(trial)) > 1.2 * before + 2
        extra = np.where(gain, delay.gap_time, 0.0)
        if np.all(gain[extra != 0]) and gain.any():
            base, raw = replace(base, delay=delay), trial
        elif gain.any():
            delay = GapDelays.per_gap(layout.positions, extra, np.zeros_like(extra))
            base = replace(base, delay=beside(delay, base.delay))
            raw = link(layout, d, base, 'pairwise')
    traffic = estimate_traffic(layout, d)
    if traffic is not None:
        base = replace(base, traffic=traffic)
        raw = link(layout, d, base, 'pairwise')
    p = calibrate(layout, d, raw, base)
    if cues is not None:
        p = replace(p, cues=bind_cues(layout, d, fit_cues(layout, d, relabel(raw))))
        raw = link(layout, d, p, 'pairwise')
        p = calibrate(layout, d, raw, p)
        fitted = fit_cues(layout, d, relabel(raw))
        p = replace(p, cues=bind_cues(layout, d, fitted))
        p, raw = _refine_cues(layout, d, p, fitted, raw)
    labels = relabel(raw)
    # the gaps whose travel times scatter beyond the calibrated model (a stop-and-go queue)
    p = estimate_gap_spread(layout, d, labels, fit_motion(layout, d, labels, p))
    if cues is not None and p.delay is not None and np.any(p.delay.gap_var > 0):
        # ... and, among them, the merges (``merges``): first the lanes' own delays, then the
        # delay of the cars that let a merging car in; each estimated from the tracks of the
        # pass with the gaps' spreads, then again from those mended with the first estimate
        raw = link(layout, d, p, 'pairwise')
        tracks = restore_order(layout, d, raw, p)
        for estimate, found in ((estimate_lane_delays, 'lanes'), (estimate_yields, 'yields')):
            for _ in range(LANE_ROUNDS):
                p = estimate(layout, d, relabel(tracks), p)
                if not getattr(p.delay, found):
                    break
                tracks = restore_order(layout, d, mend_merges(layout, d, raw, p), p)
    # the pairwise model's own fit where the traffic does not follow the Kalman model, on the
    # tracks it links under the calibrated model (one round of linking and refitting: a second
    # moves the accuracy on NGSIM I-80 by at most 0.2 points)
    tracks = relabel(repaired(layout, d, link(layout, d, p, 'pairwise'), p))
    penalty = 2 * penalty_of(int((tracks >= 0).sum()))
    fitted = fit_pairwise(layout, d, tracks, p, FIT_BOUNDS, FIT_FACTORS, JUMP_GRID, penalty)
    p = own_fit(layout, d, tracks, p, fitted)
    if not whole_passages:
        return p  # a stream window's tracks begin and end at its edges, not where they enter
    # where tracks begin and end mid-road without a partner a break would leave (``entries``)
    on_road = estimate_entries(layout, d, tracks, replace(p, open_road=openings))
    return replace(on_road, open_road=p.open_road)


def _refine_cues(
    layout: Layout, d: Detections, p: MotionParams, fitted: dict, raw: np.ndarray
) -> tuple[MotionParams, np.ndarray]:
    """Fit each cue learnt from the very tracks it changes (``CueKind.rounds``) and refine it
    over its rounds of link passes; returns the parameters and the last pass's tracks."""
    for kind in refined_kinds():
        value = kind.fit(layout, d, relabel(raw))
        if value is None:
            continue
        for _ in range(kind.rounds):
            p = replace(p, cues=bind_cues(layout, d, {**fitted, kind.name: value}))
            raw = link(layout, d, p, 'pairwise')
            value = kind.fit(layout, d, relabel(raw))
        fitted = {**fitted, kind.name: value}
        p = replace(p, cues=bind_cues(layout, d, fitted))
    return p, raw
