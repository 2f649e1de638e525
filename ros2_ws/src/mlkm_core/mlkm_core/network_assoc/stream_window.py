"""One window of the network stream as a pure function of plain data, so that it can run
beside the stream (another thread, or the live node's solver process, which gets it pickled).

``solve_window(job)`` links the window's detections by the network ``assignment`` under the
carried model, after fitting that model again on ``job.fit`` when it is given. The tracker
(``network_assoc.stream``) snapshots a ``WindowJob`` at a due boundary and applies the
``WindowResult`` at that boundary, whenever it comes back.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlkm_core.network import RoadNetwork
from mlkm_core.network_assoc.fit import NetworkModel, calibrate_and_link
from mlkm_core.network_assoc.hops import Hops
from mlkm_core.network_assoc.linking import solve
from mlkm_core.types import Detections

#: a held detection: (station index, stamp [s], speed [m/s], lane (-1 unknown), length [m])
Row = tuple[int, float, float, int, float]


@dataclass(frozen=True)
class WindowJob:
    """What a window solve needs, and nothing of the tracker."""

    net: RoadNetwork
    hops: Hops
    window: Detections  # the window's detections, in the tracker's key order
    model: NetworkModel | None  # the carried model (None: fit it on ``fit``)
    fit: Detections | None = None  # rows to fit the model on first (None: keep ``model``)


@dataclass(frozen=True)
class WindowResult:
    labels: np.ndarray  # one per window detection: its window track, -1 alone
    travel: np.ndarray  # [s] the travel time of each link of the solve
    model: NetworkModel | None  # the model fitted for this window (None: the carried one)


def solve_window(job: WindowJob) -> WindowResult:
    model, fitted = job.model, None
    if job.fit is not None:
        _, fitted = calibrate_and_link(job.net, job.hops, job.fit)
        model = fitted
    if model is None:
        raise ValueError('a window needs a carried model or rows to fit one on')
    d = job.window
    labels, links = solve(
        job.hops, d, model.motion, model.junctions, model.cue(d), model.lanes, model.per_hop
    )
    return WindowResult(labels, d.stamp[links.b] - d.stamp[links.a], fitted)


def detections_of(rows: list[Row]) -> Detections:
    """Rows as Detections, with lane and length where any row reports them."""
    s, t, v, lane, length = (np.array(c) for c in zip(*rows, strict=True))
    lane = lane.astype(np.int64)
    return Detections(
        s.astype(np.int64),
        t.astype(float),
        v.astype(float),
        lane=lane if np.any(lane >= 0) else None,
        length=length.astype(float) if np.any(np.isfinite(length)) else None,
    )
