"""Where tracks begin and end mid-road: the entry and exit rates of each sensor, from the data.

A track first seen at a sensor past the first one has, on a closed road, missed every sensor
before it (``MotionParams.misses_before``); one last seen before the last sensor will miss
every one after it. Where vehicles are observed over only part of the road (detectors that
report a vehicle only where it was observed, a camera's field of view, a road whose side
streets nobody declared) tracks begin and end mid-road far more often than misses explain:
on NGSIM I-80 with the vehicles seen where they were observed, five loops, a fifth to two
fifths of the tracks passing the second loop begin there, and no loop missed a vehicle.
Charged as misses, each of those true tracks costs several nats more than a wrong one that
takes over another's detections, and the whole-track search (``search.refine``) and the
fragment join (``linking.join_fragments``) prefer the wrong one.

``estimate_entries`` counts, on the tracks of a pass, the tracks that begin mid-road with no
track ending upstream that the pass's gate could join them to (a track the pass broke within
the gate has that partner; a vehicle that entered has none), and the tracks that end mid-road
with no such partner downstream. A break beyond the gate leaves one of each, or a track and
a detection the pass left alone (on SUMO free flow, where every vehicle enters before the
first station, four tracks began at the second one so), so only the excess of one kind over
the other and the lone detections (at least ``MIN_EXCESS`` tracks) is taken as vehicles
entering or leaving, spread over the sensors as the lone tracks are, each sensor's rate a
share of the tracks passing it. A track beginning there then costs -log(entry rate +
p_miss^k) (``MotionParams.entry_rate``): the more likely of "it entered here" and "it missed
the k sensors before"; likewise at its end. On a road whose vehicles are seen at every
sensor no such excess shows, the rates stay None and nothing changes (every dataset of the
product's simulator at 10 x 10 and 50 x 20, the closed NGSIM loops).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mlkm_core.associators.linking import fragment_pairs, relabel, track_bounds
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Detections, Layout

#: fewest tracks that begin (end) mid-road beyond those that end (begin) there for a rate to
#: be estimated: one or two are a vehicle whose first detection was missed or a pass's stray
#: break (on SUMO free flow one such track halved the cost of every track beginning at that
#: station and cost `multiframe` 0.15 points), not vehicles that enter
MIN_EXCESS = 3


def _passing(layout: Layout, d: Detections, labels: np.ndarray) -> np.ndarray:
    """Per sensor, how many tracks of two detections or more pass it (first to last)."""
    change = np.zeros(layout.n_sensors + 1)
    valid = np.flatnonzero(labels >= 0)
    if valid.size:
        order, head, tail = track_bounds(d, labels, valid)
        np.add.at(change, d.sensor_index[order[head & ~tail]], 1.0)
        np.add.at(change, d.sensor_index[order[tail & ~head]] + 1, -1.0)
    return np.cumsum(change)[:-1]


def estimate_entries(
    layout: Layout, d: Detections, labels: np.ndarray, params: MotionParams
) -> MotionParams:
    """``params`` with the entry and exit rates of each sensor estimated from the tracks of a
    pass (``labels``; module docstring); a rate that no track shows stays None."""
    labels = relabel(labels)
    # a detection the pass left alone may be the piece of a break that is not a track
    singles = int(np.count_nonzero(labels < 0))
    pairs = fragment_pairs(layout, d, labels, params)
    if pairs is None:
        return params
    ends, starts, rows, cols, _, within = pairs
    passing = np.maximum(_passing(layout, d, labels), 1.0)
    n_s = layout.n_sensors

    def alone(heads: np.ndarray, partnered: np.ndarray) -> np.ndarray:
        out = np.ones(heads.size, bool)
        out[partnered] = False
        return heads[out]

    lone_starts, lone_ends = alone(starts, cols[within]), alone(ends, rows[within])

    def rate(heads: np.ndarray, others: np.ndarray) -> np.ndarray | None:
        # a break beyond the gate leaves one lone start and one lone end, or a detection left
        # alone: only the excess of one kind over the other and the lone detections is
        # vehicles entering or leaving
        excess = heads.size - others.size - singles
        if excess < MIN_EXCESS:
            return None
        counts = np.bincount(d.sensor_index[heads], minlength=n_s) * (excess / heads.size)
        return np.minimum(counts / passing, 1.0)

    return replace(
        params,
        entry_rate=rate(lone_starts, lone_ends),
        exit_rate=rate(lone_ends, lone_starts),
    )
