"""The ``kalman`` motion model: a Kalman filter per track on (passage time, slowness, cruise
slowness) with the exact Ornstein-Uhlenbeck-in-distance transition (see ``motion`` for the
traffic model and the interface every motion model implements)."""

from __future__ import annotations

import numpy as np

from mlkm_core.model.motion import (
    FLOOR_T,
    FLOOR_V,
    LOG2PI,
    MotionModel,
    MotionParams,
    Prediction,
    mix_nll,
    register_model,
)


@register_model
class KalmanModel(MotionModel):
    """Track = Kalman filter on (tau, u, m) with the exact OU-in-distance transition.

    ``rows`` (optional) gives per-track parameter sets: arrays of any ``MotionParams`` field
    the filter reads (sigma, length, the noises, the jumps, the drift, the entry change), one
    entry per track (used to score many parameter sets in one pass).
    """

    name = 'kalman'
    keeps_history = True

    def __init__(self, params: MotionParams, rows: dict[str, np.ndarray] | None = None) -> None:
        super().__init__(params)
        self.rows = rows
        self.x = np.zeros(0)
        self.origin = np.zeros(0)  # position of each track's first detection [m]
        self.mean = np.zeros((0, 3))
        self.cov = np.zeros((0, 3, 3))

    def load(self, x: np.ndarray, mean: np.ndarray, cov: np.ndarray, origin: np.ndarray) -> None:
        """Replace the state of every track (copies), e.g. to continue saved filters;
        ``origin`` is the position of each track's first detection."""
        self.x, self.mean, self.cov = x.copy(), mean.copy(), cov.copy()
        self.origin = np.asarray(origin, float).copy()

    def save(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, mean, cov) of every track, for ``load``."""
        return self.x, self.mean, self.cov

    def _par(self, name: str, tracks: np.ndarray) -> float | np.ndarray:
        if self.rows is not None and name in self.rows:
            return self.rows[name][tracks]
        return getattr(self.p, name)

    def grow(self, n: int) -> None:
        self.x = np.concatenate([self.x, np.zeros(n)])
        self.origin = np.concatenate([self.origin, np.zeros(n)])
        self.mean = np.concatenate([self.mean, np.zeros((n, 3))])
        self.cov = np.concatenate([self.cov, np.zeros((n, 3, 3))])

    def noise(self, tracks: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Measurement noise variances (stamp, slowness) of detections with slowness u."""
        st = np.maximum(self._par('stamp_noise', tracks), FLOOR_T)
        sv = np.maximum(self._par('velocity_noise', tracks), FLOOR_V)
        return st * st + 0 * u, (sv * u * u) ** 2

    def start(
        self, tracks: np.ndarray, x: float | np.ndarray, t: np.ndarray, u: np.ndarray
    ) -> None:
        rt, ru = self.noise(tracks, u)
        sigma, length = self._par('sigma', tracks), self._par('length', tracks)
        # deviation from the cruise speed: zero at the road entry, OU-grown up to x
        dev = (sigma * u * u) ** 2 * (1 - np.exp(-2 * np.asarray(x) / length))
        cov = np.zeros((tracks.size, 3, 3))
        cov[:, 0, 0] = rt
        cov[:, 1, 1] = ru
        cov[:, 1, 2] = cov[:, 2, 1] = ru
        cov[:, 2, 2] = ru + dev
        self.x[tracks] = x
        self.origin[tracks] = x
        self.mean[tracks] = np.column_stack([t, u, u])
        self.cov[tracks] = cov

    def predict(self, tracks: np.ndarray, x: float | np.ndarray) -> Prediction:
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
        delay = self.p.delay
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
        if delay is not None:
            mean[:, 0] += delay.extra_time(self.x[tracks], x, m[:, 0])
            cov[:, 0, 0] += delay.extra_var(self.x[tracks], x)
        if self.p.traffic is not None:
            # the whole speed level follows the traffic's; half its change over the gap
            shift = self.p.traffic.change(self.x[tracks], m[:, 0], x, mean[:, 0])
            mean[:, 0] += d * shift / 2
            mean[:, 1] += shift
            mean[:, 2] += shift
        q01 = su2 * L * (1 - a) ** 2
        cov[:, 0, 1] += q01
        cov[:, 1, 0] += q01
        cov[:, 1, 1] += su2 * (1 - a * a)
        drift = self._par('drift', tracks)
        if np.any(np.asarray(drift) > 0):
            # the cruise slowness's random walk, taken at the start of the interval (an upper
            # bound of its effect on the passage time and slowness)
            q = (drift * m[:, 2] ** 2) ** 2 * d / 1000.0
            v = np.column_stack([f02, f12, np.ones_like(f12)])
            cov += q[:, None, None] * v[:, :, None] * v[:, None, :]
        rate = self._par('jump_rate', tracks)
        entry = self._par('entry_jump', tracks)
        if np.all(np.asarray(rate) <= 0) and np.all(np.asarray(entry) <= 0):
            return Prediction(tracks, x, mean, cov)
        # a speed jump at a uniform point of the interval: var vj in slowness, vj d^2 / 3 in
        # passage time, covariance vj d / 2
        vj = (self._par('jump_sigma', tracks) * m[:, 2] ** 2) ** 2
        pj = -np.expm1(-rate * d) + 0 * d
        # after a track's first detection: a change of its whole speed level instead (the
        # cruise speed too: the target settles behind its leader)
        fresh = (self.x[tracks] == self.origin[tracks]) & (np.asarray(entry) > 0)
        ve = (self._par('entry_sigma', tracks) * m[:, 2] ** 2) ** 2
        pj = np.where(fresh, entry, pj)
        # no jump, no component: the gate stays the plain filter's
        vj = np.where(fresh, ve, np.where(pj > 0, vj, 0.0))
        jump = np.column_stack([pj, vj * d * d / 3, vj * d / 2, vj, fresh])
        return Prediction(tracks, x, mean, cov, jump)

    def gate_window(self, pred: Prediction) -> tuple[np.ndarray, np.ndarray]:
        rt, _ = self.noise(pred.tracks, pred.mean[:, 1])
        var = pred.cov[:, 0, 0] + rt
        if pred.jump is not None:
            var = var + pred.jump[:, 1]
        return pred.mean[:, 0], np.sqrt(self.p.gate * var)

    @staticmethod
    def _with_jump(cov: np.ndarray, jump: np.ndarray) -> np.ndarray:
        out = cov.copy()
        out[:, 0, 0] += jump[:, 1]
        out[:, 0, 1] += jump[:, 2]
        out[:, 1, 0] += jump[:, 2]
        out[:, 1, 1] += jump[:, 3]
        # a level change moves the cruise slowness with the slowness
        level = jump[:, 4]
        out[:, 0, 2] += level * jump[:, 2]
        out[:, 2, 0] += level * jump[:, 2]
        out[:, 1, 2] += level * jump[:, 3]
        out[:, 2, 1] += level * jump[:, 3]
        out[:, 2, 2] += level * jump[:, 3]
        return out

    @staticmethod
    def _innovation(
        mean: np.ndarray, cov: np.ndarray, rt: np.ndarray, ru: np.ndarray, t: np.ndarray, u
    ) -> tuple[np.ndarray, ...]:
        """Innovation covariance S = H P H^T + R as (s00, s11, s01, det S) and the innovation
        (y0, y1) of the measurement (t, u), per row."""
        s00 = cov[:, 0, 0] + rt
        s11 = cov[:, 1, 1] + ru
        s01 = cov[:, 0, 1]
        return s00, s11, s01, s00 * s11 - s01 * s01, t - mean[:, 0], u - mean[:, 1]

    @classmethod
    def _cost(
        cls, mean: np.ndarray, cov: np.ndarray, rt: np.ndarray, ru: np.ndarray, t: np.ndarray, u
    ) -> tuple[np.ndarray, np.ndarray]:
        s00, s11, s01, det, y0, y1 = cls._innovation(mean, cov, rt, ru, t, u)
        d2 = (s11 * y0 * y0 - 2 * s01 * y0 * y1 + s00 * y1 * y1) / det
        return 0.5 * (d2 + np.log(det)) + LOG2PI, d2

    def cost(
        self, pred: Prediction, t: np.ndarray, u: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        rt, ru = self.noise(pred.tracks, u)
        nll, d2 = self._cost(pred.mean, pred.cov, rt, ru, t, u)
        if pred.jump is None:
            return nll, d2
        cov1 = self._with_jump(pred.cov, pred.jump)
        nll1, d21 = self._cost(pred.mean, cov1, rt, ru, t, u)
        return mix_nll(nll, d2, nll1, d21, pred.jump[:, 0])

    @classmethod
    def _update(
        cls, mean: np.ndarray, cov: np.ndarray, rt: np.ndarray, ru: np.ndarray, t: np.ndarray, u
    ) -> tuple[np.ndarray, np.ndarray]:
        s00, s11, s01, det, y0, y1 = cls._innovation(mean, cov, rt, ru, t, u)
        i00, i11, i01 = s11 / det, s00 / det, -s01 / det
        pc0, pc1 = cov[:, :, 0], cov[:, :, 1]  # P H^T columns
        k0 = pc0 * i00[:, None] + pc1 * i01[:, None]
        k1 = pc0 * i01[:, None] + pc1 * i11[:, None]
        new_mean = mean + k0 * y0[:, None] + k1 * y1[:, None]
        new_cov = cov - k0[:, :, None] * cov[:, 0, None, :] - (k1[:, :, None] * cov[:, 1, None, :])
        return new_mean, new_cov

    def update(self, pred: Prediction, t: np.ndarray, u: np.ndarray) -> None:
        mean, cov, tracks = pred.mean, pred.cov, pred.tracks
        rt, ru = self.noise(tracks, u)
        m0, c0 = self._update(mean, cov, rt, ru, t, u)
        if pred.jump is not None:
            # the mixture posterior collapsed to its first two moments
            cov1 = self._with_jump(cov, pred.jump)
            nll0, _ = self._cost(mean, cov, rt, ru, t, u)
            nll1, _ = self._cost(mean, cov1, rt, ru, t, u)
            pj = pred.jump[:, 0]
            with np.errstate(divide='ignore', invalid='ignore'):
                z = np.log(pj) - nll1 - (np.log1p(-pj) - nll0)
            w1 = np.where(np.isfinite(z), 1 / (1 + np.exp(-np.clip(z, -50, 50))), 0.0)
            m1, c1 = self._update(mean, cov1, rt, ru, t, u)
            w0 = 1 - w1
            mm = w0[:, None] * m0 + w1[:, None] * m1
            e0, e1 = m0 - mm, m1 - mm
            c0 = w0[:, None, None] * (c0 + e0[:, :, None] * e0[:, None, :]) + w1[:, None, None] * (
                c1 + e1[:, :, None] * e1[:, None, :]
            )
            m0 = mm
        self.mean[tracks] = m0
        self.cov[tracks] = c0
        self.x[tracks] = pred.x
