"""What stream mode's tracker process keeps: the core's
:class:`~mlkm_core.streaming.StreamTracker` behind its reorder buffer, the data of the
detections it may still publish, and each batch's answer as a ready-to-publish TrackArray
(ROS-free apart from ``encode_tracks``). The process around it is
:mod:`mlkm_assoc.stream_worker`.

Whatever is queued when the process gets to it is pushed as one batch and answered with one
TrackArray holding the latest state of every track the batch changed (TrackArray
MODE_STREAM: tracks with all their detections, the detections that became unassigned,
committed_until). Memory stays bounded: a detection's data is dropped once its link is
committed and its track is FINAL (or it was committed unassigned).

Track ids: each tracker (one per layout) is a *run*, numbered by its start in microseconds
since the Unix epoch (TrackArray.run), or just past the last id used when that is later; the
core's track n of the run is published as run + n. A run numbers far fewer tracks than
microseconds pass, so the ids of a node restarted later never meet those it published
before, and they stay below 2^53 (exact in a float).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any

from mlkm_assoc.reorder import ReorderBuffer
from mlkm_assoc.stream_merged import MergedUpdate
from mlkm_assoc.stream_shard import ShardPublisher, ShardRole
from mlkm_core.types import Layout

NS_PER_S = 1_000_000_000
#: Track status values (road_sensor_msgs/Track.STATUS_*; the core's TENTATIVE..FINAL).
TENTATIVE, CONFIRMED, FINAL = 0, 1, 2


@dataclass(frozen=True)
class TrackerSettings:
    """What the process needs to build trackers (picklable)."""

    method: str
    lag: float  # [s]
    segment_size: int
    seed: int
    max_uncommitted: int = 0  # StreamConfig.max_uncommitted (0: no bound) [-]

    def stream_config(self) -> Any:
        """The core's StreamConfig of these settings (imported here: the core's streaming
        package loads only where a tracker is built)."""
        from mlkm_core.streaming import StreamConfig

        return StreamConfig(**asdict(self))


#: A queued detection: ('det', key, sensor index, sensor id, stamp ns, velocity, position,
#: lane, length, monotonic arrival time). Other items: ('layout', Layout, entries, exits,
#: ShardRole or None), ('handoff', offers, upstream committed_until [s]) (a shard's),
#: ('flush', monotonic time), ('tick', monotonic time: the node's clock while nothing
#: arrives) and None (stop).
Item = tuple


@dataclass
class Answer:
    """What one batch changed, ready to publish, with the tracker's counters."""

    data: bytes | None  # CDR of a TrackArray; None when nothing changed
    received_at: list[float]  # monotonic arrival time of each detection of the batch
    tracks: int  # tracks in the message
    unassigned: int  # unassigned detections in the message
    solve_time: float  # [s] spent in the tracker on this batch
    committed_until: float  # [s] stamp time
    newest_stamp: float  # [s] stamp time
    working_set: int  # detections the tracker holds
    held: int  # detections whose data this process holds
    flushed: bool = False
    stats: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    # monotonic times (the clock every process of the machine shares) of each detection of
    # the batch: taken from the queue by this process, released by the reorder buffer
    dequeued_at: list[float] = field(default_factory=list)
    released_at: list[float] = field(default_factory=list)
    sent_at: float = math.nan  # monotonic time the answer was sent to the node
    handoff: bytes | None = None  # CDR of a TrackHandoff to publish (a shard's tracker)


