"""A road split into shard regions: contiguous runs of stations of about equal load.

Each shard owns a run of stations (it publishes their detections) and also takes the last
``margin`` stations of the shard upstream of it and the first ``margin`` stations of the
shard downstream. The upstream margin gives its tracker the link across the border that one
tracker over the whole road would make, and its detections are the ones an upstream shard's
hand-off offers name (:mod:`mlkm_core.shards.desk`). The downstream margin gives the tracks
that reach the border the evidence after it: without it a vehicle that enters just before a
border would have one detection in the shard, and be taken for a false alarm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlkm_core.types import Layout

#: Stations of the upstream shard a shard takes besides its own (default) [-].
DEFAULT_MARGIN = 6
#: Shards a road is split into at most; a shard's index is its track ids' residue modulo
#: this (:func:`shard_track_id`) [-].
MAX_SHARDS = 1024


@dataclass(frozen=True)
class ShardRegion:
    """Shard ``index`` of ``count``: the stations it owns and its margin, as indices into the
    whole road's layout, both in road order."""

    index: int
    count: int
    own: tuple[int, ...]
    margin: tuple[int, ...]
    offered: tuple[int, ...]  # own stations that are the next shard's margin (none: last)
    after: tuple[int, ...] = ()  # the next shard's first stations, taken as evidence only

    @property
    def stations(self) -> tuple[int, ...]:
        """Every station the shard takes, in road order: its margin, its own, the next
        shard's first ones."""
        return self.margin + self.own + self.after

    def layout(self, road: Layout) -> Layout:
        """The road's layout restricted to this shard's stations (positions, ids and names
        of the whole road, so detections and tracks need no translation)."""
        idx = np.asarray(self.stations, np.int64)
        return Layout(
            road.road_length,
            road.positions[idx],
            road.sensor_ids[idx],
            tuple(road.names[i] for i in idx.tolist()),
        )


def split_road(
    n_sensors: int,
    count: int,
    margin: int = DEFAULT_MARGIN,
    loads: np.ndarray | None = None,
) -> list[ShardRegion]:
    """``count`` regions of contiguous stations of about equal load: ``loads`` per station
    (detections seen, or a flow estimate; equal when None). Each region but the first takes
    ``margin`` stations of the one before, each but the last ``margin`` of the one after
    (fewer when that one is shorter)."""
    if not 1 <= count <= MAX_SHARDS:
        raise ValueError(f'shard count must be in 1..{MAX_SHARDS}, got {count}')
    if count > n_sensors:
        raise ValueError(f'{count} shards for {n_sensors} stations: at most one per station')
    if margin < 1:
        raise ValueError(f'the margin must be at least one station, got {margin}')
    w = np.ones(n_sensors) if loads is None else np.asarray(loads, float)
    if w.shape != (n_sensors,) or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError('loads must be finite and non-negative, one per station')
    if w.sum() <= 0:
        w = np.ones(n_sensors)
    # cut after the station whose cumulative load is nearest k/count of the total, keeping
    # at least one station per region
    cum = np.cumsum(w) / w.sum()
    cuts = [0]
    for k in range(1, count):
        c = int(np.argmin(np.abs(cum - k / count))) + 1
        c = min(max(c, cuts[-1] + 1), n_sensors - (count - k))
        cuts.append(c)
    cuts.append(n_sensors)
    margins = [
        tuple(range(max(cuts[k - 1], cuts[k] - margin), cuts[k])) if k else ()
        for k in range(count)
    ]
    return [
        ShardRegion(
            k,
            count,
            tuple(range(cuts[k], cuts[k + 1])),
            margins[k],
            margins[k + 1] if k + 1 < count else (),
            tuple(range(cuts[k + 1], min(cuts[k + 1] + margin, cuts[k + 2])))
            if k + 1 < count
            else (),
        )
        for k in range(count)
    ]


def shard_track_id(first_id: int, n: int, index: int) -> int:
    """Track ``n`` of shard ``index`` whose ids start at ``first_id`` (a multiple of
    ``MAX_SHARDS``): ids of different shards never meet, and the id names its origin
    (``id % MAX_SHARDS``)."""
    return first_id + n * MAX_SHARDS + index
