"""Multi-frame local search (N-scan style) on track exchanges, scored by Kalman likelihood.

``refine`` improves a labelling by exchanging detections between pairs of tracks. A move
(A, B, s, k) exchanges between tracks A and B their detections at sensors [s, s + k) for k in
``MOVES`` (1, 2, 3 or 5 sensors), or their whole tails from s on (k = 0, a 2-opt exchange;
when B starts at s it stitches B onto A, a track lost after misses onto the track that was
born from its detections). Candidates are the gated pairs (A's last detection before s, a
detection of B at s) in a window of ``CANDIDATE_GATE`` of the tracking gate. Each move is
scored by the Kalman marginal NLL (``likelihood``) of the four sequences (old A, B and new A,
B) restricted to sensors [s - window, s + window), with the birth / early-end costs of tracks
that start or end inside the window; improving moves are applied greedily, best first, each
track at most once per round; the next round looks only at moves that involve a track changed
in the round before, for at most ``rounds`` rounds.

Where the detections carry lanes, a move also pays for the order it breaks within a lane
(``lane_swap_cost``): two vehicles in one lane at two consecutive sensors pass the second in
the order they passed the first unless one changed lanes twice in between, and the tracks'
own pairs show how rarely that happens. A move that makes such a pair cross (or uncross) at
a boundary of the exchange changes the score by that log-odds; the likelihood of each track
alone cannot see it (an exchange of two neighbours fits both tracks about as well).

The work is bounded by ``budget``, the number of candidates scored over all rounds (each with
all its ``MOVES``). Congested traffic (near-stationary vehicles, whose passage-time gates span
the whole episode) can otherwise produce candidates quadratic in the number of tracks. When a
round has more candidates than the budget left, the first ones in (track, track, sensor)
order are scored and the search stops after applying their improving moves; the result is
deterministic for a given input and budget.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlkm_core.associators.gating import gate_pairs
from mlkm_core.associators.likelihood import sequence_nll, sequence_state
from mlkm_core.associators.linking import by_sensor
from mlkm_core.model.motion import MotionParams, PairwiseModel
from mlkm_core.types import Detections, Layout

#: exchange lengths tried for each candidate: the whole tail (0) or 1, 2, 3, 5 sensors
MOVES = (0, 1, 2, 3, 5)
#: candidate time window as a fraction of the tracking gate (4 of 6 sigma)
CANDIDATE_GATE = 4 / 6
#: candidates scored in one batch (bounds the memory of the batched filters)
CHUNK = 20_000


@dataclass(frozen=True)
class SearchResult:
    """Outcome of ``refine``: the labels and the work it took."""

    labels: np.ndarray  # raw track ids (no singleton pruning)
    rounds: int  # rounds that scored candidates
    scored: int  # candidates scored over all rounds (the unit of ``budget``)
    exhausted: bool  # True when the budget left candidates unscored


def candidates(
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
                centre, half = pw.gate_window(pw.predict(ids, float(layout.positions[s])))
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


#: bounds of the probability that two vehicles of one lane pass the next sensor in the other
#: order (their tracks rarely show enough pairs to estimate it closer)
SWAP_PROB = (0.005, 0.5)


def lane_swap_cost(d: Detections, M: np.ndarray) -> float:
    """Log-odds [nats] against two vehicles of one lane at consecutive sensors passing the
    second in the other order, from the tracks ``M`` (track x sensor -> detection): over the
    neighbours in a lane's order at a sensor whose tracks are both seen in that lane at the
    next, the share that cross (Laplace-smoothed, within ``SWAP_PROB``). 0 without lanes, or
    where every known lane is the same one: then the lane tells no vehicle apart (a sensor
    that reports one lane for all), as for the lane cue (``model.lane.bind``)."""
    if d.lane is None or np.unique(d.lane[d.lane >= 0]).size < 2:
        return 0.0
    crossed = pairs = 0
    for p in range(M.shape[1] - 1):
        here, there = M[:, p], M[:, p + 1]
        both = (here >= 0) & (there >= 0)
        h, t = here[both], there[both]
        same = (d.lane[h] >= 0) & (d.lane[h] == d.lane[t])
        h, t = h[same], t[same]
        for lane in np.unique(d.lane[h]):
            k = d.lane[h] == lane
            order = np.argsort(d.stamp[h[k]], kind='stable')
            after = d.stamp[t[k]][order]
            pairs += max(order.size - 1, 0)
            crossed += int(np.sum(np.diff(after) < 0))
    prob = float(np.clip((crossed + 1) / (pairs + 2), *SWAP_PROB))
    return float(np.log((1 - prob) / prob))


def _swaps(d: Detections, M: np.ndarray, ca, cb, p: np.ndarray) -> np.ndarray:
    """Per candidate, +1 where the exchange at the boundary between sensors p and p + 1
    makes the two tracks cross within one lane, -1 where it makes them uncross, 0 where the
    four detections are not all in one lane."""
    n_s = M.shape[1]
    ok = (p >= 0) & (p + 1 < n_s)
    pc, qc = np.clip(p, 0, n_s - 1), np.clip(p + 1, 0, n_s - 1)
    ap, bp, aq, bq = M[ca, pc], M[cb, pc], M[ca, qc], M[cb, qc]
    ok &= (ap >= 0) & (bp >= 0) & (aq >= 0) & (bq >= 0)
    lane = d.lane
    ok &= (lane[ap] >= 0) & (lane[ap] == lane[bp]) & (lane[ap] == lane[aq])
    ok &= lane[ap] == lane[bq]
    before = d.stamp[ap] < d.stamp[bp]
    crossed_now = before != (d.stamp[aq] < d.stamp[bq])
    return np.where(ok, np.where(crossed_now, -1, 1), 0)


def _gains(
    layout: Layout,
    d: Detections,
    M: np.ndarray,
    params: MotionParams,
    ca: np.ndarray,
    cb: np.ndarray,
    cs: np.ndarray,
    window: int,
    model: str,
    swap_cost: float = 0.0,
) -> np.ndarray:
    """(n_cand, n_moves) change of NLL of every move of every candidate (< 0 improves),
    ``swap_cost`` [nats] per pair of tracks made to cross within a lane."""
    n_s = M.shape[1]
    has = M >= 0
    first_s = np.where(has.any(axis=1), has.argmax(axis=1), n_s)
    last_s = np.where(has.any(axis=1), n_s - 1 - has[:, ::-1].argmax(axis=1), -1)
    offs = np.arange(-window, window)
    cols = cs[:, None] + offs[None, :]
    inside = (cols >= 0) & (cols < n_s)
    cc = np.clip(cols, 0, n_s - 1)
    wa = np.where(inside, M[ca[:, None], cc], -1)
    wb = np.where(inside, M[cb[:, None], cc], -1)
    lo, hi = cs - window, cs + window
    a_born, b_born = first_s[ca] >= lo, first_s[cb] >= lo
    a_more, b_more = last_s[ca] >= hi, last_s[cb] >= hi
    # the prefix (sensors before s) is the same for old and new sequences: filter it once,
    # then continue every old and new suffix from the prefix state of its owner
    n_c = ca.size
    birth2 = np.concatenate([a_born, b_born])
    pre = sequence_state(
        layout, d, np.concatenate([wa[:, :window], wb[:, :window]]), params, birth2, model
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
        state=pre.take(owner),
        model=model,
    ).reshape(len(suf), -1)
    gains = np.stack(
        [nll[2 + 2 * j] + nll[3 + 2 * j] - nll[0] - nll[1] for j in range(len(MOVES))], axis=1
    )
    if swap_cost > 0:
        first = _swaps(d, M, ca, cb, cs - 1)
        for j, k in enumerate(MOVES):
            gains[:, j] += swap_cost * (first + (_swaps(d, M, ca, cb, cs + k - 1) if k else 0))
    return gains


def refine(
    layout: Layout,
    d: Detections,
    labels: np.ndarray,
    params: MotionParams,
    budget: int | None = None,
    window: int = 6,
    rounds: int = 10,
    model: str = 'kalman',
) -> SearchResult:
    """Local search on track exchanges (module doc), scored under ``model`` (``kalman`` or
    ``pairwise``, ``likelihood.sequence_nll``); ``budget`` None means unbounded."""
    n_s = layout.n_sensors
    valid = np.flatnonzero(labels >= 0)
    if valid.size == 0:
        return SearchResult(labels.copy(), 0, 0, False)
    n_tracks = int(labels.max()) + 1
    M = np.full((n_tracks, n_s), -1, dtype=np.int64)
    M[labels[valid], d.sensor_index[valid]] = valid
    dirty = np.ones(n_tracks, bool)
    cur = labels.copy()
    swap_cost = lane_swap_cost(d, M)
    scored, done, exhausted = 0, 0, False
    for _ in range(rounds):
        ca, cb, cs = candidates(layout, d, cur, params)
        sel = dirty[ca] | dirty[cb]
        ca, cb, cs = ca[sel], cb[sel], cs[sel]
        if ca.size == 0:
            break
        # one move per unordered pair and sensor
        key = np.unique(np.column_stack([np.minimum(ca, cb), np.maximum(ca, cb), cs]), axis=0)
        if budget is not None and key.shape[0] > budget - scored:
            exhausted = True
            key = key[: budget - scored]
            if key.shape[0] == 0:
                break
        ca, cb, cs = key[:, 0], key[:, 1], key[:, 2]
        gain = np.concatenate(
            [
                _gains(
                    layout,
                    d,
                    M,
                    params,
                    ca[i : i + CHUNK],
                    cb[i : i + CHUNK],
                    cs[i : i + CHUNK],
                    window,
                    model,
                    swap_cost,
                )
                for i in range(0, ca.size, CHUNK)
            ]
        )
        scored += ca.size
        done += 1
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
        if exhausted:
            break
    return SearchResult(cur, done, scored, exhausted)
