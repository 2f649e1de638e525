"""Motion models of a target along the road, shared by the tracking associators.

Travel along the road is modelled in *slowness* u = 1/v [s/m], in which the passage time is
linear: tau(x2) = tau(x1) + int u dx. The simulator's speed is an Ornstein-Uhlenbeck process
in distance around each target's cruise speed (correlation length L, stationary std sigma);
in slowness that is, to first order, an OU process around the cruise slowness m with std
sigma_u = sigma * m^2. Stamps and speeds carry Gaussian noise sigma_t, sigma_v.

A :class:`MotionModel` holds the state of many tracks (arrays indexed by track id) and offers
the few operations the linker and the likelihood need: start tracks, predict them to a
position, a gating window, the cost of a measurement given a prediction, and the update.
Two models, chosen by name (``link.make_model``):

* ``pairwise`` (:class:`PairwiseModel`, used by ``assignment``): a track is its last
  detection. The cost of linking it to a detection at the next sensor is the Gaussian NLL of
  two residuals, each scaled by its variance: the travel time predicted from the speeds at
  *both* ends (trapezoid in slowness), e_t = t2 - t1 - dx (u1 + u2) / 2,
  var = 2 sigma_t^2 + dx^2 (var u1 + var u2) / 4 + sigma_u^2 dx^3 / (6 L) (a Brownian bridge
  of the fluctuation between two known ends), both corrected by the extra time of the gaps
  crossed where there is one (``GapDelays``: its mean and variance), and the slowness change
  e_u = u2 - u1,
  var = 2 var_u,noise + 2 sigma_u^2 (1 - exp(-dx / L)) (the stationary OU increment).
* ``kalman`` (``kalman.KalmanModel``, used by ``multiframe``): a track is a Kalman filter over
  position with the state (tau, u, m): passage time, slowness and the target's own cruise
  slowness. The exact OU transition (and its integral, for tau) is used, so every past
  detection of the track informs the prediction: the cruise slowness m is learnt over several
  sensors (the speed reverts to it) and noisy stamps/speeds are averaged. In car-following
  traffic the cruise speed itself drifts with the traffic around a vehicle (``drift``, a
  random walk of m in distance), so that detections far upstream weigh less, and a vehicle
  may be seen first before it has settled behind its leader (``entry_jump``: its speed level
  may change between its first two sensors).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np

from mlkm_core.model.cues import CueSet
from mlkm_core.model.gap_delays import GapDelays
from mlkm_core.model.traffic import TrafficSlowness
from mlkm_core.registry import Registry

LOG2PI = math.log(2.0 * math.pi)
FLOOR_T = 1e-3  # [s] floor of sigma_t (paper mode has exact stamps)
FLOOR_V = 1e-3  # [m/s] floor of sigma_v


#: most sensors a track that ends before the last one is charged a miss for
END_MISSES = 10


@dataclass(frozen=True)
class MotionParams:
    """Parameters of the traffic and sensor model (estimated by ``calibration``)."""

    sigma: float = 2.0  # stationary std of the speed fluctuation [m/s]
    length: float = 500.0  # correlation length L of the fluctuation [m]
    stamp_noise: float = 0.1  # sigma_t [s]
    velocity_noise: float = 0.2  # sigma_v [m/s]
    p_miss: float = 0.02  # probability that a passage is not reported
    clutter_density: float = 1e-3  # false alarms per sensor per second per (s/m) of slowness
    gate: float = 36.0  # chi-square gate on the normalised innovation (6 sigma)
    max_skip: int = 3  # a track may miss this many consecutive sensors
    # abrupt speed changes (car following: braking behind a leader, accelerating after
    # overtaking): with probability 1 - exp(-jump_rate dx) over a distance dx the speed jumps
    # by N(0, jump_sigma^2) at a uniformly distributed point; 0 = pure OU model
    jump_rate: float = 0.0  # [1/m]
    jump_sigma: float = 4.0  # [m/s]
    # the cruise speed itself drifts (a random walk in distance: car following adapts it to
    # the traffic around), std of its change over 1 km [m/s]; 0 = each target keeps its own
    drift: float = 0.0
    # a target seen first before it has settled behind its leader: with probability
    # entry_jump its speed level (cruise speed included) changes by N(0, entry_sigma^2)
    # between its first two sensors; 0 = every target is seen first at its cruise speed
    entry_jump: float = 0.0
    entry_sigma: float = 4.0  # [m/s]
    # open road, per sensor: the first sensor a track seen first there could have passed (after
    # the last entry upstream) and the last one a track seen last there could pass (before the
    # first exit downstream); None: a closed road (0 and n_sensors - 1)
    open_road: tuple[np.ndarray, np.ndarray] | None = field(
        default=None, compare=False, repr=False
    )
    # per sensor, the share of the tracks passing it that begin there / end there although
    # the road declares no entry / exit (vehicles observed only over part of the road:
    # ``associators.entries``); None: a track first or last seen mid-road has missed the
    # sensors before / after it
    entry_rate: np.ndarray | None = field(default=None, compare=False, repr=False)
    exit_rate: np.ndarray | None = field(default=None, compare=False, repr=False)
    # extra travel time of the gaps between consecutive sensors that the speeds measured at
    # their ends do not show (road works, a queue between two sensors); None: none
    delay: GapDelays | None = field(default=None, compare=False, repr=False)
    # the traffic's own slowness at each station over time, which every vehicle's follows
    # (a queue, the end of road works); None: vehicles keep to their own cruise speed only
    traffic: TrafficSlowness | None = field(default=None, compare=False, repr=False)
    # the cues (lane, length, ...) bound to the detections being associated (None: none)
    cues: CueSet | None = field(default=None, compare=False, repr=False)
    # the fluctuation and noise parameters the pairwise model links with, fitted under its
    # own likelihood (``calibration.fit_pairwise``) as (field, value) pairs; None: the fields
    # above. The Kalman model's likelihood, under which the fields above are fitted, credits
    # a persistent cruise speed; where traffic has none (stop-and-go), the values it prefers
    # make the pairwise cost trust the speeds at a gap's two ends too much or too little.
    pairwise_fit: tuple[tuple[str, float], ...] | None = field(default=None, repr=False)
    # whether the Kalman model predicts the traffic's links (``multiframe.kalman_fits``),
    # decided beforehand: a stream's window decides on the links of every window before it
    # too (``multiframe.settled``); None: the input decides on its own links
    kalman_fits: bool | None = None

    @staticmethod
    def road_openings(
        positions: np.ndarray, entries: tuple[float, ...], exits: tuple[float, ...]
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """``open_road`` for sensors at ``positions`` and entry / exit positions [m]."""
        if not entries and not exits:
            return None
        n = positions.size
        first = np.zeros(n, np.int64)
        last = np.full(n, n - 1, np.int64)
        for e in entries:
            k = int(np.searchsorted(positions, e))  # first sensor downstream of the entry
            first[k:] = np.maximum(first[k:], k)
        for e in exits:
            k = int(np.searchsorted(positions, e))  # sensors 0..k-1 are upstream of the exit
            last[:k] = np.minimum(last[:k], k - 1)
        return first, last

    def for_pairwise(self) -> MotionParams:
        """These parameters with the pairwise model's own fit (``pairwise_fit``) in place."""
        if self.pairwise_fit is None:
            return self
        return replace(self, pairwise_fit=None, **dict(self.pairwise_fit))

    def on_road(
        self, positions: np.ndarray, entries: tuple[float, ...], exits: tuple[float, ...]
    ) -> MotionParams:
        """These parameters on a road with sensors at ``positions`` and entries and exits at
        the given positions [m] (``open_road``; a closed road without either)."""
        return replace(self, open_road=MotionParams.road_openings(positions, entries, exits))

    def extra_time(
        self,
        x1: float | np.ndarray,
        x2: float | np.ndarray,
        t1: float | np.ndarray | None = None,
    ) -> float | np.ndarray:
        """Extra travel time [s] from position x1 to x2 of a vehicle at x1 at time ``t1``
        (``delay``; 0 without it)."""
        return 0.0 if self.delay is None else self.delay.extra_time(x1, x2, t1)

    def traffic_change(
        self,
        x1: float | np.ndarray,
        t1: float | np.ndarray,
        x2: float | np.ndarray,
        t2: float | np.ndarray,
    ) -> float | np.ndarray:
        """How the traffic's slowness changes from (x1, t1) to (x2, t2) [s/m] (``traffic``;
        0 without it)."""
        return 0.0 if self.traffic is None else self.traffic.change(x1, t1, x2, t2)

    def extra_var(self, x1: float | np.ndarray, x2: float | np.ndarray) -> float | np.ndarray:
        """Variance [s^2] of the extra travel time from x1 to x2 (0 without ``delay``)."""
        return 0.0 if self.delay is None else self.delay.extra_var(x1, x2)

    @property
    def miss_cost(self) -> float:
        return -math.log(self.p_miss)

    def misses_before(self, first: np.ndarray) -> np.ndarray:
        """Miss cost of the sensors a track seen first at sensor ``first`` has passed unseen.

        Those after the last entry upstream (``open_road``; on a closed road all of them), at
        most ``max_skip + 1``: targets enter the road before its first sensor.
        """
        opened = 0 if self.open_road is None else self.open_road[0][first]
        missed = np.minimum(first - opened, self.max_skip + 1) * self.miss_cost
        return _or_begun(missed, self.entry_rate, first)

    def misses_after(self, last: np.ndarray, n_sensors: int) -> np.ndarray:
        """Miss cost of the sensors a track seen last at sensor ``last`` will pass unseen.

        Those before the first exit downstream (``open_road``; on a closed road all of them),
        at most ``END_MISSES``.
        """
        closed = n_sensors - 1 if self.open_road is None else self.open_road[1][last]
        missed = np.minimum(closed - last, END_MISSES) * self.miss_cost
        return _or_begun(missed, self.exit_rate, last)

    @property
    def new_cost(self) -> float:
        return -math.log(self.clutter_density)


