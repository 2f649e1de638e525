"""Self-calibration: the motion model's parameters estimated from the detections themselves.

The parameters are not given to the associators. Pass 1 links with generic parameters
(``MotionParams()``, pairwise model); from its tracks, ``calibrate`` takes moments: the speed
variogram gamma(h) = 0.5 E[(v(x + h) - v(x))^2] over pairs of detections of one track gives
sigma_v^2 (nugget), sigma^2 (sill) and L (range, by a grid search with non-negative least
squares); the trapezoid residuals of consecutive links give sigma_t; skipped sensors give
p_miss, singleton tracks the false-alarm density. ``fit_motion`` then maximises the Kalman
marginal likelihood of those tracks over (sigma, L, sigma_t, sigma_v), adds speed jumps and a
drifting cruise speed where the tracks show them. ``estimate_params`` does all three, with the
extra travel time of the gaps the speeds do not explain (``delays``) before and after.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.optimize import nnls

from mlkm_core.associators.count_curves import beside, with_count_curves
from mlkm_core.associators.delays import estimate_delay, estimate_gap_spread, gap_links
from mlkm_core.associators.entries import estimate_entries
from mlkm_core.associators.laneorder import restore_order
from mlkm_core.associators.likelihood import sequence_nll, track_sequences
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


_FIT_FIELDS = ('sigma', 'length', 'stamp_noise', 'velocity_noise')
_JUMP_FIELDS = ('jump_rate', 'jump_sigma')
#: candidate drifts of the cruise speed [m/s per km] tried against a constant cruise speed
_DRIFT_GRID = (0.5, 1.0, 2.0, 4.0, 8.0)
#: least likelihood gain per detection [nats] for the drift: above what the model's
#: approximations alone give on traffic whose targets keep their cruise speed, below what
#: car-following traffic shows (figures: docs/benchmarks.md#simulator-defaults)
DRIFT_MIN_GAIN = 0.03
#: candidate changes of a target's speed level between its first two sensors: (probability,
#: std [m/s]) tried against none
_ENTRY_GRID = tuple((q, s) for q in (0.05, 0.1, 0.2, 0.4) for s in (2.0, 4.0, 8.0))
#: least likelihood gain per detection [nats] for the change of level after the first sensor
#: (as for the drift)
ENTRY_MIN_GAIN = 0.03
#: bounds of the fitted motion parameters (both models' fits)
FIT_BOUNDS = {
    'sigma': (0.05, 50.0),
    'length': (5.0, 1e5),
    'stamp_noise': (FLOOR_T, 5.0),
    'velocity_noise': (FLOOR_V, 5.0),
    'jump_rate': (1e-6, 1.5e-3),
    'jump_sigma': (0.3, 10.0),
}
#: candidate speed-jump models (rate [1/m], std [m/s]) tried against the pure OU model
JUMP_GRID = tuple((r, s) for r in (1e-4, 3e-4, 1e-3, 3e-3) for s in (1.5, 3.0, 6.0))
FIT_FACTORS = (np.array([0.35, 0.6, 1.0, 1.7, 2.9]), np.array([0.8, 0.9, 1.0, 1.1, 1.25]))


def min_length(layout: Layout) -> float:
    """Lower bound of the fitted correlation length L [m].

    A fluctuation that decorrelates within a few sensor spacings cannot be told apart from
    speed measurement noise at this sampling, and the fit would trade one for the other; L is
    kept above 4 median spacings and a fifth of the instrumented road.
    """
    pos = layout.positions
    if pos.size < 2:
        return 5.0
    return float(max(4 * np.median(np.diff(pos)), 0.4 * (pos[-1] - pos[0]), 5.0))


def fit_motion(
    layout: Layout, d: Detections, labels: np.ndarray, p: MotionParams, max_tracks: int = 120
) -> MotionParams:
    """Maximum-likelihood motion parameters given tracks (coordinate search on log grids).

    The Kalman marginal likelihood of the tracks of a first pass is maximised over
    (sigma, L, sigma_t, sigma_v), one coordinate at a time, five values per coordinate scored
    in one batched pass; innovations are capped (``sequence_nll``) so that the few wrong links
    of the first pass do not inflate the noise estimates. Speed jumps (``_fit_jumps``) and the
    cruise speed's drift (``_fit_drift``) are switched on only where the tracks show them.
    """
    seqs = track_sequences(d, labels, min_len=3, max_tracks=max_tracks)
    n = seqs.shape[0]
    if n < 3:
        return p
    bounds = dict(FIT_BOUNDS)
    bounds['length'] = (min_length(layout), FIT_BOUNDS['length'][1])
    p = replace(p, length=float(np.clip(p.length, *bounds['length'])))
    if p.stamp_noise <= 2 * FLOOR_T:
        # the moments left nothing for the stamp noise (heavy-tailed travel times inflate the
        # fluctuation terms): start it from the most likely value of a wide grid instead
        vals = np.geomspace(FLOOR_T, 1.0, 10)
        best = int(np.argmin(_score(layout, d, seqs, p, {'stamp_noise': vals})))
        p = replace(p, stamp_noise=float(vals[best]))
    # joint coarse grid on (sigma, L), which trade off against each other, then coordinates
    fs = np.array([0.5, 0.7, 1.0, 1.4, 2.0])
    sg = np.repeat(np.clip(p.sigma * fs, *bounds['sigma']), fs.size)
    ln = np.tile(np.clip(p.length * fs, *bounds['length']), fs.size)
    rows = {f: np.full(n * sg.size, float(getattr(p, f))) for f in _FIT_FIELDS}
    rows['sigma'], rows['length'] = np.repeat(sg, n), np.repeat(ln, n)
    nll = sequence_nll(layout, d, np.tile(seqs, (sg.size, 1)), p, rows=rows)
    best = int(np.argmin(nll.reshape(sg.size, n).sum(axis=1)))
    p = replace(p, sigma=float(sg[best]), length=float(ln[best]))
    for factors in FIT_FACTORS:
        p = _coordinate_pass(layout, d, seqs, p, _FIT_FIELDS, factors, bounds)
    p = _fit_drift(layout, d, seqs, _fit_jumps(layout, d, seqs, p, bounds))
    return _fit_entry(layout, d, seqs, p)


def _score(
    layout: Layout, d: Detections, seqs: np.ndarray, p: MotionParams, values: dict[str, np.ndarray]
) -> np.ndarray:
    """Total NLL of ``seqs`` under each of k parameter sets (``values``: field -> (k,))."""
    n = seqs.shape[0]
    k = len(next(iter(values.values())))
    names = _FIT_FIELDS + _JUMP_FIELDS + ('drift', 'entry_jump', 'entry_sigma')
    rows = {f: np.full(n * k, float(getattr(p, f))) for f in names}
    for f, v in values.items():
        rows[f] = np.repeat(np.asarray(v, float), n)
    nll = sequence_nll(layout, d, np.tile(seqs, (k, 1)), p, rows=rows)
    return nll.reshape(k, n).sum(axis=1)


def _coordinate_pass(
    layout: Layout,
    d: Detections,
    seqs: np.ndarray,
    p: MotionParams,
    names: tuple[str, ...],
    factors: np.ndarray,
    bounds: dict[str, tuple[float, float]],
) -> MotionParams:
    for name in names:
        vals = np.clip(getattr(p, name) * factors, *bounds[name])
        best = int(np.argmin(_score(layout, d, seqs, p, {name: vals})))
        p = replace(p, **{name: float(vals[best])})
    return p


def _penalty(seqs: np.ndarray) -> float:
    """BIC penalty [nats] of one more parameter: half the log of the number of detections."""
    return penalty_of(int((seqs >= 0).sum()))


def penalty_of(detections: int) -> float:
    """BIC penalty [nats] of one more parameter on ``detections`` detections."""
    return 0.5 * math.log(max(int(detections), 2))


def _fit_drift(layout: Layout, d: Detections, seqs: np.ndarray, p: MotionParams) -> MotionParams:
    """Let the cruise speed drift when that explains the tracks better than a constant cruise
    speed by ``DRIFT_MIN_GAIN`` per detection (and at least a BIC penalty). The other
    parameters are not refitted: the drift is the Kalman model's alone, and the pairwise model
    keeps the parameters it links with.

    Car following adapts each vehicle's speed to its neighbours' over the road, so a speed far
    upstream says less about the speed here than a constant cruise speed assumes; on the
    product's own simulator, whose targets keep their cruise speed, the drift stays off.
    """
    drift = np.array((0.0, *_DRIFT_GRID))
    nll = _score(layout, d, seqs, p, {'drift': drift})
    best = int(np.argmin(nll))
    need = max(_penalty(seqs), DRIFT_MIN_GAIN * int((seqs >= 0).sum()))
    if best == 0 or nll[0] - nll[best] <= need:
        return p
    return replace(p, drift=float(drift[best]))


def _fit_entry(layout: Layout, d: Detections, seqs: np.ndarray, p: MotionParams) -> MotionParams:
    """Let a target's speed level change between its first two sensors when that explains the
    tracks better by ``ENTRY_MIN_GAIN`` per detection (and at least a BIC penalty for two
    parameters).

    The product's own simulator starts every target at its cruise speed; in car-following
    traffic a vehicle often enters at its desired speed and settles behind a slower leader
    only downstream. The model would otherwise learn its cruise speed from that first speed
    and rather leave the detection out of the track.
    """
    q = np.array([0.0] + [r for r, _ in _ENTRY_GRID])
    sig = np.array([p.entry_sigma] + [s for _, s in _ENTRY_GRID])
    nll = _score(layout, d, seqs, p, {'entry_jump': q, 'entry_sigma': sig})
    best = int(np.argmin(nll))
    need = max(2 * _penalty(seqs), ENTRY_MIN_GAIN * int((seqs >= 0).sum()))
    if best == 0 or nll[0] - nll[best] <= need:
        return p
    return replace(p, entry_jump=float(q[best]), entry_sigma=float(sig[best]))


def _fit_jumps(
    layout: Layout,
    d: Detections,
    seqs: np.ndarray,
    p: MotionParams,
    bounds: dict[str, tuple[float, float]],
) -> MotionParams:
    """Turn on the speed-jump component when it explains the tracks better than the pure OU
    model by more than a BIC penalty (two parameters: log of the number of detections), then
    refit every parameter with it."""
    rate = np.array([0.0] + [r for r, _ in JUMP_GRID])
    sig = np.array([p.jump_sigma] + [s for _, s in JUMP_GRID])
    nll = _score(layout, d, seqs, p, {'jump_rate': rate, 'jump_sigma': sig})
    best = int(np.argmin(nll))
    if best == 0 or nll[0] - nll[best] <= 2 * _penalty(seqs):
        return p
    p = replace(p, jump_rate=float(rate[best]), jump_sigma=float(sig[best]))
    for factors in FIT_FACTORS:
        p = _coordinate_pass(layout, d, seqs, p, _FIT_FIELDS + _JUMP_FIELDS, factors, bounds)
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
