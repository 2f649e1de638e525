"""Sensor-to-sensor linking: the machinery of the assignment-based associators.

* ``match_sparse``: optimal one-to-one matching of rows (tracks) to columns (detections) with
  dummies for "row unmatched" (a miss) and "column unmatched" (a false alarm or a new track).
  Only gated candidate pairs are given. A pair is worth linking when its cost is below the sum
  of the two dummy costs, so the problem is a min-weight bipartite matching with weights
  ``w = cost - row_dummy - col_dummy < 0``. The candidate graph is split into connected
  components (time gating makes them small) and each component is solved exactly with
  ``scipy.optimize.linear_sum_assignment`` on a dense block in which non-edges weigh 0, which
  is the standard "dummy rows and columns" augmentation without building the (n+m)^2 matrix.
* ``by_sensor``: detections grouped per sensor, sorted by stamp.
* ``link``: the forward pass. It walks the sensors in road order. At each sensor the active
  tracks (last seen at most ``max_skip`` sensors back) are gated in predicted passage time
  against the detections (``model.link.LinkModel``: motion and cues), and the gated pairs
  are solved by ``match_sparse``: a track left unmatched is a miss (cost -log p_miss per
  skipped sensor, carried forward with the growing variance of the longer gap), a detection
  left unmatched starts a new track (cost -log kappa, kappa = clutter density).
* ``join_fragments``: a track the pass ends where no target can leave, joined to one it
  starts downstream where none can enter, when the whole-track cost favours the link. Its
  reach is the whole road, not ``max_skip``: a vehicle unseen over more sensors than the
  forward pass carries a track (a gap in a camera's coverage) is still one vehicle, and each
  sensor it passed unseen is priced as a miss.
* ``relabel``: a track of a single detection is a false alarm and is labelled UNASSIGNED.
* ``finish_tracks``: what every associator does last (double reports, fragments, relabel).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from mlkm_core.associators.base import canonical_order
from mlkm_core.associators.gating import gate_pairs
from mlkm_core.model.length import LengthParams
from mlkm_core.model.link import LinkModel
from mlkm_core.model.motion import MotionParams
from mlkm_core.progress import advance
from mlkm_core.types import Detections, Layout


def by_sensor(detections: Detections, n_sensors: int) -> list[np.ndarray]:
    """Indices of the detections of each sensor, sorted by (stamp, velocity)."""
    order = canonical_order(detections)
    bounds = np.searchsorted(detections.sensor_index[order], np.arange(n_sensors + 1))
    return [order[bounds[s] : bounds[s + 1]] for s in range(n_sensors)]


def match_sparse(
    rows: np.ndarray, cols: np.ndarray, weight: np.ndarray, n_rows: int, n_cols: int
) -> tuple[np.ndarray, np.ndarray]:
    """Min-weight one-to-one matching over candidate edges with ``weight`` (< 0 to be useful).

    Returns matched (rows, cols). Edges with weight >= 0 never improve on leaving both ends
    unmatched (the dummies), so they are dropped first.
    """
    keep = weight < 0
    rows, cols, weight = rows[keep], cols[keep], weight[keep]
    if rows.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # scipy.optimize takes half a second to import: on first use, not in every process that
    # imports the associators (sources, scorer)
    from scipy.optimize import linear_sum_assignment

    # keep the best edge per (row, col) pair
    graph = coo_matrix(
        (np.ones(rows.size), (rows, n_rows + cols)), shape=(n_rows + n_cols, n_rows + n_cols)
    )
    n_comp, comp = connected_components(graph, directed=False)
    edge_comp = comp[rows]
    order = np.argsort(edge_comp, kind='stable')
    rows, cols, weight, edge_comp = rows[order], cols[order], weight[order], edge_comp[order]
    bounds = np.flatnonzero(np.diff(edge_comp)) + 1
    starts = np.concatenate([[0], bounds])
    ends = np.concatenate([bounds, [rows.size]])
    sizes = ends - starts
    single = sizes == 1
    out_r = [rows[starts[single]]]
    out_c = [cols[starts[single]]]
    for s, e in zip(starts[~single], ends[~single], strict=True):
        r, c, w = rows[s:e], cols[s:e], weight[s:e]
        ur, ri = np.unique(r, return_inverse=True)
        uc, ci = np.unique(c, return_inverse=True)
        block = np.zeros((ur.size, uc.size))
        np.minimum.at(block, (ri, ci), w)
        a, b = linear_sum_assignment(block)
        useful = block[a, b] < 0
        out_r.append(ur[a[useful]])
        out_c.append(uc[b[useful]])
    return np.concatenate(out_r).astype(np.int64), np.concatenate(out_c).astype(np.int64)


def relabel(labels: np.ndarray, min_size: int = 2) -> np.ndarray:
    """Tracks with fewer than ``min_size`` detections become UNASSIGNED; ids made 0..k-1."""
    out = np.full(labels.size, -1, dtype=np.int64)
    valid = labels >= 0
    if not valid.any():
        return out
    ids, inverse, counts = np.unique(labels[valid], return_inverse=True, return_counts=True)
    big = counts[inverse] >= min_size
    new_ids = np.cumsum(counts >= min_size) - 1
    tmp = np.full(valid.sum(), -1, dtype=np.int64)
    tmp[big] = new_ids[inverse[big]]
    out[valid] = tmp
    return out


def link(
    layout: Layout, detections: Detections, params: MotionParams, model: str = 'pairwise'
) -> np.ndarray:
    """Sequential sensor-to-sensor assignment; returns raw track ids (no singleton pruning).

    ``model`` names the motion model (``link.make_model``) of the link model that predicts and
    scores tracks.
    """
    n_s = layout.n_sensors
    per_sensor = by_sensor(detections, n_s)
    labels = np.full(len(detections), -1, dtype=np.int64)
    m = LinkModel(params, model)
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
            pred = m.predict(active, x)
            centre, half = m.gate_window(pred)
            r, c = gate_pairs(centre, half, t)
            if r.size:
                nll, d2 = m.cost(pred.take(r), t[c], u[c], idx[c])
                skipped = s - 1 - last_sensor[active[r]]
                w = nll + skipped * params.miss_cost - params.miss_cost - params.new_cost
                w = np.where(d2 <= params.gate, w, 0.0)
                mr, mc = match_sparse(r, c, w, active.size, idx.size)
                if mr.size:
                    tr = active[mr]
                    m.update(pred.take(mr), t[mc], u[mc], idx[mc])
                    last_sensor[tr] = s
                    labels[idx[mc]] = tr
                    matched_d = mc
        new = np.setdiff1d(np.arange(idx.size), matched_d)
        if new.size:
            ids = np.arange(n_tracks, n_tracks + new.size)
            n_tracks += new.size
            m.grow(new.size)
            last_sensor = np.concatenate([last_sensor, np.full(new.size, s)])
            m.start(ids, x, t[new], u[new], idx[new])
            labels[idx[new]] = ids
        advance(s + 1, n_s)
    return labels


def track_bounds(
    d: Detections, labels: np.ndarray, valid: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The detections ``valid`` ordered by (track, sensor, stamp), and which of them are the
    first (head) and the last (tail) of their track."""
    order = valid[np.lexsort((d.stamp[valid], d.sensor_index[valid], labels[valid]))]
    lab = labels[order]
    head = np.r_[True, lab[1:] != lab[:-1]]
    tail = np.r_[lab[1:] != lab[:-1], True]
    return order, head, tail