def _or_begun(missed: np.ndarray, rate: np.ndarray | None, sensor: np.ndarray) -> np.ndarray:
    """Cost [nats] of a track's first (last) detection at ``sensor``: it missed the sensors
    before (after) it, at ``missed`` nats, or it began (ended) there, at the estimated
    ``rate`` of the sensor; -log of the sum of both probabilities, 0 where nothing was
    missed."""
    if rate is None:
        return missed
    begun = -np.log(np.minimum(rate[sensor] + np.exp(-missed), 1.0))
    return np.where(missed > 0, begun, missed)


@dataclass(frozen=True)
class Prediction:
    """Tracks predicted to a position: ``tracks[i]`` to ``x`` (scalar or per row).

    ``mean`` and ``cov`` are the predicted state of a filtering model (None for a model whose
    prediction is its stored state). Row i of a cost or update refers to row i here.
    """

    tracks: np.ndarray
    x: float | np.ndarray
    mean: np.ndarray | None = None
    cov: np.ndarray | None = None
    # (n, 5) probability of a speed jump and the covariance it adds: (p, var tau,
    # cov tau-u, var u, 1 where the cruise slowness jumps with u, else 0); None without jumps
    jump: np.ndarray | None = None

    def take(self, rows: np.ndarray) -> Prediction:
        """The prediction of the given rows (repeats allowed), in that order."""
        x = self.x if np.isscalar(self.x) else np.asarray(self.x)[rows]
        if self.mean is None:
            return Prediction(self.tracks[rows], x)
        jump = None if self.jump is None else self.jump[rows]
        return Prediction(self.tracks[rows], x, self.mean[rows], self.cov[rows], jump)


