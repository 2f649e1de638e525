"""Sensor-to-sensor tracking engine behind ``assignment`` and ``multiframe`` (issue 4).

Travel along the road is modelled in *slowness* u = 1/v [s/m], in which the passage time is
linear: tau(x2) = tau(x1) + int u dx. The simulator's speed is an Ornstein-Uhlenbeck process
in distance around each target's cruise speed (correlation length L, stationary std sigma);
in slowness that is, to first order, an OU process around the cruise slowness m with std
sigma_u = sigma * m^2. Stamps and speeds carry Gaussian noise sigma_t, sigma_v.

Two track models share the engine (same gating, dummies and calibration):

* ``PairwiseModel`` (``assignment``): a track is its last detection. The cost of linking it to a
  detection at the next sensor is the Gaussian NLL of two residuals, each scaled by its
  variance: the travel time predicted from the speeds at *both* ends (trapezoid in slowness),
  e_t = t2 - t1 - dx (u1 + u2) / 2, var = 2 sigma_t^2 + dx^2 (var u1 + var u2) / 4
  + sigma_u^2 dx^3 / (6 L) (a Brownian bridge of the fluctuation between two known ends), and
  the slowness change e_u = u2 - u1, var = 2 var_u,noise + 2 sigma_u^2 (1 - exp(-dx / L))
  (the stationary OU increment).
* ``KalmanModel`` (``multiframe``): a track is a Kalman filter over position with the state
  (tau, u, m): passage time, slowness and the target's own cruise slowness. The exact OU
  transition (and its integral, for tau) is used, so every past detection of the track
  informs the prediction: the cruise slowness m is learnt over several sensors (the speed
  reverts to it) and noisy stamps/speeds are averaged. This is the "more than two sensors"
  evidence that pairwise assignment cannot use.

The engine walks the sensors in road order. At each sensor the active tracks (last seen at
most ``max_skip`` sensors back) are gated in predicted passage time against the detections,
and the gated pairs are solved as a one-to-one assignment with dummies (``linking``): a track
left unmatched is a miss (cost -log p_miss per skipped sensor, carried forward with the growing
variance of the longer gap), a detection left unmatched starts a new track (cost -log kappa,
kappa = clutter density). At the end a track of a single detection is a false alarm and is
labelled UNASSIGNED.

Calibration (``calibrate``): the model parameters are not given to the associators; they are
estimated from the data. Pass 1 links with generic parameters; from its tracks, the speed
variogram gamma(h) = 0.5 E[(v(x + h) - v(x))^2] over pairs of detections of one track gives
sigma_v^2 (nugget), sigma^2 (sill) and L (range, by a grid search with non-negative least
squares); the trapezoid residuals of consecutive links give sigma_t; skipped sensors give
p_miss, singleton tracks the false-alarm density. Pass 2 links with these estimates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import nnls

from mlkm_core.associators.linking import by_sensor, gate_pairs, match_sparse, relabel
from mlkm_core.types import Detections, Layout

LOG2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class MotionParams:
    """Parameters of the traffic and sensor model (estimated by ``calibrate``)."""

    sigma: float = 2.0  # stationary std of the speed fluctuation [m/s]
    length: float = 500.0  # correlation length L of the fluctuation [m]
    stamp_noise: float = 0.1  # sigma_t [s]
    velocity_noise: float = 0.2  # sigma_v [m/s]
    p_miss: float = 0.02  # probability that a passage is not reported
    clutter_density: float = 1e-3  # false alarms per sensor per second per (s/m) of slowness
    gate: float = 36.0  # chi-square gate on the normalised innovation (6 sigma)
    max_skip: int = 3  # a track may miss this many consecutive sensors

    @property
    def miss_cost(self) -> float:
        return -math.log(self.p_miss)

    @property
    def new_cost(self) -> float:
        return -math.log(self.clutter_density)


FLOOR_T = 1e-3  # [s] floor of sigma_t (paper mode has exact stamps)
FLOOR_V = 1e-3  # [m/s] floor of sigma_v


class PairwiseModel:
    """Track = its last detection; pairwise cost on travel time and slowness continuity."""

    def __init__(self, p: MotionParams) -> None:
        self.p = p
        self.x = np.zeros(0)
        self.t = np.zeros(0)
        self.u = np.zeros(0)

    def grow(self, n: int) -> None:
        self.x = np.concatenate([self.x, np.zeros(n)])
        self.t = np.concatenate([self.t, np.zeros(n)])
        self.u = np.concatenate([self.u, np.zeros(n)])

    def start(self, tracks: np.ndarray, x: float, t: np.ndarray, u: np.ndarray) -> None:
        self.x[tracks], self.t[tracks], self.u[tracks] = x, t, u

    def update(
        self,
        tracks: np.ndarray,
        x: float,
        t: np.ndarray,
        u: np.ndarray,
        pos: np.ndarray | None = None,
    ) -> None:
        self.start(tracks, x, t, u)

    def _var_u_noise(self, u: np.ndarray) -> np.ndarray:
        return (max(self.p.velocity_noise, FLOOR_V) * u * u) ** 2

    def gate_window(self, tracks: np.ndarray, x: float) -> tuple[np.ndarray, np.ndarray]:
        dx = x - self.x[tracks]
        u = self.u[tracks]
        var_du = 2 * self._var_u_noise(u) + 2 * (self.p.sigma * u * u) ** 2 * (
            1 - np.exp(-dx / self.p.length)
        )
        var_t = (
            2 * max(self.p.stamp_noise, FLOOR_T) ** 2
            + dx * dx * var_du
            + (self.p.sigma * u * u) ** 2 * dx**3 / (6 * self.p.length)
        )
        return self.t[tracks] + dx * u, np.sqrt(self.p.gate * var_t)

    def pair_cost(
        self,
        tracks: np.ndarray,
        x: float,
        t: np.ndarray,
        u: np.ndarray,
        pos: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(NLL, squared Mahalanobis distance) of linking each track to each detection."""
        p = self.p
        dx = x - self.x[tracks]
        u1 = self.u[tracks]
        su2 = (p.sigma * u1 * u) ** 2  # sigma_u^2 with m^2 ~ u1 u2
        vn1, vn2 = self._var_u_noise(u1), self._var_u_noise(u)
        e_t = t - self.t[tracks] - dx * (u1 + u) / 2
        var_t = (
            2 * max(p.stamp_noise, FLOOR_T) ** 2
            + dx * dx * (vn1 + vn2) / 4
            + su2 * dx**3 / (6 * p.length)
        )
        e_u = u - u1
        var_u = vn1 + vn2 + 2 * su2 * (1 - np.exp(-dx / p.length))
        d2 = e_t * e_t / var_t + e_u * e_u / var_u
        return 0.5 * (d2 + np.log(var_t * var_u)) + LOG2PI, d2


