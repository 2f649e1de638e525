"""Shards offline: a road's detections associated by several stream trackers, one per
region, joined by their hand-off desks (what ``association_node`` shards do over DDS, in one
process and in a fixed order, so the result is a function of the detections alone).

Each detection goes, in stamp order, to the tracker of the shard that owns its station and
to those that take it as margin. After every push the commits go to that shard's desk;
its offers and commit time go to the next shard's desk. A detection's label is its owner's
committed track, followed up the continuations to the track that began upstream.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from mlkm_core.shards.desk import DEFAULT_HORIZON, DetId, HandoffDesk
from mlkm_core.shards.regions import DEFAULT_MARGIN, ShardRegion, shard_track_id, split_road
from mlkm_core.types import UNKNOWN_LANE, Detections, Layout

NS_PER_S = 1_000_000_000


@dataclass
class ShardedResult:
    """Labels of every detection (-1 unassigned), the regions, and per shard: detections
    pushed, tracks continued from upstream, and the tracker's counters."""

    labels: np.ndarray
    regions: list[ShardRegion]
    pushed: list[int] = field(default_factory=list)
    accepted: list[int] = field(default_factory=list)
    offered: list[int] = field(default_factory=list)
    stats: list[dict] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)  # [s] CPU in each shard's tracker


def det_ids(layout: Layout, d: Detections) -> list[DetId]:
    """The join key of every detection of ``d`` (sensor id, lane, stamp ns, speed)."""
    n = len(d.stamp)
    lane = d.lane if d.lane is not None else np.full(n, UNKNOWN_LANE)
    ids = layout.sensor_ids[d.sensor_index]
    return [
        (int(ids[i]), int(lane[i]), round(float(d.stamp[i]) * NS_PER_S), float(d.velocity[i]))
        for i in range(n)
    ]


def root_of(parent: dict[int, int], track: int) -> int:
    """The track a continuation chain began with."""
    seen = set()
    while track in parent and track not in seen:
        seen.add(track)
        track = parent[track]
    return track


def associate_sharded(
    layout: Layout,
    d: Detections,
    count: int,
    config=None,
    margin: int = DEFAULT_MARGIN,
    horizon: float = DEFAULT_HORIZON,
    loads: np.ndarray | None = None,
) -> ShardedResult:
    """Associate ``d`` on ``layout`` with ``count`` shards (``config``: the trackers'
    ``StreamConfig``, the default when None)."""
    from mlkm_core.streaming import StreamConfig, StreamTracker

    config = config or StreamConfig()
    regions = split_road(layout.n_sensors, count, margin, loads)
    trackers, desks, local = [], [], []
    for r in regions:
        trackers.append(StreamTracker(r.layout(layout), config))
        desks.append(
            HandoffDesk(
                {int(layout.sensor_ids[s]): s for s in r.margin},
                (int(layout.sensor_ids[s]) for s in r.offered),
                horizon,
                (int(layout.sensor_ids[s]) for s in r.after),
            )
        )
        local.append({s: i for i, s in enumerate(r.stations)})
    owner = np.empty(layout.n_sensors, np.int64)
    for r in regions:
        owner[list(r.own)] = r.index
    ids = det_ids(layout, d)
    n = len(d.stamp)
    lane = d.lane if d.lane is not None else np.full(n, UNKNOWN_LANE)
    length = d.length if d.length is not None else np.full(n, np.nan)
    committed = np.full(n, -2, np.int64)  # the owner's committed track; -2 not yet
    parent: dict[int, int] = {}
    result = ShardedResult(np.full(n, -1, np.int64), regions)
    result.pushed = [0] * count
    result.accepted = [0] * count
    result.offered = [0] * count
    result.seconds = [0.0] * count

    def take(k: int, update) -> None:
        rows = []
        for key, track in update.committed.tolist():
            gid = shard_track_id(0, track, k) if track >= 0 else -1
            rows.append((gid, ids[key]))
            if owner[d.sensor_index[key]] == k:
                committed[key] = gid
        out = desks[k].commit(rows, update.committed_until)
        for up, here in out.accepts:
            parent[here] = up
        result.accepted[k] += len(out.accepts)
        result.offered[k] += len(out.offers)
        if k + 1 < count:
            desks[k + 1].take_offers(out.offers, desks[k].committed_until)
            for up, here in desks[k + 1].decide():
                parent[here] = up
                result.accepted[k + 1] += 1

    order = np.lexsort((np.arange(n), d.sensor_index, d.stamp)).tolist()
    for i in order:
        s = int(d.sensor_index[i])
        k = int(owner[s])
        for j in (k - 1, k, k + 1):
            if 0 <= j < count and s in local[j]:
                row = (float(d.stamp[i]), float(d.velocity[i]), int(lane[i]), float(length[i]))
                t0 = time.process_time()
                update = trackers[j].push(i, local[j][s], *row)
                result.seconds[j] += time.process_time() - t0
                take(j, update)
                result.pushed[j] += 1
    for k in range(count):
        t0 = time.process_time()
        update = trackers[k].flush()
        result.seconds[k] += time.process_time() - t0
        take(k, update)
        desks[k].committed_until = math.inf
    for k in range(1, count):
        desks[k].take_offers((), math.inf)
        for up, here in desks[k].decide():
            parent[here] = up
            result.accepted[k] += 1
    if np.any(committed == -2):
        raise RuntimeError(f'{int((committed == -2).sum())} detections were never committed')
    result.labels = np.array([root_of(parent, t) if t >= 0 else -1 for t in committed.tolist()])
    result.stats = [t.stats() for t in trackers]
    return result