def merge_double_reports(d: Detections, labels: np.ndarray, params: MotionParams) -> np.ndarray:
    """Give both reports of a vehicle changing lane on top of a station one track.

    A vehicle changing lane on top of a loop station is reported by both lanes' loops: two
    detections at one sensor, in adjacent lanes, with the same length and nearly the same stamp
    and speed. The forward pass links one of them to the vehicle's track, and either

    * the other one starts a new track that carries on (its lane matches the next
      detections), so the vehicle's track ends there and its rest gets a new label: a track of
      two detections or more that ends at sensor s on detection a is given the label of the
      track that starts at s on a twin b of a; or
    * the track carries on from the report it took and the other one is left alone (a
      single detection, which would be unassigned): it gets the label of its twin's track.

    Twins: lanes known and adjacent, length within 3 standard deviations of a difference, and
    stamp and speed within 3 standard deviations plus what the vehicle's own motion explains:
    the loops see it up to the time it takes to cover its length apart (about 0.8 s at 5 m/s
    in a queue) and its speed may change by ``TWIN_ACCELERATION`` over that time. Both reports
    then share the label (one is a false alarm: its label does not count); the result may have
    two detections of a track at one sensor, so this runs after the association proper.
    """
    if d.lane is None or len(d) == 0:
        return labels
    out = labels.copy()
    valid = np.flatnonzero(out >= 0)
    if valid.size == 0:
        return out
    order, head, tail = track_bounds(d, out, valid)
    known = d.lane[order] >= 0  # a twin's lane is known: the others need no search
    ends = order[tail & ~head & known]  # last detection of a track with two or more
    starts = order[head & ~tail & known]  # first detection of a track with two or more
    alone = order[head & tail & known]  # a track of one detection
    twins = _twin_test(d, params)
    merged: dict[int, int] = {}
    key_s = d.sensor_index[starts]
    for a in ends.tolist():
        cand = starts[key_s == d.sensor_index[a]]
        cand = cand[twins(a, cand)]
        cand = cand[[int(out[c]) not in merged for c in cand]]
        if cand.size == 0:
            continue
        b = int(cand[np.argmin(np.abs(d.stamp[cand] - d.stamp[a]))])
        merged[int(out[b])] = int(out[a])
    if alone.size:
        tracked = order[~(head & tail) & known]
        key_t = d.sensor_index[tracked]
        for b in alone.tolist():
            cand = tracked[key_t == d.sensor_index[b]]
            cand = cand[twins(b, cand)]
            if cand.size:
                merged[int(out[b])] = int(out[cand[np.argmin(np.abs(d.stamp[cand] - d.stamp[b]))]])
    if merged:

        def root(x: int) -> int:
            while x in merged:
                x = merged[x]
            return x

        mapping = np.arange(int(out.max()) + 1)
        for src in merged:
            mapping[src] = root(src)
        out[valid] = mapping[out[valid]]
    return out


