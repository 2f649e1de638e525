"""A stream tracker as one shard of a road: its region, its hand-off desk, and what it
publishes (ROS-free apart from the encoder it is given).

The shard's tracker runs on its region's stations, its margin included
(:mod:`mlkm_core.shards.regions`). Its TrackArrays carry only the detections of its own
stations, under ids that name the shard (``run + n * MAX_SHARDS + index``); the margin's
detections are the upstream shard's to publish. After every batch the commits go to the
desk (:mod:`mlkm_core.shards.desk`), and its offers, continuations and commit times are
published as one TrackHandoff.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from mlkm_core.shards.desk import DetId, HandoffDesk
from mlkm_core.shards.regions import MAX_SHARDS, ShardRegion, shard_track_id
from mlkm_core.types import Layout

NS_PER_S = 1_000_000_000
#: A TrackHandoff with no offer and no continuation is published only when the shard's commit
#: or settled time moved this far since the last one it published, or when it caught up with
#: (or fell behind) the newest stamp it took [s]. Every batch commits a little, and a message
#: per batch (and per upstream message received) flooded the shards and the merge that read
#: them; the consumers' decisions wait at most this much longer.
TIMES_STEP = 1.0


@dataclass(frozen=True)
class ShardRole:
    """What a tracker process needs to act as shard ``index`` of ``count`` (picklable)."""

    index: int
    count: int
    margin_ids: tuple[tuple[int, int], ...]  # (sensor id, road order) of the margin stations
    offered_ids: tuple[int, ...]  # sensor ids of the stations offered downstream
    horizon: float  # [s] see mlkm_core.shards.desk
    after_ids: tuple[int, ...] = ()  # sensor ids of the next shard's stations taken too

    @classmethod
    def of(cls, region: ShardRegion, road: Layout, horizon: float) -> ShardRole:
        ids = road.sensor_ids
        return cls(
            region.index,
            region.count,
            tuple((int(ids[s]), s) for s in region.margin),
            tuple(int(ids[s]) for s in region.offered),
            float(horizon),
            tuple(int(ids[s]) for s in region.after),
        )

    @property
    def foreign(self) -> frozenset[int]:
        """Sensor ids of the stations taken but not owned: their detections are another
        shard's to publish."""
        return frozenset(s for s, _ in self.margin_ids) | frozenset(self.after_ids)

    def desk(self) -> HandoffDesk:
        return HandoffDesk(dict(self.margin_ids), self.offered_ids, self.horizon, self.after_ids)

    def first_id(self, at_least: int) -> int:
        """The run's first track id: ``at_least`` rounded up to a multiple of MAX_SHARDS."""
        return -(-at_least // MAX_SHARDS) * MAX_SHARDS

    def track_id(self, run: int, n: int) -> int:
        return shard_track_id(run, n, self.index)


def det_id(row) -> DetId:
    """The join key of a tracker-state row [sensor id, stamp ns, speed, position, lane,
    length]."""
    return (int(row[0]), int(row[4]), int(row[1]), float(row[2]))


class ShardPublisher:
    """The shard's side of each answer: margin detections left out of the tracks, the commits
    through the desk, the hand-off message."""

    def __init__(self, role: ShardRole, encode_handoff) -> None:
        self.role = role
        self.desk = role.desk()
        self._foreign = role.foreign
        self._encode = encode_handoff
        self._shown: set[int] = set()  # tracks published with own detections, not FINAL
        self._newest = -math.inf  # [s] newest stamp the tracker took
        self._sent: tuple[float, float, bool] | None = None  # times of the last message
        self.counts = {'handoff_offers': 0, 'handoff_accepts': 0, 'handoff_received': 0}

    def own_rows(self, track_id: int, status: int, rows: list[tuple]) -> list[tuple] | None:
        """The rows of a changed track to publish (its own stations'); None: not published
        (it holds other shards' detections only and was never shown)."""
        own = [r for r in rows if r[0] not in self._foreign]
        if not own and track_id not in self._shown:
            return None
        if own and status != 2:
            self._shown.add(track_id)
        else:
            self._shown.discard(track_id)
        return own

    def is_own(self, row) -> bool:
        return row[0] not in self._foreign

    def commit(
        self, committed: list[tuple[int, tuple]], until: float, newest: float, run: int
    ) -> bytes | None:
        """Committed (track id or -1, row) of one answer, the commit time and the newest
        stamp taken [s]; the TrackHandoff to publish, None when it would say nothing new
        (``TIMES_STEP``)."""
        self._newest = max(self._newest, newest)
        out = self.desk.commit([(t, det_id(r)) for t, r in committed], until)
        rows = {det_id(r): r for _, r in committed}
        offers: dict[int, list[tuple]] = {}
        for track, det in out.offers:
            offers.setdefault(track, []).append(rows[det])
        return self._message(run, offers, out.accepts)

    def take(self, offers: list[tuple[int, DetId]], upstream_until: float, run: int):
        """Offers of the upstream shard; the TrackHandoff of the continuations decided (None
        when it would say nothing new)."""
        self.counts['handoff_received'] += len(offers)
        self.desk.take_offers(offers, upstream_until)
        return self._message(run, {}, self.desk.decide())

    def _message(self, run: int, offers: dict, accepts: list[tuple[int, int]]) -> bytes | None:
        times = (
            self.desk.committed_until,
            self.desk.settled_until,
            self.desk.settled_until >= self._newest,
        )
        if not offers and not accepts and not self._news(times):
            return None
        self._sent = times
        self.counts['handoff_offers'] += sum(len(v) for v in offers.values())
        self.counts['handoff_accepts'] += len(accepts)
        return self._encode(
            shard=self.role.index,
            shard_count=self.role.count,
            run=run,
            offers=[(t, 1, rows) for t, rows in offers.items()],
            continuations=accepts,
            committed_until_ns=_ns(self.desk.committed_until),
            settled_until_ns=_ns(self.desk.settled_until),
            newest_ns=_ns(self._newest),
        )

    def _news(self, times: tuple[float, float, bool]) -> bool:
        """The times moved enough since the last message to be worth one."""
        if self._sent is None or times[2] != self._sent[2]:
            return True
        return any(
            (now - then >= TIMES_STEP) if math.isfinite(then) else now != then
            for now, then in zip(times[:2], self._sent[:2], strict=True)
        )


def _ns(seconds: float) -> int:
    return max(0, round(seconds * NS_PER_S)) if math.isfinite(seconds) else 0


def encode_handoff(**kwargs) -> bytes:
    """A TrackHandoff, serialized (runs in the tracker process of a shard)."""
    from rclpy.serialization import serialize_message

    from mlkm_ros.handoff_conversions import handoff_to_msg

    return serialize_message(handoff_to_msg(stamp_ns=time.time_ns(), **kwargs))
