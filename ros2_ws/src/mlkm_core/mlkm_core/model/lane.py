"""The lane cue: a vehicle keeps its lane between nearby stations unless it changes lane.

A lane change across the gap between stations g and g + 1 has probability p_g. Over the gaps
from the track's last known lane (lane a, station s_a) to station s_b, stay = prod (1 - p_g).
Same lane: ratio stay / P_pop(a at s_b); another lane (chosen like the population among the
other lanes): ratio (1 - stay) / (1 - P_pop(a at s_b)). P_pop is the lane frequency per
station (Laplace-smoothed). The cost is -log(ratio); an unknown lane (-1) costs nothing.

``fit`` estimates p_g from the links of a pass: a distance-proportional rate over all gaps,
and per gap its own share of changes shrunk to that rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlkm_core.model.cues import Cue, CueKind, CueTracks
from mlkm_core.types import Detections, Layout, link_pairs

#: bounds of a lane change probability per gap
CHANGE_BOUNDS = (1e-3, 0.95)
#: weight (in links) of the distance-proportional prior of a gap's lane-change probability
CHANGE_PRIOR_LINKS = 10.0


@dataclass(frozen=True)
class LaneParams:
    change_rate: float = 1e-4  # lane changes per metre (prior of every gap)
    change: np.ndarray | None = None  # p_g per gap (n_sensors - 1,), None = from the rate


class LaneCue(Cue):
    name = 'lane'

    def __init__(self, layout: Layout, d: Detections, params: LaneParams) -> None:
        self.params = params
        self.lane = d.lane.copy()
        self.sensor = d.sensor_index
        n_s = layout.n_sensors
        gaps = np.diff(layout.positions)
        p = params.change
        if p is None or p.shape != gaps.shape:
            p = 1 - np.exp(-params.change_rate * gaps)
        p = np.clip(p, *CHANGE_BOUNDS)
        self.log_stay = np.concatenate([[0.0], np.cumsum(np.log1p(-p))])
        # lane frequency per station
        known = self.lane >= 0
        n_lanes = int(self.lane[known].max()) + 1
        counts = np.zeros((n_s, n_lanes))
        np.add.at(counts, (self.sensor[known], self.lane[known]), 1.0)
        width = np.zeros(n_s, np.int64)
        np.maximum.at(width, self.sensor[known], self.lane[known] + 1)
        present = np.arange(n_lanes)[None, :] < width[:, None]
        counts = counts + present
        self.pop_lane = counts / np.maximum(counts.sum(axis=1, keepdims=True), 1.0)

    def tracks(self, accumulate: bool) -> LaneTracks:
        return LaneTracks(self, accumulate)


class LaneTracks(CueTracks):
    """Per track: its last known lane and the station where it was seen in it."""

    FIELDS = {'lane': (-1, np.int64), 'sensor': (0, np.int64)}

    def __init__(self, cue: LaneCue, accumulate: bool) -> None:
        super().__init__(accumulate)
        self.cue = cue

    def start(self, tracks: np.ndarray, det: np.ndarray) -> None:
        self.state['lane'][tracks] = self.cue.lane[det]
        self.state['sensor'][tracks] = self.cue.sensor[det]

    def cost(self, tracks: np.ndarray, det: np.ndarray) -> np.ndarray:
        c = self.cue
        out = np.zeros(det.size)
        la, lb = self.state['lane'][tracks], c.lane[det]
        ok = (la >= 0) & (lb >= 0)
        if ok.any():
            sb = c.sensor[det[ok]]
            # either direction along the road (mlkm_robust also matches backwards)
            sa = self.state['sensor'][tracks[ok]]
            stay = np.exp(-np.abs(c.log_stay[sb] - c.log_stay[sa]))
            lane_a = la[ok]
            inside = lane_a < c.pop_lane.shape[1]
            pop_a = np.where(
                inside, c.pop_lane[sb, np.minimum(lane_a, c.pop_lane.shape[1] - 1)], 0
            )
            pop_a = np.clip(pop_a, 1e-6, 1 - 1e-6)
            ratio = np.where(lane_a == lb[ok], stay / pop_a, (1 - stay) / (1 - pop_a))
            out[ok] = -np.log(np.maximum(ratio, 1e-300))
        return out

    def update(self, tracks: np.ndarray, det: np.ndarray) -> None:
        lb = self.cue.lane[det]
        known = lb >= 0
        self.state['lane'][tracks[known]] = lb[known]
        self.state['sensor'][tracks[known]] = self.cue.sensor[det[known]]


def bind(layout: Layout, d: Detections, params: LaneParams) -> LaneCue | None:
    """The cue on ``d``; None when no lane is known, or when every known lane is the same one
    (a one-lane road): then no vehicle changes lane, the cue carries no information and must
    not weigh in the links."""
    if d.lane is None or np.unique(d.lane[d.lane >= 0]).size < 2:
        return None
    return LaneCue(layout, d, params)


def fit(
    layout: Layout, d: Detections, labels: np.ndarray, base: LaneParams | None = None
) -> LaneParams:
    """Lane-change probabilities per gap from the links of the tracks ``labels`` (robust to a
    few wrong links); ``base`` (the generic values) where there are too few links."""
    base = base or LaneParams()
    rate, change = base.change_rate, None
    if d.lane is not None:
        a, b = link_pairs(d, labels)
        ok = (d.lane[a] >= 0) & (d.lane[b] >= 0)
        a2, b2 = a[ok], b[ok]
        if a2.size >= 10:
            pos = layout.positions
            changed = d.lane[a2] != d.lane[b2]
            dx = pos[d.sensor_index[b2]] - pos[d.sensor_index[a2]]
            rate = max(float(changed.sum()) / max(float(dx.sum()), 1.0), 1e-7)
            gaps = np.diff(pos)
            prior = 1 - np.exp(-rate * gaps)
            one = d.sensor_index[b2] - d.sensor_index[a2] == 1
            g = d.sensor_index[a2[one]]
            n_g = np.bincount(g, minlength=gaps.size).astype(float)
            c_g = np.bincount(g, changed[one], minlength=gaps.size)
            k = CHANGE_PRIOR_LINKS
            change = np.clip((c_g + k * prior) / (n_g + k), *CHANGE_BOUNDS)
    return LaneParams(rate, change)


KIND = CueKind('lane', needs='known lanes, two or more', bind=bind, fit=fit, generic=LaneParams())
