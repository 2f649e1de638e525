"""Maximum-likelihood fit of the Kalman motion model's parameters given a first pass's tracks.

``fit_motion`` maximises the Kalman marginal likelihood of the tracks over (sigma, L, sigma_t,
sigma_v), one coordinate at a time on log grids, then switches on speed jumps, a drifting
cruise speed and a change of speed level after the first sensor only where the tracks show
them by more than a BIC penalty (``penalty_of``). ``calibration.estimate_params`` calls it
after the moments; the bounds and grids are shared with the pairwise model's own fit
(``pairwise_fit``) and the network's (``network_assoc.fit``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from mlkm_core.associators.likelihood import sequence_nll, track_sequences
from mlkm_core.model.motion import FLOOR_T, FLOOR_V, MotionParams
from mlkm_core.types import Detections, Layout

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
