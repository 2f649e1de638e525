"""The motion models against independent references.

The Kalman model (exact Ornstein-Uhlenbeck-in-distance transition on (passage time, slowness,
cruise slowness)) is checked against filterpy's textbook ``KalmanFilter`` fed with the same
transition F, process noise Q and measurement noise R written out by hand: same predicted
means and covariances, same updated state, same innovation log-likelihoods.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from mlkm_core.associators.likelihood import sequence_nll, sequence_state
from mlkm_core.model.kalman import KalmanModel
from mlkm_core.model.link import make_model
from mlkm_core.model.motion import GapDelays, MotionParams, PairwiseModel
from mlkm_core.types import Detections, Layout

P = MotionParams(sigma=3.0, length=250.0, stamp_noise=0.15, velocity_noise=0.4)
# one target along a road: positions [m], stamps [s], speeds [m/s] (speed changes and a long
# gap between 420 m and 700 m)
X = np.array([60.0, 130.0, 260.0, 420.0, 700.0, 760.0])
T = np.array([2.0, 4.1, 7.3, 11.6, 19.0, 20.9])
V = np.array([31.0, 33.5, 38.0, 35.0, 36.5, 33.0])


def reference_matrices(p: MotionParams, d: float, m: float) -> tuple[np.ndarray, np.ndarray]:
    """F and Q of the OU-in-distance model over a step d [m], cruise slowness m [s/m]."""
    L = p.length
    a = math.exp(-d / L)
    F = np.array([[1.0, L * (1 - a), d - L * (1 - a)], [0.0, a, 1 - a], [0.0, 0.0, 1.0]])
    su2 = (p.sigma * m * m) ** 2
    var_int = (2 * d / L - 3 + 4 * a - a * a) * L * L  # Var of the integral of the OU / su2
    Q = su2 * np.array(
        [[var_int, L * (1 - a) ** 2, 0.0], [L * (1 - a) ** 2, 1 - a * a, 0.0], [0.0, 0.0, 0.0]]
    )
    return F, Q


def reference_noise(p: MotionParams, u: float) -> np.ndarray:
    return np.diag([p.stamp_noise**2, (p.velocity_noise * u * u) ** 2])


def test_kalman_model_equals_a_reference_kalman_filter():
    u = 1.0 / V
    model = KalmanModel(P)
    model.grow(1)
    track = np.array([0])
    model.start(track, X[0], T[:1], u[:1])

    kf = KalmanFilter(dim_x=3, dim_z=2)
    kf.H = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    kf.x = np.array([T[0], u[0], u[0]])
    rt, ru = P.stamp_noise**2, (P.velocity_noise * u[0] ** 2) ** 2
    dev = (P.sigma * u[0] ** 2) ** 2 * (1 - math.exp(-2 * X[0] / P.length))
    kf.P = np.array([[rt, 0.0, 0.0], [0.0, ru, ru], [0.0, ru, ru + dev]])
    np.testing.assert_allclose(model.mean[0], kf.x, rtol=1e-12)
    np.testing.assert_allclose(model.cov[0], kf.P, rtol=1e-12)

    total = 0.0
    for k in range(1, X.size):
        F, Q = reference_matrices(P, X[k] - X[k - 1], kf.x[2])
        kf.predict(F=F, Q=Q)
        pred = model.predict(track, X[k])
        np.testing.assert_allclose(pred.mean[0], kf.x, rtol=1e-10)
        np.testing.assert_allclose(pred.cov[0], kf.P, rtol=1e-9, atol=1e-15)

        nll, d2 = model.cost(pred, T[k : k + 1], u[k : k + 1])
        kf.update(np.array([T[k], u[k]]), R=reference_noise(P, u[k]))
        assert nll[0] == pytest.approx(-kf.log_likelihood, rel=1e-9)
        assert d2[0] == pytest.approx(float(kf.y @ np.linalg.solve(kf.S, kf.y)), rel=1e-9)
        total += nll[0]

        model.update(pred, T[k : k + 1], u[k : k + 1])
        np.testing.assert_allclose(model.mean[0], kf.x, rtol=1e-10)
        np.testing.assert_allclose(model.cov[0], kf.P, rtol=1e-8, atol=1e-15)

    # neither born nor ended here and no sensor skipped: the track likelihood is exactly the
    # sum of those innovation NLLs
    layout = Layout(1000.0, X)
    d = Detections(np.arange(X.size), T, V)
    seq = np.arange(X.size)[None, :]
    got = sequence_nll(layout, d, seq, P, birth=np.array([False]), end=np.array([False]))
    assert got[0] == pytest.approx(total, rel=1e-12)


def test_models_are_chosen_by_name():
    assert isinstance(make_model('kalman', P), KalmanModel)
    assert isinstance(make_model('pairwise', P), PairwiseModel)
    with pytest.raises(ValueError, match='unknown motion model'):
        make_model('constant_velocity', P)


def test_pairwise_cost_hand_computed():
    """Two detections 100 m apart: the trapezoid travel-time residual and the slowness change."""
    p = MotionParams(sigma=2.0, length=500.0, stamp_noise=0.1, velocity_noise=0.2)
    m = PairwiseModel(p)
    m.grow(1)
    m.start(np.array([0]), 100.0, np.array([10.0]), np.array([1 / 20]))
    u1, u2, dx = 1 / 20, 1 / 25, 100.0
    t2 = 10.0 + dx * (u1 + u2) / 2 + 0.3  # 0.3 s late against the trapezoid
    nll, d2 = m.cost(m.predict(np.array([0]), 200.0), np.array([t2]), np.array([u2]))
    vn1, vn2 = (0.2 * u1 * u1) ** 2, (0.2 * u2 * u2) ** 2
    su2 = (2.0 * u1 * u2) ** 2
    var_t = 2 * 0.1**2 + dx * dx * (vn1 + vn2) / 4 + su2 * dx**3 / (6 * 500.0)
    var_u = vn1 + vn2 + 2 * su2 * (1 - math.exp(-dx / 500.0))
    want_d2 = 0.3**2 / var_t + (u2 - u1) ** 2 / var_u
    assert d2[0] == pytest.approx(want_d2, rel=1e-9)
    assert nll[0] == pytest.approx(
        0.5 * (want_d2 + math.log(var_t * var_u)) + math.log(2 * math.pi), rel=1e-9
    )


def test_drifting_cruise_speed_adds_a_random_walk_before_the_step():
    """With ``drift`` (std of the cruise speed's change per km), the prediction equals the
    reference filter's with the random walk of the cruise slowness, variance
    (drift m^2)^2 d / 1000, added before the step: Q + q F[:, 2] F[:, 2]^T."""
    p = MotionParams(sigma=3.0, length=250.0, stamp_noise=0.15, velocity_noise=0.4, drift=2.5)
    u = 1.0 / V
    model = KalmanModel(p)
    model.grow(1)
    track = np.array([0])
    model.start(track, X[0], T[:1], u[:1])
    kf = KalmanFilter(dim_x=3, dim_z=2)
    kf.H = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    kf.x, kf.P = model.mean[0].copy(), model.cov[0].copy()
    for k in range(1, X.size):
        d = X[k] - X[k - 1]
        F, Q = reference_matrices(p, d, kf.x[2])
        q = (2.5 * kf.x[2] ** 2) ** 2 * d / 1000.0
        kf.predict(F=F, Q=Q + q * np.outer(F[:, 2], F[:, 2]))
        pred = model.predict(track, X[k])
        np.testing.assert_allclose(pred.cov[0], kf.P, rtol=1e-9, atol=1e-15)
        nll, _ = model.cost(pred, T[k : k + 1], u[k : k + 1])
        kf.update(np.array([T[k], u[k]]), R=reference_noise(p, u[k]))
        assert nll[0] == pytest.approx(-kf.log_likelihood, rel=1e-9)
        model.update(pred, T[k : k + 1], u[k : k + 1])
    # the drift widens the prediction of the cruise slowness, so it weighs the far past less
    still = KalmanModel(P)
    still.grow(1)
    still.start(track, X[0], T[:1], u[:1])
    assert model.predict(track, 900.0).cov[0, 2, 2] > still.predict(track, 900.0).cov[0, 2, 2]


def test_a_speed_level_change_after_the_first_sensor_is_a_mixture_hand_computed():
    """With ``entry_jump`` q, a track's first prediction is the mixture (1 - q) N(plain) +
    q N(plain + level change): the slowness and the cruise slowness both move by the change
    J ~ N(0, (entry_sigma m^2)^2) at a uniform point of the gap, so the passage time gets
    var_J d^2 / 3 and covariances var_J d / 2 with both. Later predictions have no such term."""
    p = replace(P, entry_jump=0.3, entry_sigma=5.0)
    u = 1.0 / V
    model, plain = KalmanModel(p), KalmanModel(P)
    track = np.array([0])
    for m in (model, plain):
        m.grow(1)
        m.start(track, X[0], T[:1], u[:1])
    pred, ref = model.predict(track, X[1]), plain.predict(track, X[1])
    d, mc = X[1] - X[0], ref.mean[0, 2]
    vj = (5.0 * mc * mc) ** 2
    g = np.array([d / 2, 1.0, 1.0])  # how a change of the level moves (tau, u, m), on average
    jumped = ref.cov[0] + vj * np.outer(g, g)
    jumped[0, 0] += vj * d * d / 3 - vj * d * d / 4  # tau's own spread over the jump point
    noise = reference_noise(P, u[1])
    z = np.array([T[1], u[1]])

    def density(cov: np.ndarray) -> float:
        s = cov[:2, :2] + noise
        y = z - ref.mean[0, :2]
        norm = 2 * math.pi * math.sqrt(np.linalg.det(s))
        return math.exp(-0.5 * y @ np.linalg.solve(s, y)) / norm

    want = -math.log(0.7 * density(ref.cov[0]) + 0.3 * density(jumped))
    np.testing.assert_allclose(pred.mean, ref.mean, rtol=1e-12)
    nll, _ = model.cost(pred, T[1:2], u[1:2])
    assert nll[0] == pytest.approx(want, rel=1e-9)
    # the level change moved the cruise slowness with the slowness
    model.update(pred, T[1:2], u[1:2])
    plain.update(ref, T[1:2], u[1:2])
    assert model.cov[0, 2, 2] > plain.cov[0, 2, 2]
    # from the second sensor on, only the ordinary fluctuation (no jump component)
    later = model.predict(track, X[2])
    assert later.jump[0, 0] == 0.0
    free = KalmanModel(P)
    free.grow(1)
    free.load(model.x, model.mean, model.cov, np.array([X[0]]))
    nll2, d2 = model.cost(later, T[2:3], u[2:3])
    plain_pred = free.predict(track, X[2])
    want2, want_d2 = free.cost(plain_pred, T[2:3], u[2:3])
    assert nll2[0] == pytest.approx(want2[0], rel=1e-12)
    # and the gate is the plain filter's too (this model has no ordinary jumps)
    assert d2[0] == pytest.approx(want_d2[0], rel=1e-12)
    np.testing.assert_allclose(model.gate_window(later), free.gate_window(plain_pred))


def test_gap_delays_add_up_over_the_gaps_crossed_in_either_direction():
    """Sensors at 0, 100, 250 and 400 m; gaps with extra times (1, 0, 4) s and variances
    (0.25, 0, 2.25) s^2."""
    delays = GapDelays.per_gap(
        np.array([0.0, 100.0, 250.0, 400.0]), np.array([1.0, 0.0, 4.0]), np.array([0.25, 0, 2.25])
    )
    np.testing.assert_allclose(delays.gap_time, [1.0, 0.0, 4.0])
    np.testing.assert_allclose(delays.gap_var, [0.25, 0.0, 2.25])
    x1, x2 = np.array([0.0, 100.0, 0.0, 400.0]), np.array([100.0, 250.0, 400.0, 100.0])
    np.testing.assert_allclose(delays.extra_time(x1, x2), [1.0, 0.0, 5.0, -4.0])
    np.testing.assert_allclose(delays.extra_var(x1, x2), [0.25, 0.0, 2.5, 2.25])
    # the road seen backwards: from -400 to -100 m is the forward 100 -> 400 m reversed
    back = delays.mirrored()
    assert back.extra_time(-400.0, -100.0) == pytest.approx(4.0)
    assert back.extra_var(-400.0, -100.0) == pytest.approx(2.25)
    assert back.extra_time(-100.0, 0.0) == pytest.approx(1.0)


def test_a_gap_delay_shifts_and_widens_both_models_predictions():
    """Crossing a gap with extra time 3 s and variance 2 s^2 moves the predicted passage 3 s
    later and adds 2 s^2 to its variance, in the pairwise cost and in the Kalman prediction."""
    delays = GapDelays.per_gap(np.array([100.0, 200.0]), np.array([3.0]), np.array([2.0]))
    p = MotionParams(sigma=2.0, length=500.0, stamp_noise=0.1, velocity_noise=0.2)
    u1, u2, dx = 1 / 20, 1 / 25, 100.0
    t2 = 10.0 + dx * (u1 + u2) / 2 + 3.0 + 0.3  # 0.3 s late against the delayed trapezoid
    costs = []
    for q in (p, replace(p, delay=delays)):
        m = PairwiseModel(q)
        m.grow(1)
        m.start(np.array([0]), 100.0, np.array([10.0]), np.array([u1]))
        costs.append(m.cost(m.predict(np.array([0]), 200.0), np.array([t2]), np.array([u2])))
    vn1, vn2 = (0.2 * u1 * u1) ** 2, (0.2 * u2 * u2) ** 2
    su2 = (2.0 * u1 * u2) ** 2
    var_t = 2 * 0.1**2 + dx * dx * (vn1 + vn2) / 4 + su2 * dx**3 / (6 * 500.0)
    var_u = vn1 + vn2 + 2 * su2 * (1 - math.exp(-dx / 500.0))
    want_d2 = 0.3**2 / (var_t + 2.0) + (u2 - u1) ** 2 / var_u
    assert costs[1][1][0] == pytest.approx(want_d2, rel=1e-9)
    assert costs[1][0][0] == pytest.approx(
        0.5 * (want_d2 + math.log((var_t + 2.0) * var_u)) + math.log(2 * math.pi), rel=1e-9
    )
    # without the delay the same detection is 3.3 s late: far less likely
    assert costs[0][0][0] > costs[1][0][0] + 10
    preds = []
    for q in (p, replace(p, delay=delays)):
        k = KalmanModel(q)
        k.grow(1)
        k.start(np.array([0]), 100.0, np.array([10.0]), np.array([u1]))
        preds.append(k.predict(np.array([0]), 200.0))
    assert preds[1].mean[0, 0] == pytest.approx(preds[0].mean[0, 0] + 3.0, rel=1e-12)
    assert preds[1].cov[0, 0, 0] == pytest.approx(preds[0].cov[0, 0, 0] + 2.0, rel=1e-12)
    np.testing.assert_allclose(preds[1].cov[0, 1:, :], preds[0].cov[0, 1:, :])


def test_the_pairwise_sequence_likelihood_is_the_sum_of_its_link_costs():
    """Under the pairwise model a track's likelihood is a Markov chain: its new-track cost,
    each link's cost from the detection before it alone (sensors 0 -> 1 -> 3, one missed),
    and the miss costs of the sensors it skipped and will pass unseen after its last one."""
    layout = Layout(800.0, X)
    keep = np.array([0, 1, 3])
    d = Detections(np.arange(6)[keep], T[keep], V[keep], np.zeros(3, np.int64))
    seqs = np.array([[0, 1, 2]])
    ones = np.ones(1, bool)
    got = sequence_nll(layout, d, seqs, P, ones, ones, model='pairwise')[0]
    m = PairwiseModel(P)
    m.grow(1)
    links = 0.0
    for a, b in ((0, 1), (1, 3)):
        m.start(np.array([0]), X[a], np.array([T[a]]), np.array([1 / V[a]]))
        nll, d2 = m.cost(m.predict(np.array([0]), X[b]), np.array([T[b]]), np.array([1 / V[b]]))
        assert d2[0] < 4 * P.gate  # below the cap: the plain NLL counts
        links += nll[0]
    misses = 1 + 2  # sensor 2 skipped; sensors 4 and 5 passed unseen after the last detection
    want = P.new_cost + links + misses * P.miss_cost
    assert got == pytest.approx(want, rel=1e-12)
    # unlike the Kalman model's, which carries the whole history
    assert sequence_nll(layout, d, seqs, P, ones, ones)[0] != pytest.approx(want, rel=1e-6)


@pytest.mark.parametrize('model', ['pairwise', 'kalman'])
def test_a_saved_prefix_continues_as_the_whole_sequence(model):
    """The local search filters a shared prefix once and continues it (``sequence_state``,
    ``save``/``load`` of the motion model): the same NLL as the whole sequence at once."""
    layout = Layout(800.0, X)
    d = Detections(np.arange(6), T, V, np.zeros(6, np.int64))
    ones = np.ones(2, bool)
    seqs = np.array([[0, 1, 2, 3, 4, 5], [0, 1, 2, -1, 4, 5]])
    whole = sequence_nll(layout, d, seqs, P, ones, ones, model=model)
    pre = sequence_state(layout, d, seqs[:, :3], P, ones, model)
    rest = sequence_nll(layout, d, seqs[:, 3:], P, ones, ones, state=pre.take([0, 1]), model=model)
    np.testing.assert_allclose(rest, whole, rtol=1e-12)