class TrackerState:
    """The tracker and the data of the detections it may still publish (ROS-free apart from
    ``encode``, which turns a batch into a serialized TrackArray)."""

    def __init__(
        self, settings: TrackerSettings, encode, executor=None, encode_handoff=None
    ) -> None:
        self._settings = settings
        self._encode = encode
        self._encode_handoff = encode_handoff  # serializes a TrackHandoff (shards only)
        self._shard: ShardPublisher | None = None
        self._executor = executor  # runs the tracker's window solves (None: inside push)
        self._tracker = None
        self._layout: Layout | None = None
        self._network = False
        self._method = settings.method  # the method the tracks were linked with
        self._rows: dict[int, list] = {}  # key -> [sensor id, stamp ns, v, pos, lane, length]
        self._committed: dict[int, int] = {}  # key -> committed track (-1 unassigned)
        self._final: dict[int, int] = {}  # final track -> its detections still held
        self._published: dict[int, int] = {}  # key -> track it was last published in
        self.counts: dict[str, int] = {
            'pushed': 0,
            'tracks_confirmed': 0,
            'tracks_final': 0,
            'links_revised': 0,
            'flushes': 0,
            'push_errors': 0,
        }
        self._confirmed_ids: set[int] = set()  # confirmed tracks that are not final yet
        self.newest = -math.inf
        self.committed_until = -math.inf
        self._reorder: ReorderBuffer | None = None
        self.node_now = -math.inf  # the node's clock as far as its items tell [s]
        self.run = 0  # the current run's first track id [us since the Unix epoch]
        self._next_id = 0  # past every track id published so far

    # --- inputs ---------------------------------------------------------------------------
    def set_layout(self, layout: Layout, entries, exits, shard: ShardRole | None = None) -> Answer:
        """A new road, a new run: the old tracker is flushed first (its tracks become
        FINAL); the first road of the process announces its run with an empty TrackArray,
        which tells consumers that the tracks of a run before a restart have ended.
        ``shard``: the layout is a shard's region (:mod:`mlkm_assoc.stream_shard`)."""
        answer = self.flush(time.monotonic()) if self._tracker is not None else None
        from mlkm_core.network_assoc.stations import NetworkStations
        from mlkm_core.network_assoc.stream import NetworkStreamConfig, NetworkStreamTracker
        from mlkm_core.streaming import StreamTracker

        if isinstance(layout, NetworkStations):  # a road network: its own stream
            config = NetworkStreamConfig(lag=self._settings.lag)
            self._tracker = NetworkStreamTracker(layout.network, config, self._executor)
        else:
            self._tracker = StreamTracker(
                layout,
                self._settings.stream_config(),
                entries=entries,
                exits=exits,
                executor=self._executor,
            )
        self.run = max(time.time_ns() // 1000, self._next_id)
        self._shard = None
        if shard is not None:
            self._shard = ShardPublisher(shard, self._encode_handoff)
            self.run = shard.first_id(self.run)
        self._layout = layout
        self._network = isinstance(layout, NetworkStations)  # tracks ordered by stamp
        # the method the tracks were linked with: on a network, the network stream's own
        self._method = NetworkStreamTracker.METHOD if self._network else self._settings.method
        self._reorder = ReorderBuffer(layout.n_sensors)
        self.newest = self.committed_until = -math.inf
        if answer is None:
            data = self._encode(
                method=self._method,
                tracks=[],
                unassigned=[],
                committed_until_ns=0,
                solve_time=0.0,
                run=self.run,
                by_stamp=self._network,
            )
            answer = Answer(data, [], 0, 0, 0.0, -math.inf, -math.inf, 0, 0)
        return answer

    def hold(self, item: Item) -> None:
        """A detection into the reorder buffer (see :mod:`mlkm_assoc.reorder`)."""
        self.node_now = max(self.node_now, item[9])
        self._reorder.add((item, time.monotonic()), item[2], item[4] / NS_PER_S, item[9])

    def tick(self, now: float) -> None:
        self.node_now = max(self.node_now, now)

    def release(self, drain: bool = False) -> Answer | None:
        """Push what the reorder buffer releases by the node's clock (everything with
        ``drain``)."""
        if self._reorder is None:
            return None
        ready = self._reorder.drain() if drain else self._reorder.release(self.node_now)
        if not ready:
            return None
        now = time.monotonic()
        answer = self.push_batch([r[0] for r in ready])
        answer.dequeued_at = [r[1] for r in ready]
        answer.released_at = [now] * len(ready)
        return answer

    def push_batch(self, items: list[Item]) -> Answer:
        if self._tracker is None:
            return Answer(
                None,
                [i[9] for i in items],
                0,
                0,
                0.0,
                -math.inf,
                -math.inf,
                0,
                0,
                error='detections before the layout reached the tracker process',
            )
        merged = MergedUpdate(self._track_id)
        received = []
        t0 = time.perf_counter()
        error = None
        for item in items:
            _, key, s, sensor_id, stamp_ns, velocity, position, lane, length, rx = item
            received.append(rx)
            self._rows[key] = [sensor_id, stamp_ns, velocity, position, lane, length]
            stamp = stamp_ns / NS_PER_S
            self.newest = max(self.newest, stamp)
            self.counts['pushed'] += 1
            try:
                update = self._tracker.push(key, s, stamp, velocity, lane, length)
            except Exception as exc:  # noqa: BLE001 - reported; the detection stays unassigned
                self.counts['push_errors'] += 1
                error = f'tracker refused detection {key}: {type(exc).__name__}: {exc}'
                merged.unassigned[key] = None
                continue
            merged.add(update)
        return self._answer(merged, received, time.perf_counter() - t0, error)

    def defer_solves(self, on: bool) -> None:
        """Hold due window solves back while a backlog of detections waits (see
        ``StreamTracker.deferring``)."""
        if self._tracker is not None:
            self._tracker.deferring = on

    @property
    def solving(self) -> bool:
        return self._tracker is not None and self._tracker.solving

    def poll(self) -> Answer | None:
        """Apply the window solves that are done; an Answer when that changed anything."""
        if not self.solving:
            return None
        t0 = time.perf_counter()
        merged = MergedUpdate(self._track_id)
        error = None
        try:
            merged.add(self._tracker.poll())
        except Exception as exc:  # noqa: BLE001 - reported
            error = f'tracker poll failed: {type(exc).__name__}: {exc}'
        if not (merged.tracks or merged.unassigned or merged.committed or error):
            return None
        return self._answer(merged, [], time.perf_counter() - t0, error)

    def flush(self, now: float) -> Answer:
        t0 = time.perf_counter()
        merged = MergedUpdate(self._track_id)
        error = None
        if self._tracker is not None:
            try:
                merged.add(self._tracker.flush())
            except Exception as exc:  # noqa: BLE001 - reported
                error = f'tracker flush failed: {type(exc).__name__}: {exc}'
            self.counts['flushes'] += 1
        answer = self._answer(merged, [], time.perf_counter() - t0, error, flushed=True)
        answer.flushed = True
        return answer

    def take_handoff(self, offers, upstream_until: float) -> Answer | None:
        """The upstream shard's offers [(track id, detection id)] and commit time [s]; an
        Answer carrying the TrackHandoff of the continuations that decided."""
        if self._shard is None:
            return None
        data = self._shard.take(offers, upstream_until, self.run)
        answer = self._answer(MergedUpdate(self._track_id), [], 0.0, None)
        answer.handoff = data
        return answer

    # --- output ---------------------------------------------------------------------------
    def _track_id(self, n: int) -> int:
        """The published id of the tracker's track ``n``."""
        return self.run + n if self._shard is None else self._shard.role.track_id(self.run, n)

    def _publish_row(self, key: int, track_id: int) -> tuple | None:
        """The row of detection ``key`` as published in track ``track_id`` (-1: unassigned),
        counting a changed link as revised; None when its row is gone."""
        row = self._rows.get(key)
        if row is None:
            return None
        old = self._published.get(key)
        if old is not None and old != track_id:
            self.counts['links_revised'] += 1
        self._published[key] = track_id
        return tuple(row)

    def _answer(
        self, merged: MergedUpdate, received, solve_time: float, error, flushed: bool = False
    ) -> Answer:
        tracks = []
        missing = 0
        shard = self._shard
        for track_id, (status, keys) in merged.tracks.items():
            held = []
            for k in keys.tolist():
                row = self._publish_row(k, track_id)
                if row is None:
                    missing += 1
                else:
                    held.append(row)
            if shard is not None:
                held = shard.own_rows(track_id, status, held)
                if held is None:
                    continue
            tracks.append((track_id, status, held))
            self._count_status(track_id, status)
            self._next_id = max(self._next_id, track_id + 1)
        unassigned = []
        for k in merged.unassigned:
            if k in merged.in_tracks:
                continue
            row = self._publish_row(k, -1)
            if row is None:
                missing += 1
            elif shard is None or shard.is_own(row):
                unassigned.append(row)
        if missing:
            self.counts['missing_rows'] = self.counts.get('missing_rows', 0) + missing
        if merged.committed_until > self.committed_until:
            self.committed_until = merged.committed_until
        if flushed and math.isfinite(self.newest):
            # every detection seen is committed, the newest one included
            self.committed_until = max(self.committed_until, self.newest + 1e-9)
        data = None
        if tracks or unassigned or flushed:
            committed = self.committed_until
            if committed == math.inf:
                committed = self.newest + 1e-9
            data = self._encode(
                method=self._method,
                tracks=tracks,
                unassigned=unassigned,
                committed_until_ns=_to_ns(committed),
                solve_time=solve_time,
                run=self.run,
                by_stamp=self._network,
            )
        handoff = None
        if shard is not None:
            rows = [(t, self._rows[k]) for k, t in merged.committed if k in self._rows]
            if rows or data is not None:
                handoff = shard.commit(rows, self.committed_until, self.newest, self.run)
        self._forget(merged)
        stats = dict(self.counts)
        if shard is not None:
            stats.update(shard.counts)
            stats['handoff_pending'] = shard.desk.pending
        if self._tracker is not None:
            counters = self._tracker.stats
            counters = counters() if callable(counters) else counters
            stats.update({f'tracker.{k}': v for k, v in counters.items()})
        if self._reorder is not None:
            stats['reorder_held'] = len(self._reorder)
            stats['reorder_timeouts'] = self._reorder.released_by_timeout
        return Answer(
            data=data,
            received_at=received,
            tracks=len(tracks),
            unassigned=len(unassigned),
            solve_time=solve_time,
            committed_until=self.committed_until,
            newest_stamp=self.newest,
            working_set=0 if self._tracker is None else int(self._tracker.working_set),
            held=len(self._rows),
            stats=stats,
            error=error,
            handoff=handoff,
        )

    def _count_status(self, track_id: int, status: int) -> None:
        if status == CONFIRMED and track_id not in self._confirmed_ids:
            self._confirmed_ids.add(track_id)
            self.counts['tracks_confirmed'] += 1
        elif status == FINAL:
            if track_id not in self._confirmed_ids:
                self.counts['tracks_confirmed'] += 1
            self._confirmed_ids.discard(track_id)
            self.counts['tracks_final'] += 1

    def _forget(self, merged: MergedUpdate) -> None:
        """Drop the data of detections that can never be published again."""
        for track_id, (status, keys) in merged.tracks.items():
            if status == FINAL:
                self._final[track_id] = 0
                for k in keys.tolist():
                    if k in self._committed:
                        self._drop(k)
                    else:
                        self._final[track_id] += 1
                if not self._final[track_id]:
                    del self._final[track_id]
        for k, track_id in merged.committed:
            if k not in self._rows:
                continue
            if track_id < 0 or track_id in self._final:
                self._drop(k)
                if track_id in self._final:
                    self._final[track_id] -= 1
                    if self._final[track_id] <= 0:
                        del self._final[track_id]
            else:
                self._committed[k] = track_id

    def _drop(self, key: int) -> None:
        self._rows.pop(key, None)
        self._committed.pop(key, None)
        self._published.pop(key, None)


def _to_ns(seconds: float) -> int:
    return int(round(seconds * NS_PER_S)) if math.isfinite(seconds) else 0


def encode_tracks(**kwargs) -> bytes:
    """A stream TrackArray, serialized (runs in the tracker process)."""
    from rclpy.serialization import serialize_message

    from mlkm_ros.conversions import stream_tracks_to_msg

    msg = stream_tracks_to_msg(stamp_ns=time.time_ns(), **kwargs)
    return serialize_message(msg)