_NONE = np.zeros(0, np.int64)


def fragment_pairs(layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams):
    """The candidate joins of ``join_fragments``: None without a valid label, else (ends,
    starts, rows, cols, weight, within): the last detections of the tracks (two detections
    or more) that end where they could not leave, the first of those that start where they
    could not enter, and per gated pair (an end ``ends[rows]``, a start ``starts[cols]``
    anywhere downstream) the weight of the join against the two ends' costs (0 outside the
    pass's gate) and whether it is ``within`` that gate."""
    valid = np.flatnonzero(labels >= 0)
    if valid.size == 0:
        return None
    n_s = layout.n_sensors
    order, head, tail = track_bounds(d, labels, valid)
    ends, starts = order[tail & ~head], order[head & ~tail]
    death = params.misses_after(d.sensor_index[ends], n_s)
    ends, death = ends[death > 0], death[death > 0]
    birth = params.misses_before(d.sensor_index[starts])
    starts, birth = starts[birth > 0], birth[birth > 0] + params.new_cost
    rows, cols, weight, within = [_NONE], [_NONE], [np.zeros(0)], [np.zeros(0, bool)]
    if ends.size == 0 or starts.size == 0:
        return ends, starts, *(a[0] for a in (rows, cols, weight, within))
    pos = layout.positions
    sa, sb = d.sensor_index[ends], d.sensor_index[starts]
    m = LinkModel(params)
    m.grow(ends.size)
    m.start(np.arange(ends.size), pos[sa], d.stamp[ends], 1.0 / d.velocity[ends], ends)
    for skip in range(n_s - 1 - int(sa.min())):  # to the last sensor
        i = np.flatnonzero(sa + 1 + skip < n_s)
        pred = m.predict(i, pos[sa[i] + 1 + skip])
        r, c = gate_pairs(*m.gate_window(pred), d.stamp[starts])
        keep = sb[c] == sa[i[r]] + 1 + skip
        r, c = r[keep], c[keep]
        if r.size == 0:
            continue
        nll, d2 = m.cost(pred.take(r), d.stamp[starts[c]], 1.0 / d.velocity[starts[c]], starts[c])
        w = nll + skip * params.miss_cost - death[i[r]] - birth[c]
        rows.append(i[r])
        cols.append(c)
        within.append(d2 <= params.gate)
        weight.append(np.where(within[-1], w, 0.0))
    return ends, starts, *(np.concatenate(a) for a in (rows, cols, weight, within))


