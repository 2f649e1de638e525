"""Likelihood of tracks under a motion model: the score of ``multiframe``.

``sequence_nll`` is the marginal negative log-likelihood of detection sequences (one track
each) under the Kalman model (``model.kalman``) or, where that model does not hold, the
Markov chain of the pairwise model (``motion.PairwiseModel``: each link scored from the
detection before it alone), computed for many sequences at once; ``total_nll`` scores a whole
labelling, so two labellings of the same detections can be compared under one model;
``sequence_state`` filters a common prefix once so that many continuations of it can be scored
(the local search of ``search``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from mlkm_core.model.cues import TrackArrays, take_state
from mlkm_core.model.link import LinkModel
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Detections, Layout


@dataclass(frozen=True)
class SequenceState:
    """Filters and running costs of sequences after their first columns (one row each)."""

    x: np.ndarray  # position of each filter [m]
    mean: np.ndarray  # (n, 3) filter means
    cov: np.ndarray  # (n, 3, 3) filter covariances
    out: np.ndarray  # NLL so far
    last: np.ndarray  # sensor of the last detection, -1 before the first
    first_sensor: np.ndarray  # sensor of the first detection
    count: np.ndarray  # detections so far
    cues: tuple[TrackArrays, ...] | None = None  # state of the cues (None: none bound)

    def take(self, rows: np.ndarray) -> SequenceState:
        """The state of the given rows (repeats allowed), in that order."""
        return SequenceState(
            **{f.name: getattr(self, f.name)[rows] for f in fields(self) if f.name != 'cues'},
            cues=None if self.cues is None else take_state(self.cues, rows),
        )


def _filter(
    layout: Layout,
    d: Detections,
    seqs: np.ndarray,
    params: MotionParams,
    birth: np.ndarray,
    rows: dict[str, np.ndarray] | None,
    state: SequenceState | None,
    model: str,
) -> SequenceState:
    """Run the filters of every row over the columns of ``seqs`` (see ``sequence_nll``)."""
    n_seq, width = seqs.shape
    m = LinkModel(params, model, rows, cap=4 * params.gate)
    if state is None:
        m.grow(n_seq)
        out = np.zeros(n_seq)
        last = np.full(n_seq, -1, dtype=np.int64)
        first_sensor = np.zeros(n_seq, dtype=np.int64)
        count = np.zeros(n_seq, dtype=np.int64)
    else:
        m.motion.load(state.x, state.mean, state.cov, layout.positions[state.first_sensor])
        m.load_cues(state.cues)
        out, last = state.out.copy(), state.last.copy()
        first_sensor, count = state.first_sensor.copy(), state.count.copy()
    count = count + (seqs >= 0).sum(axis=1)
    u_all = 1.0 / d.velocity
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
            m.start(r0, x[first], t[first], u[first], det[first])
            out[r0] += np.where(birth[r0], params.new_cost, 0.0)
            first_sensor[r0] = s[first]
        nxt = ~first
        if nxt.any():
            r1 = live[nxt]
            pred = m.predict(r1, x[nxt])
            nll, _ = m.cost(pred, t[nxt], u[nxt], det[nxt])
            out[r1] += nll + (s[nxt] - last[r1] - 1) * params.miss_cost
            m.update(pred, t[nxt], u[nxt], det[nxt])
        last[live] = s
    x, mean, cov = m.motion.save()
    return SequenceState(x, mean, cov, out, last, first_sensor, count, m.cue_state)


def sequence_state(
    layout: Layout,
    d: Detections,
    seqs: np.ndarray,
    params: MotionParams,
    birth: np.ndarray | None = None,
    model: str = 'kalman',
) -> SequenceState:
    """Filter the rows of ``seqs`` without the end-of-track costs, to be continued later by
    ``sequence_nll(..., state=...)`` (rows of the state taken with ``SequenceState.take``)."""
    birth = np.ones(seqs.shape[0], bool) if birth is None else birth
    return _filter(layout, d, seqs, params, birth, None, None, model)


def sequence_nll(
    layout: Layout,
    d: Detections,
    seqs: np.ndarray,
    params: MotionParams,
    birth: np.ndarray | None = None,
    end: np.ndarray | None = None,
    rows: dict[str, np.ndarray] | None = None,
    state: SequenceState | None = None,
    model: str = 'kalman',
) -> np.ndarray:
    """NLL under ``model`` (``kalman`` or ``pairwise``) of each detection sequence (rows of
    ``seqs``, -1 = no detection).

    Columns are visited in order; a row's entries must have increasing sensors (gaps allowed).
    Every further detection pays its innovation NLL, capped (past a squared Mahalanobis
    distance of 4 gates, so that a few wrong links do not dominate), plus the miss cost per
    skipped sensor, as in the forward pass. A sequence flagged ``birth`` (the track starts
    here) pays the new-track cost and, if it has two detections or more, the miss cost of the
    sensors it passed unseen before its first detection (``MotionParams.misses_before``); one
    flagged ``end`` (the track ends here) with two detections or more pays the miss cost of
    the sensors it would pass unseen after its last one (``MotionParams.misses_after``). A
    single detection is a false alarm: the new-track cost only. ``rows`` optionally gives
    per-row motion parameters (see ``KalmanModel``). ``state`` continues rows from
    ``sequence_state`` (made with the same ``model``).
    """
    n_seq = seqs.shape[0]
    birth = np.ones(n_seq, bool) if birth is None else birth
    end = np.zeros(n_seq, bool) if end is None else end
    st = _filter(layout, d, seqs, params, birth, rows, state, model)
    out, count, first_sensor, last = st.out, st.count, st.first_sensor, st.last
    n_s = layout.n_sensors
    several = count >= 2
    born = birth & several
    ended = end & several
    out[born] += params.misses_before(first_sensor[born])
    out[ended] += params.misses_after(last[ended], n_s)
    return out


def track_sequences(
    d: Detections,
    labels: np.ndarray,
    min_len: int = 3,
    max_tracks: int | None = None,
    seed: int = 0,
) -> np.ndarray:
    """Detections of each track ordered by sensor, as rows of a -1 padded matrix.

    Tracks shorter than ``min_len`` are left out; at most ``max_tracks`` (a seeded sample).
    """
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


def total_nll(
    layout: Layout,
    d: Detections,
    labels: np.ndarray,
    params: MotionParams,
    model: str = 'kalman',
) -> float:
    """Negative log-likelihood of a whole labelling under ``model`` (comparable between
    labellings of the same detections: every detection is in a track or a false alarm).

    Not finite when the model cannot score some track (e.g. a singular innovation covariance
    with extreme slowness); callers must treat such a labelling as unscored.
    """
    seqs = track_sequences(d, labels, min_len=1)
    n = seqs.shape[0]
    if n == 0:
        return 0.0
    ones = np.ones(n, bool)
    return float(sequence_nll(layout, d, seqs, params, ones, ones, model=model).sum())
