"""TrackHandoff to and from plain values, and a stream TrackArray's rows back (for the merge
of shards). Rows are (sensor id, stamp [ns], speed [m/s], position [m], lane, length [m]),
as stream mode's tracker process keeps them."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from mlkm_ros.stamps import NS_PER_S, header, ns_to_time, time_to_ns
from mlkm_ros.track_conversions import stream_tracks_to_msg
from road_sensor_msgs.msg import TrackArray, TrackHandoff

Row = tuple[int, int, float, float, int, float]


@dataclass(frozen=True)
class Handoff:
    """A decoded TrackHandoff: offers as (track id, rows), continuations as (upstream id,
    id), times in seconds (-inf for a zero time: nothing yet)."""

    shard: int
    shard_count: int
    run: int
    offers: list[tuple[int, list[Row]]]
    continuations: list[tuple[int, int]]
    committed_until: float
    settled_until: float
    newest: float

    def offered_detections(self) -> list[tuple[int, tuple[int, int, int, float]]]:
        """(track id, detection join key (sensor id, lane, stamp ns, speed)) per offer."""
        return [(t, (r[0], r[4], r[1], r[2])) for t, rows in self.offers for r in rows]

    def offered_stamps(self) -> list[tuple[int, float]]:
        """(track id, its newest offered stamp [s]) per offered track."""
        return [(t, max(r[1] for r in rows) / NS_PER_S) for t, rows in self.offers if rows]


def handoff_to_msg(
    *,
    shard: int,
    shard_count: int,
    run: int,
    offers: Sequence[tuple[int, int, Sequence[Row]]],
    continuations: Sequence[tuple[int, int]],
    committed_until_ns: int,
    settled_until_ns: int,
    newest_ns: int,
    stamp_ns: int,
) -> TrackHandoff:
    """A TrackHandoff; ``offers`` are (track id, status, rows) as in a stream TrackArray."""
    tracks = stream_tracks_to_msg(
        method='',
        tracks=offers,
        unassigned=[],
        committed_until_ns=0,
        solve_time=0.0,
        stamp_ns=stamp_ns,
    ).tracks
    return TrackHandoff(
        header=header(stamp_ns),
        shard=int(shard),
        shard_count=int(shard_count),
        run=int(run),
        offers=tracks,
        continued_ids=[int(a) for a, _ in continuations],
        continuing_ids=[int(b) for _, b in continuations],
        committed_until=ns_to_time(max(int(committed_until_ns), 0)),
        settled_until=ns_to_time(max(int(settled_until_ns), 0)),
        newest=ns_to_time(max(int(newest_ns), 0)),
    )


def handoff_from_msg(msg: TrackHandoff) -> Handoff:
    """Decode; ValueError when parallel arrays disagree."""
    if len(msg.continued_ids) != len(msg.continuing_ids):
        raise ValueError('continued_ids and continuing_ids differ in length')
    offers = [(int(t.track_id), _rows(t)) for t in msg.offers]
    return Handoff(
        int(msg.shard),
        int(msg.shard_count),
        int(msg.run),
        offers,
        [(int(a), int(b)) for a, b in zip(msg.continued_ids, msg.continuing_ids, strict=True)],
        _seconds(msg.committed_until),
        _seconds(msg.settled_until),
        _seconds(msg.newest),
    )


def _seconds(t) -> float:
    """A hand-off time in seconds; -inf for zero (the shard has nothing there yet)."""
    ns = time_to_ns(t)
    return ns / NS_PER_S if ns > 0 else -math.inf


def stream_rows_from_msg(
    msg: TrackArray,
) -> tuple[list[tuple[int, int, list[Row]]], list[Row]]:
    """The (track id, status, rows) of a stream TrackArray and its unassigned rows (whose
    position the message does not carry: NaN)."""
    tracks = [(int(t.track_id), int(t.status), _rows(t)) for t in msg.tracks]
    n = len(msg.unassigned_sensor_ids)
    if len(msg.unassigned_stamps) != n or len(msg.unassigned_velocities) != n:
        raise ValueError('unassigned: parallel arrays differ in length')
    lanes = list(msg.unassigned_lanes) or [-1] * n
    lengths = list(msg.unassigned_lengths) or [math.nan] * n
    unassigned = [
        (int(s), time_to_ns(t), float(v), math.nan, int(lane), float(length))
        for s, t, v, lane, length in zip(
            msg.unassigned_sensor_ids,
            msg.unassigned_stamps,
            msg.unassigned_velocities,
            lanes,
            lengths,
            strict=True,
        )
    ]
    return tracks, unassigned


def _rows(t) -> list[Row]:
    n = len(t.sensor_ids)
    if len(t.stamps) != n or len(t.velocities) != n or len(t.positions) != n:
        raise ValueError(f'track {t.track_id}: parallel arrays differ in length')
    lanes = list(t.lanes) or [-1] * n
    lengths = list(t.lengths) or [math.nan] * n
    return [
        (int(s), time_to_ns(ts), float(v), float(p), int(lane), float(length))
        for s, ts, v, p, lane, length in zip(
            t.sensor_ids, t.stamps, t.velocities, t.positions, lanes, lengths, strict=True
        )
    ]