def mix_nll(
    nll0: np.ndarray, d20: np.ndarray, nll1: np.ndarray, d21: np.ndarray, pj: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """NLL of the two-component mixture (1 - pj) exp(-nll0) + pj exp(-nll1) and the gating
    distance (the smaller of the two squared Mahalanobis distances)."""
    with np.errstate(divide='ignore'):
        lp0, lp1 = np.log1p(-pj), np.log(pj)
    return -np.logaddexp(lp0 - nll0, lp1 - nll1), np.minimum(d20, d21)


def trapezoid_residual(
    p: MotionParams,
    xa: np.ndarray,
    xb: np.ndarray,
    ta: np.ndarray,
    tb: np.ndarray,
    ua: np.ndarray,
    ub: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Travel-time residual e_t [s] of links (xa, ta, ua) -> (xb, tb, ub) against the trapezoid
    in slowness plus the gaps' extra time, and its variance [s^2] under the pairwise model's
    nominal (pure OU) component, as ``PairwiseModel.cost`` has them (without jumps)."""
    p = p.for_pairwise()
    dx = xb - xa
    e_t = tb - ta - dx * (ua + ub) / 2 - p.extra_time(xa, xb, ta)
    sv = max(p.velocity_noise, FLOOR_V)
    var_t = (
        2 * max(p.stamp_noise, FLOOR_T) ** 2
        + dx * dx * ((sv * ua * ua) ** 2 + (sv * ub * ub) ** 2) / 4
        + (p.sigma * ua * ub) ** 2 * dx**3 / (6 * p.length)
        + p.extra_var(xa, xb)
    )
    return e_t, var_t


class MotionModel(ABC):
    """State of many tracks under one motion model; tracks are ids 0..n-1 (see ``grow``)."""

    name: ClassVar[str]
    #: a track is its whole history (a filter), not just its last detection
    keeps_history: ClassVar[bool] = False

    def __init__(self, params: MotionParams) -> None:
        self.p = params

    @abstractmethod
    def grow(self, n: int) -> None:
        """Make room for ``n`` more tracks (ids continue after the existing ones)."""

    @abstractmethod
    def start(
        self, tracks: np.ndarray, x: float | np.ndarray, t: np.ndarray, u: np.ndarray
    ) -> None:
        """Start ``tracks`` from one detection each: position x, stamp t, slowness u."""

    @abstractmethod
    def predict(self, tracks: np.ndarray, x: float | np.ndarray) -> Prediction:
        """Predict ``tracks`` (last seen upstream) to position ``x``."""

    @abstractmethod
    def gate_window(self, pred: Prediction) -> tuple[np.ndarray, np.ndarray]:
        """(centre, half width) of the passage-time window in which each track is gated."""

    @abstractmethod
    def cost(
        self, pred: Prediction, t: np.ndarray, u: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(NLL, squared Mahalanobis distance) of detection i (t[i], u[i]) for ``pred`` row i."""

    @abstractmethod
    def update(self, pred: Prediction, t: np.ndarray, u: np.ndarray) -> None:
        """Take detection i into the track of ``pred`` row i (each track at most once)."""

    @abstractmethod
    def save(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position [m], mean (n, 3), covariance (n, 3, 3)) of every track: the state that
        ``load`` continues (the likelihood's shared prefixes, ``associators.likelihood``)."""

    @abstractmethod
    def load(self, x: np.ndarray, mean: np.ndarray, cov: np.ndarray, origin: np.ndarray) -> None:
        """Replace the state of every track (copies) with one ``save`` gave; ``origin`` is
        the position of each track's first detection [m]."""


#: the motion models by name (``link.make_model`` chooses one)
MODELS: Registry[type[MotionModel]] = Registry('motion model')


def register_model(cls: type[MotionModel]) -> type[MotionModel]:
    """Class decorator: make a motion model selectable by its ``name``."""
    return MODELS.add(cls.name, cls)


@register_model
class PairwiseModel(MotionModel):
    """Track = its last detection; pairwise cost on travel time and slowness continuity."""

    name = 'pairwise'

    def __init__(self, params: MotionParams) -> None:
        super().__init__(params.for_pairwise())
        self.x = np.zeros(0)
        self.t = np.zeros(0)
        self.u = np.zeros(0)

    def grow(self, n: int) -> None:
        self.x = np.concatenate([self.x, np.zeros(n)])
        self.t = np.concatenate([self.t, np.zeros(n)])
        self.u = np.concatenate([self.u, np.zeros(n)])

    def start(
        self, tracks: np.ndarray, x: float | np.ndarray, t: np.ndarray, u: np.ndarray
    ) -> None:
        self.x[tracks], self.t[tracks], self.u[tracks] = x, t, u

    def predict(self, tracks: np.ndarray, x: float | np.ndarray) -> Prediction:
        return Prediction(tracks, x)

    def _var_u_noise(self, u: np.ndarray) -> np.ndarray:
        return (max(self.p.velocity_noise, FLOOR_V) * u * u) ** 2

    def gate_window(self, pred: Prediction) -> tuple[np.ndarray, np.ndarray]:
        p, tracks = self.p, pred.tracks
        dx = pred.x - self.x[tracks]
        u = self.u[tracks]
        var_du = 2 * self._var_u_noise(u) + 2 * (p.sigma * u * u) ** 2 * (
            1 - np.exp(-dx / p.length)
        )
        var_t = (
            2 * max(p.stamp_noise, FLOOR_T) ** 2
            + dx * dx * var_du
            + (p.sigma * u * u) ** 2 * dx**3 / (6 * p.length)
        )
        if p.jump_rate > 0:
            var_t = var_t + (p.jump_sigma * u * u) ** 2 * dx * dx
        x1 = self.x[tracks]
        var_t = var_t + p.extra_var(x1, pred.x)
        t1 = self.t[tracks]
        # the slowness at the far end moves with the traffic's: half of it over the gap
        shift = p.traffic_change(x1, t1, pred.x, t1 + dx * u)
        centre = t1 + dx * (u + shift / 2) + p.extra_time(x1, pred.x, t1)
        return centre, np.sqrt(p.gate * var_t)

    def cost(
        self, pred: Prediction, t: np.ndarray, u: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        p, tracks = self.p, pred.tracks
        dx = pred.x - self.x[tracks]
        u1 = self.u[tracks]
        su2 = (p.sigma * u1 * u) ** 2  # sigma_u^2 with m^2 ~ u1 u2
        vn1, vn2 = self._var_u_noise(u1), self._var_u_noise(u)
        e_t, var_t = trapezoid_residual(p, self.x[tracks], pred.x, self.t[tracks], t, u1, u)
        e_u = u - u1 - p.traffic_change(self.x[tracks], self.t[tracks], pred.x, t)
        var_u = vn1 + vn2 + 2 * su2 * (1 - np.exp(-dx / p.length))
        d2 = e_t * e_t / var_t + e_u * e_u / var_u
        nll = 0.5 * (d2 + np.log(var_t * var_u)) + LOG2PI
        if p.jump_rate <= 0:
            return nll, d2
        # a jump at a uniform point: slowness change vj, trapezoid error vj dx^2 / 12
        vj = (p.jump_sigma * u1 * u) ** 2
        vt1, vu1 = var_t + vj * dx * dx / 12, var_u + vj
        d21 = e_t * e_t / vt1 + e_u * e_u / vu1
        nll1 = 0.5 * (d21 + np.log(vt1 * vu1)) + LOG2PI
        return mix_nll(nll, d2, nll1, d21, -np.expm1(-p.jump_rate * dx))

    def update(self, pred: Prediction, t: np.ndarray, u: np.ndarray) -> None:
        self.start(pred.tracks, pred.x, t, u)

    def save(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, mean, cov) of every track in the filters' layout (``KalmanModel.save``): the
        mean is (t, u, u), the covariance zero (a detection is taken as it is)."""
        return self.x, np.column_stack([self.t, self.u, self.u]), np.zeros((self.x.size, 3, 3))

    def load(self, x: np.ndarray, mean: np.ndarray, _cov: np.ndarray, _origin: np.ndarray) -> None:
        """Replace the state of every track with one saved by ``save``."""
        self.x, self.t, self.u = x.copy(), mean[:, 0].copy(), mean[:, 1].copy()