class KalmanModel:
    """Track = Kalman filter on (tau, u, m) with the exact OU-in-distance transition.

    ``rows`` (optional) gives per-track parameter sets: arrays of sigma, length, stamp and
    velocity noise, one entry per track (used to score many parameter sets in one pass).
    """

    def __init__(self, p: MotionParams, rows: dict[str, np.ndarray] | None = None) -> None:
        self.p = p
        self.rows = rows
        self.x = np.zeros(0)
        self.mean = np.zeros((0, 3))
        self.cov = np.zeros((0, 3, 3))
        self._cache: tuple | None = None

    def _par(self, name: str, tracks: np.ndarray) -> float | np.ndarray:
        if self.rows is not None and name in self.rows:
            return self.rows[name][tracks]
        return getattr(self.p, name)

    def grow(self, n: int) -> None:
        self.x = np.concatenate([self.x, np.zeros(n)])
        self.mean = np.concatenate([self.mean, np.zeros((n, 3))])
        self.cov = np.concatenate([self.cov, np.zeros((n, 3, 3))])
        self._cache = None

    def _r(self, tracks: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        st = np.maximum(self._par('stamp_noise', tracks), FLOOR_T)
        sv = np.maximum(self._par('velocity_noise', tracks), FLOOR_V)
        return st * st + 0 * u, (sv * u * u) ** 2

    def start(
        self, tracks: np.ndarray, x: float | np.ndarray, t: np.ndarray, u: np.ndarray
    ) -> None:
        rt, ru = self._r(tracks, u)
        sigma, length = self._par('sigma', tracks), self._par('length', tracks)
        # deviation from the cruise speed: zero at the road entry, OU-grown up to x
        dev = (sigma * u * u) ** 2 * (1 - np.exp(-2 * np.asarray(x) / length))
        cov = np.zeros((tracks.size, 3, 3))
        cov[:, 0, 0] = rt
        cov[:, 1, 1] = ru
        cov[:, 1, 2] = cov[:, 2, 1] = ru
        cov[:, 2, 2] = ru + dev
        self.x[tracks] = x
        self.mean[tracks] = np.column_stack([t, u, u])
        self.cov[tracks] = cov
        self._cache = None

    def predict(self, tracks: np.ndarray, x: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = self._cache
        if c is not None and c[0] is tracks and np.isscalar(x) and c[1] == x:
            return c[2], c[3]
        d = x - self.x[tracks]
        L = self._par('length', tracks)
        a = np.exp(-d / L)
        z = d / L
        small = z < 1e-3
        zs = np.where(small, z, 0.0)
        i_var = (
            np.where(small, (2 / 3) * zs**3 - 0.5 * zs**4, 2 * z - 3 + 4 * a - a * a) * L * L
        )  # Var of int of OU / sigma_u^2
        b = L * (1 - a)
        m = self.mean[tracks]
        P = self.cov[tracks]
        su2 = (self._par('sigma', tracks) * m[:, 2] ** 2) ** 2
        f01, f02, f11, f12 = b, d - b, a, 1 - a
        mean = np.column_stack(
            [m[:, 0] + f01 * m[:, 1] + f02 * m[:, 2], f11 * m[:, 1] + f12 * m[:, 2], m[:, 2]]
        )
        # F P F^T with F = [[1, f01, f02], [0, f11, f12], [0, 0, 1]], done by rows
        r0 = P[:, 0, :] + f01[:, None] * P[:, 1, :] + f02[:, None] * P[:, 2, :]
        r1 = f11[:, None] * P[:, 1, :] + f12[:, None] * P[:, 2, :]
        r2 = P[:, 2, :]
        cov = np.empty_like(P)
        for i, r in enumerate((r0, r1, r2)):
            cov[:, i, 0] = r[:, 0] + f01 * r[:, 1] + f02 * r[:, 2]
            cov[:, i, 1] = f11 * r[:, 1] + f12 * r[:, 2]
            cov[:, i, 2] = r[:, 2]
        cov[:, 0, 0] += su2 * np.maximum(i_var, 0)
        q01 = su2 * L * (1 - a) ** 2
        cov[:, 0, 1] += q01
        cov[:, 1, 0] += q01
        cov[:, 1, 1] += su2 * (1 - a * a)
        if np.isscalar(x):
            self._cache = (tracks, x, mean, cov)
        return mean, cov

    def gate_window(self, tracks: np.ndarray, x: float) -> tuple[np.ndarray, np.ndarray]:
        mean, cov = self.predict(tracks, x)
        rt, _ = self._r(tracks, mean[:, 1])
        return mean[:, 0], np.sqrt(self.p.gate * (cov[:, 0, 0] + rt))

    def innovation(
        self, tracks: np.ndarray, mean: np.ndarray, cov: np.ndarray, t: np.ndarray, u: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(NLL, squared Mahalanobis distance) of measurements given predictions."""
        rt, ru = self._r(tracks, u)
        s00 = cov[:, 0, 0] + rt
        s11 = cov[:, 1, 1] + ru
        s01 = cov[:, 0, 1]
        det = s00 * s11 - s01 * s01
        y0 = t - mean[:, 0]
        y1 = u - mean[:, 1]
        d2 = (s11 * y0 * y0 - 2 * s01 * y0 * y1 + s00 * y1 * y1) / det
        return 0.5 * (d2 + np.log(det)) + LOG2PI, d2

    def pair_cost(
        self,
        tracks: np.ndarray,
        x: float,
        t: np.ndarray,
        u: np.ndarray,
        pos: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Cost of track ``tracks[i]`` for detection i; ``pos`` indexes a cached prediction."""
        if pos is not None and self._cache is not None:
            mean, cov = self._cache[2][pos], self._cache[3][pos]
        else:
            mean, cov = self.predict(tracks, x)
        return self.innovation(tracks, mean, cov, t, u)

    def update(
        self,
        tracks: np.ndarray,
        x: float | np.ndarray,
        t: np.ndarray,
        u: np.ndarray,
        pos: np.ndarray | None = None,
    ) -> None:
        if pos is not None and self._cache is not None:
            mean, cov = self._cache[2][pos], self._cache[3][pos]
        else:
            mean, cov = self.predict(tracks, x)
        rt, ru = self._r(tracks, u)
        s00 = cov[:, 0, 0] + rt
        s11 = cov[:, 1, 1] + ru
        s01 = cov[:, 0, 1]
        det = s00 * s11 - s01 * s01
        i00, i11, i01 = s11 / det, s00 / det, -s01 / det
        pc0, pc1 = cov[:, :, 0], cov[:, :, 1]  # P H^T columns
        k0 = pc0 * i00[:, None] + pc1 * i01[:, None]
        k1 = pc0 * i01[:, None] + pc1 * i11[:, None]
        y0 = t - mean[:, 0]
        y1 = u - mean[:, 1]
        self.mean[tracks] = mean + k0 * y0[:, None] + k1 * y1[:, None]
        self.cov[tracks] = (
            cov - k0[:, :, None] * cov[:, 0, None, :] - (k1[:, :, None] * cov[:, 1, None, :])
        )
        self.x[tracks] = x
        self._cache = None


MODELS = {'pairwise': PairwiseModel, 'kalman': KalmanModel}


def link(
    layout: Layout, detections: Detections, params: MotionParams, model: str = 'pairwise'
) -> np.ndarray:
    """Sequential sensor-to-sensor assignment; returns raw track ids (no singleton pruning)."""
    n_s = layout.n_sensors
    per_sensor = by_sensor(detections, n_s)
    labels = np.full(len(detections), -1, dtype=np.int64)
    m = MODELS[model](params)
    last_sensor = np.zeros(0, dtype=np.int64)
    n_tracks = 0
    u_all = 1.0 / detections.velocity
    for s in range(n_s):
        idx = per_sensor[s]
        x = float(layout.positions[s])
        t, u = detections.stamp[idx], u_all[idx]
        active = np.flatnonzero(last_sensor >= s - 1 - params.max_skip)
        matched_d = np.zeros(0, np.int64)
        if active.size and idx.size:
            centre, half = m.gate_window(active, x)
            r, c = gate_pairs(centre, half, t)
            if r.size:
                nll, d2 = m.pair_cost(active[r], x, t[c], u[c], pos=r)
                skipped = s - 1 - last_sensor[active[r]]
                w = nll + skipped * params.miss_cost - params.miss_cost - params.new_cost
                w = np.where(d2 <= params.gate, w, 0.0)
                mr, mc = match_sparse(r, c, w, active.size, idx.size)
                if mr.size:
                    tr = active[mr]
                    m.update(tr, x, t[mc], u[mc], pos=mr)
                    last_sensor[tr] = s
                    labels[idx[mc]] = tr
                    matched_d = mc
        new = np.setdiff1d(np.arange(idx.size), matched_d)
        if new.size:
            ids = np.arange(n_tracks, n_tracks + new.size)
            n_tracks += new.size
            m.grow(new.size)
            last_sensor = np.concatenate([last_sensor, np.full(new.size, s)])
            m.start(ids, x, t[new], u[new])
            labels[idx[new]] = ids
    return labels


def _variogram_fit(
    layout: Layout, d: Detections, labels: np.ndarray, max_pairs: int = 200_000
) -> tuple[float, float, float] | None:
    """(nugget sigma_v, sill sigma, range L) of the speed variogram over same-track pairs."""
    keep = labels >= 0
    if keep.sum() < 10:
        return None
    lab, x, v = labels[keep], layout.positions[d.sensor_index[keep]], d.velocity[keep]
    order = np.lexsort((x, lab))
    lab, x, v = lab[order], x[order], v[order]
    h_all, g_all = [], []
    n = lab.size
    for lag in range(1, 12):
        if lag >= n:
            break
        same = lab[lag:] == lab[:-lag]
        h_all.append((x[lag:] - x[:-lag])[same])
        g_all.append(0.5 * (v[lag:] - v[:-lag])[same] ** 2)
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
    """Estimate the model parameters from the tracks of a first pass (see module doc)."""
    labels = relabel(raw)
    fit = _variogram_fit(layout, d, labels)
    p = base
    if fit is not None:
        nug, sill, L = fit
        p = replace(p, velocity_noise=max(nug, FLOOR_V), sigma=max(sill, 0.05), length=L)
    keep = labels >= 0
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
    _ = keep
    return p


def sequence_nll(
    layout: Layout,
    d: Detections,
    seqs: np.ndarray,
    params: MotionParams,
    birth: np.ndarray | None = None,
    end: np.ndarray | None = None,
    rows: dict[str, np.ndarray] | None = None,
    state: dict | None = None,
    finish: bool = True,
) -> np.ndarray | tuple[np.ndarray, dict]:
    """Kalman marginal NLL of each detection sequence (rows of ``seqs``, -1 = no detection).

    Columns are visited in order; a row's entries must have increasing sensors (gaps allowed).
    Every further detection pays its (capped) innovation NLL plus the miss cost per skipped
    sensor, as in the forward pass. A sequence flagged ``birth`` (the track starts here) pays
    the new-track cost and, if it has two detections or more, the miss cost of every sensor
    before its first detection (capped at ``max_skip + 1``: targets enter before the first
    sensor); one flagged ``end`` (the track ends here) with two detections or more pays the
    miss cost of every sensor after its last one (capped at 10). A single detection is a
    false alarm: the new-track cost only. ``rows`` optionally gives per-row motion parameters
    (see ``KalmanModel``). ``state`` continues rows from a returned state (``finish=False``
    returns ``(nll so far, state)`` without the birth / end costs).
    """
    n_seq, width = seqs.shape
    birth = np.ones(n_seq, bool) if birth is None else birth
    end = np.zeros(n_seq, bool) if end is None else end
    m = KalmanModel(params, rows)
    if state is None:
        m.grow(n_seq)
        out = np.zeros(n_seq)
        last = np.full(n_seq, -1, dtype=np.int64)
        first_sensor = np.zeros(n_seq, dtype=np.int64)
        count = np.zeros(n_seq, dtype=np.int64)
    else:
        m.x, m.mean, m.cov = state['x'].copy(), state['mean'].copy(), state['cov'].copy()
        out, last = state['out'].copy(), state['last'].copy()
        first_sensor, count = state['first_sensor'].copy(), state['count'].copy()
    count = count + (seqs >= 0).sum(axis=1)
    u_all = 1.0 / d.velocity
    cap = 4 * params.gate
    for k in range(width):
        col = seqs[:, k]
        live = np.flatnonzero(col >= 0)
        if live.size == 0:
            continue
        det = col[live]
        s = d.sensor_index[det]
        x = layout.positions[s]
        t, u = d.stamp[det], u_all[det]
        first = last[live] < 0
        if first.any():
            r0 = live[first]
            m.start(r0, x[first], t[first], u[first])
            out[r0] += np.where(birth[r0], params.new_cost, 0.0)
            first_sensor[r0] = s[first]
        nxt = ~first
        if nxt.any():
            r1 = live[nxt]
            mean, cov = m.predict(r1, x[nxt])
            nll, d2 = m.innovation(r1, mean, cov, t[nxt], u[nxt])
            nll = nll - 0.5 * np.maximum(d2 - cap, 0.0)
            out[r1] += nll + (s[nxt] - last[r1] - 1) * params.miss_cost
            m._cache = (r1, None, mean, cov)
            m.update(r1, x[nxt], t[nxt], u[nxt], pos=np.arange(r1.size))
        last[live] = s
    if not finish:
        return out, {
            'x': m.x,
            'mean': m.mean,
            'cov': m.cov,
            'out': out,
            'last': last,
            'first_sensor': first_sensor,
            'count': count,
        }
    # a track (two detections or more) that starts late or ends early missed the sensors
    # before / after it; a single detection is a false alarm and pays the new-track cost only
    n_s = layout.n_sensors
    several = count >= 2
    born = birth & several
    out[born] += np.minimum(first_sensor[born], params.max_skip + 1) * params.miss_cost
    ended = end & several
    out[ended] += np.minimum(n_s - 1 - last[ended], 10) * params.miss_cost
    return out


def _take_state(state: dict, idx: np.ndarray) -> dict:
    return {k: v[idx] for k, v in state.items()}


def _candidates(
    layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, s): a detection of track B at sensor s is in the time gate of the pairwise
    prediction from track A's last detection before s."""
    n_s = layout.n_sensors
    per_sensor = by_sensor(d, n_s)
    u_all = 1.0 / d.velocity
    n_tracks = int(labels.max()) + 1 if (labels >= 0).any() else 0
    last_det = np.full(n_tracks, -1, dtype=np.int64)
    out_a, out_b, out_s = [], [], []
    for s in range(n_s):
        idx = per_sensor[s]
        if s > 0 and idx.size:
            ld = last_det[last_det >= 0]
            act = ld[d.sensor_index[ld] >= s - 1 - params.max_skip]
            if act.size:
                pw = PairwiseModel(params)
                pw.grow(act.size)
                ids = np.arange(act.size)
                pw.start(ids, layout.positions[d.sensor_index[act]], d.stamp[act], u_all[act])
                x = float(layout.positions[s])
                centre, half = pw.gate_window(ids, x)
                r, c = gate_pairs(centre, half * CANDIDATE_GATE, d.stamp[idx])
                a, b = labels[act[r]], labels[idx[c]]
                ok = (a != b) & (b >= 0)
                out_a.append(a[ok])
                out_b.append(b[ok])
                out_s.append(np.full(int(ok.sum()), s))
        lab = labels[idx]
        last_det[lab[lab >= 0]] = idx[lab >= 0]
    if not out_a:
        z = np.zeros(0, np.int64)
        return z, z, z
    return np.concatenate(out_a), np.concatenate(out_b), np.concatenate(out_s)


#: exchange lengths tried for each candidate: the whole tail (0) or 1, 2, 3, 5 sensors
MOVES = (0, 1, 2, 3, 5)
#: candidate time window as a fraction of the tracking gate (4 of 6 sigma)
CANDIDATE_GATE = 4 / 6


def refine(
    layout: Layout,
    d: Detections,
    labels: np.ndarray,
    params: MotionParams,
    window: int = 6,
    rounds: int = 10,
) -> np.ndarray:
    """Local search on track exchanges, scored by Kalman likelihood over several sensors.

    A move (A, B, s, k) exchanges between tracks A and B their detections at sensors
    [s, s + k) (k = 1, 2), or their whole tails from s on (k = 0, a 2-opt exchange; when B
    starts at s it stitches B onto A). Candidates are the gated pairs (A's last detection
    before s, a detection of B at s). Each move is scored by the Kalman marginal NLL of the
    four sequences (old A, B and new A, B) restricted to sensors [s - window, s + window),
    with the birth / early-end costs of tracks that start or end inside the window; improving
    moves are applied greedily, each track at most once per round; the next round looks only
    at moves that involve a track changed in the round before.
    """
    n_s = layout.n_sensors
    valid = np.flatnonzero(labels >= 0)
    if valid.size == 0:
        return labels.copy()
    n_tracks = int(labels.max()) + 1
    M = np.full((n_tracks, n_s), -1, dtype=np.int64)
    M[labels[valid], d.sensor_index[valid]] = valid
    dirty = np.ones(n_tracks, bool)
    offs = np.arange(-window, window)
    cur = labels.copy()
    for _ in range(rounds):
        ca, cb, cs = _candidates(layout, d, cur, params)
        sel = dirty[ca] | dirty[cb]
        ca, cb, cs = ca[sel], cb[sel], cs[sel]
        if ca.size == 0:
            break
        # one move per unordered pair and sensor
        key = np.unique(np.column_stack([np.minimum(ca, cb), np.maximum(ca, cb), cs]), axis=0)
        ca, cb, cs = key[:, 0], key[:, 1], key[:, 2]
        has = M >= 0
        first_s = np.where(has.any(axis=1), has.argmax(axis=1), n_s)
        last_s = np.where(has.any(axis=1), n_s - 1 - has[:, ::-1].argmax(axis=1), -1)
        cols = cs[:, None] + offs[None, :]
        inside = (cols >= 0) & (cols < n_s)
        cc = np.clip(cols, 0, n_s - 1)
        wa = np.where(inside, M[ca[:, None], cc], -1)
        wb = np.where(inside, M[cb[:, None], cc], -1)
        lo, hi = cs - window, cs + window
        a_born, b_born = first_s[ca] >= lo, first_s[cb] >= lo
        a_more, b_more = last_s[ca] >= hi, last_s[cb] >= hi
        # the prefix (sensors before s) is the same for old and new sequences: filter it
        # once, then continue every old and new suffix from the prefix state of its owner
        n_c = ca.size
        birth2 = np.concatenate([a_born, b_born])
        _, pre = sequence_nll(
            layout,
            d,
            np.concatenate([wa[:, :window], wb[:, :window]]),
            params,
            birth2,
            finish=False,
        )
        sa, sb = wa[:, window:], wb[:, window:]
        suf, owner, end = [sa, sb], [np.arange(n_c), n_c + np.arange(n_c)], [~a_more, ~b_more]
        for k in MOVES:
            region = (cols[:, window:] >= cs[:, None]) & (
                (cols[:, window:] < cs[:, None] + k) if k else True
            )
            suf += [np.where(region, sb, sa), np.where(region, sa, sb)]
            owner += [np.arange(n_c), n_c + np.arange(n_c)]
            end += [~b_more, ~a_more] if k == 0 else [~a_more, ~b_more]
        owner = np.concatenate(owner)
        nll = sequence_nll(
            layout,
            d,
            np.concatenate(suf),
            params,
            birth2[owner],
            np.concatenate(end),
            state=_take_state(pre, owner),
        ).reshape(len(suf), -1)
        gain = np.stack(
            [nll[2 + 2 * j] + nll[3 + 2 * j] - nll[0] - nll[1] for j in range(len(MOVES))], axis=1
        )  # (n_cand, n_moves)
        flat = np.flatnonzero(gain.ravel() < -1e-6)
        if flat.size == 0:
            break
        used = np.zeros(n_tracks, bool)
        dirty[:] = False
        for i in flat[np.argsort(gain.ravel()[flat], kind='stable')].tolist():
            c, j = divmod(i, len(MOVES))
            a, b, s = int(ca[c]), int(cb[c]), int(cs[c])
            if used[a] or used[b]:
                continue
            used[a] = used[b] = dirty[a] = dirty[b] = True
            e = n_s if MOVES[j] == 0 else min(s + MOVES[j], n_s)
            tmp = M[a, s:e].copy()
            M[a, s:e] = M[b, s:e]
            M[b, s:e] = tmp
        t_idx, s_idx = np.nonzero(M >= 0)
        cur = np.full(labels.size, -1, dtype=np.int64)
        cur[M[t_idx, s_idx]] = t_idx
    return cur


def track_sequences(
    d: Detections,
    labels: np.ndarray,
    min_len: int = 3,
    max_tracks: int | None = None,
    seed: int = 0,
) -> np.ndarray:
    """Detections of each track ordered by sensor, as rows of a -1 padded matrix."""
    valid = np.flatnonzero(labels >= 0)
    if valid.size == 0:
        return np.zeros((0, 0), dtype=np.int64)
    order = valid[np.lexsort((d.sensor_index[valid], labels[valid]))]
    ids, starts, counts = np.unique(labels[order], return_index=True, return_counts=True)
    keep = np.flatnonzero(counts >= min_len)
    if max_tracks is not None and keep.size > max_tracks:
        keep = np.sort(np.random.default_rng(seed).choice(keep, max_tracks, replace=False))
    if keep.size == 0:
        return np.zeros((0, 0), dtype=np.int64)
    width = int(counts[keep].max())
    seqs = np.full((keep.size, width), -1, dtype=np.int64)
    pos = np.arange(width)
    mask = pos[None, :] < counts[keep][:, None]
    seqs[mask] = order[(starts[keep][:, None] + pos[None, :])[mask]]
    return seqs


_FIT_FIELDS = ('sigma', 'length', 'stamp_noise', 'velocity_noise')
_FIT_BOUNDS = {
    'sigma': (0.05, 50.0),
    'length': (5.0, 1e5),
    'stamp_noise': (FLOOR_T, 5.0),
    'velocity_noise': (FLOOR_V, 5.0),
}
_FIT_FACTORS = (np.array([0.35, 0.6, 1.0, 1.7, 2.9]), np.array([0.8, 0.9, 1.0, 1.1, 1.25]))


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
    of the first pass do not inflate the noise estimates.
    """
    seqs = track_sequences(d, labels, min_len=3, max_tracks=max_tracks)
    n = seqs.shape[0]
    if n < 3:
        return p
    bounds = dict(_FIT_BOUNDS)
    bounds['length'] = (min_length(layout), _FIT_BOUNDS['length'][1])
    p = replace(p, length=float(np.clip(p.length, *bounds['length'])))
    # joint coarse grid on (sigma, L), which trade off against each other, then coordinates
    fs = np.array([0.5, 0.7, 1.0, 1.4, 2.0])
    sg = np.repeat(np.clip(p.sigma * fs, *bounds['sigma']), fs.size)
    ln = np.tile(np.clip(p.length * fs, *bounds['length']), fs.size)
    rows = {f: np.full(n * sg.size, float(getattr(p, f))) for f in _FIT_FIELDS}
    rows['sigma'], rows['length'] = np.repeat(sg, n), np.repeat(ln, n)
    nll = sequence_nll(layout, d, np.tile(seqs, (sg.size, 1)), p, rows=rows)
    best = int(np.argmin(nll.reshape(sg.size, n).sum(axis=1)))
    p = replace(p, sigma=float(sg[best]), length=float(ln[best]))
    for factors in _FIT_FACTORS:
        for name in _FIT_FIELDS:
            lo, hi = bounds[name]
            vals = np.clip(getattr(p, name) * factors, lo, hi)
            rows = {f: np.full(n * vals.size, float(getattr(p, f))) for f in _FIT_FIELDS}
            rows[name] = np.repeat(vals, n)
            nll = sequence_nll(layout, d, np.tile(seqs, (vals.size, 1)), p, rows=rows)
            best = int(np.argmin(nll.reshape(vals.size, n).sum(axis=1)))
            p = replace(p, **{name: float(vals[best])})
    return p


def estimate_params(layout: Layout, d: Detections) -> tuple[MotionParams, np.ndarray]:
    """Self-calibration: pass 1 with generic parameters, then moments, then maximum likelihood.

    Returns the parameters and the raw track ids of pass 1.
    """
    base = MotionParams()
    raw = link(layout, d, base, 'pairwise')
    p = calibrate(layout, d, raw, base)
    p = fit_motion(layout, d, relabel(raw), p)
    return p, raw


def canonical(detections: Detections) -> np.ndarray:
    """Order in which the tracking associators read detections (input order independent)."""
    return np.lexsort((detections.velocity, detections.stamp, detections.sensor_index))


def total_nll(layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams) -> float:
    """Negative log-likelihood of a whole labelling under the Kalman model (comparable between
    labellings of the same detections: every detection is in a track or a false alarm)."""
    seqs = track_sequences(d, labels, min_len=1)
    n = seqs.shape[0]
    if n == 0:
        return 0.0
    ones = np.ones(n, bool)
    return float(sequence_nll(layout, d, seqs, params, ones, ones).sum())