def join_fragments(
    layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams
) -> np.ndarray:
    """Join a track that ends mid-road to one that starts a few sensors downstream.

    The forward pass decides each sensor alone: leaving a track unmatched costs it one miss
    and the detection one new track, so it breaks a link whose cost is a few nats above that
    (a car accelerating hard away from an on-ramp, one that waited to merge at a lane drop).
    Under the whole-track model of ``likelihood.sequence_nll`` a break costs much more where
    targets can neither leave nor enter: the track that ends has missed every sensor after it
    (``MotionParams.misses_after``) and the one that starts is a new track that has missed
    every sensor before it (``misses_before``). Here each track of two detections or more that
    ends where it could not leave (``params.open_road``; anywhere before the last sensor on a
    closed road) is matched one-to-one (``match_sparse``) to those that start downstream
    where they could not enter, however many sensors lie between: ``max_skip`` bounds the
    tracks the forward pass carries, not how long a vehicle may go unseen (on NGSIM I-80 with
    vehicles seen where they were observed, 20 loops, one vehicle is unseen at four loops in
    a row). A link is scored as the pairwise pass scores it (motion model, lane and length,
    the pass's gate) plus a miss per sensor skipped, against the two ends' costs. ``labels``
    are raw track ids (-1 allowed) and may hold two reports of a vehicle at one sensor
    (``merge_double_reports``); a track's end is its latest detection and its start its
    earliest. Returns new labels.
    """
    out = labels.copy()
    pairs = fragment_pairs(layout, d, out, params)
    if pairs is None:
        return out
    ends, starts, rows, cols, weight, _ = pairs
    if rows.size == 0:
        return out
    mr, mc = match_sparse(rows, cols, weight, ends.size, starts.size)
    mapping = np.arange(int(out.max()) + 1)
    mapping[out[starts[mc]]] = out[ends[mr]]
    for _ in range(mr.size):  # a chain of joins takes the label of its first fragment
        nxt = mapping[mapping]
        if np.array_equal(nxt, mapping):
            break
        mapping = nxt
    valid = out >= 0
    out[valid] = mapping[out[valid]]
    return out


def finish_tracks(
    layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams
) -> np.ndarray:
    """The last steps of every associator: a lane change's two reports share a track
    (``merge_double_reports``), fragments of a track are joined (``join_fragments``), and a
    track of a single detection becomes UNASSIGNED (``relabel``)."""
    labels = merge_double_reports(d, labels, params)
    return relabel(join_fragments(layout, d, labels, params))


#: largest speed change [m/s^2] between the two loops' reports of a vehicle changing lane:
#: ordinary braking, as of a vehicle that slows down to merge into a queue (3-4 m/s^2; the
#: comfortable deceleration of car-following models, SUMO's default for a car included, is
#: 4.5 m/s^2)
TWIN_ACCELERATION = 4.5
#: vehicle length [m] assumed where the sensor does not report it
TYPICAL_LENGTH = 4.5


def _twin_test(d: Detections, params: MotionParams):
    """twins(a, cand): which detections of ``cand`` (at a's sensor) may be a's twin report."""
    k = 3 * math.sqrt(2)
    tol_t = k * max(params.stamp_noise, 0.05) + 0.2
    tol_v = k * max(params.velocity_noise, 0.05)
    fitted = None if params.cues is None else params.cues.params.get('length')
    tol_l = k * max(LengthParams().length_noise if fitted is None else fitted.length_noise, 0.05)

    def twins(a: int, cand: np.ndarray) -> np.ndarray:
        dt = np.abs(d.stamp[cand] - d.stamp[a])
        size = TYPICAL_LENGTH
        if d.length is not None and np.isfinite(d.length[a]):
            size = float(d.length[a])
        ok = dt <= tol_t + size / d.velocity[a]
        ok &= np.abs(d.velocity[cand] - d.velocity[a]) <= tol_v + TWIN_ACCELERATION * dt
        ok &= (d.lane[a] >= 0) & (d.lane[cand] >= 0) & (np.abs(d.lane[cand] - d.lane[a]) == 1)
        if d.length is not None:
            ok &= ~(np.abs(d.length[cand] - d.length[a]) > tol_l)
        return ok

    return twins
