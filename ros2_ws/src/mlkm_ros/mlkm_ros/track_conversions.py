"""TrackArray <-> arrays, in both modes (re-exported by :mod:`mlkm_ros.conversions`).

Episodes mode (``TrackArray.MODE_EPISODES``): the association of one episode, every track
FINAL in a final array, CONFIRMED in a partial one. Stream mode (``TrackArray.MODE_STREAM``,
an open road): the tracks that changed, each with every detection it holds, the detections
that became unassigned and the commit horizon.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mlkm_ros.stamps import NS_PER_S, header, ns_to_time, time_to_ns
from road_sensor_msgs.msg import Detection, Track, TrackArray

#: Detection.lane of a sensor that does not report lanes.
LANE_UNKNOWN = Detection.LANE_UNKNOWN

# --- episodes mode ------------------------------------------------------------------------


def tracks_to_msg(
    *,
    episode_id: int,
    method: str,
    final: bool,
    segments_done: int,
    segments_total: int,
    sensor_ids: np.ndarray,
    stamps_ns: np.ndarray,
    velocities: np.ndarray,
    positions: np.ndarray,
    labels: np.ndarray,
    solve_time: float,
    stamp_ns: int,
    lanes: np.ndarray | None = None,
    lengths: np.ndarray | None = None,
    retired: Sequence[int] = (),
    by_stamp: bool = False,
) -> TrackArray:
    """Group detections by label into Tracks (each ordered by position, then stamp, then
    lane; ``by_stamp``: by stamp, then position, as on a road network, whose positions lie
    on different links) of an episodes-mode TrackArray: every track STATUS_FINAL in a final
    array, STATUS_CONFIRMED in a partial one.

    ``labels[i]`` is the track id of detection i, or -1 (unassigned); ``lanes`` (-1 unknown)
    and ``lengths`` [m] (NaN unknown) default to unknown. Each id of ``retired`` (a track an
    earlier message of the episode carried, whose detections all went to other tracks) is
    added as an empty track with STATUS_FINAL.
    """
    labels = np.asarray(labels, dtype=np.int64)
    sensor_ids = np.asarray(sensor_ids, dtype=np.int64)
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    velocities = np.asarray(velocities, dtype=float)
    positions = np.asarray(positions, dtype=float)
    n = labels.size
    lanes = np.full(n, LANE_UNKNOWN, np.int64) if lanes is None else np.asarray(lanes, np.int64)
    lengths = np.full(n, math.nan) if lengths is None else np.asarray(lengths, dtype=float)
    if lanes.shape != (n,) or lengths.shape != (n,):
        raise ValueError('lanes and lengths need one entry per detection')
    status = Track.STATUS_FINAL if final else Track.STATUS_CONFIRMED
    first, second = (stamps_ns, positions) if by_stamp else (positions, stamps_ns)
    order = np.lexsort((lanes, second, first, labels))
    sorted_labels = labels[order]
    cuts = np.flatnonzero(np.diff(sorted_labels)) + 1
    msg = TrackArray(
        header=header(stamp_ns),
        mode=TrackArray.MODE_EPISODES,
        episode_id=int(episode_id),
        method=method,
        final=bool(final),
        segments_done=int(segments_done),
        segments_total=int(segments_total),
        solve_time=float(solve_time),
    )
    tracks = []
    for group in np.split(order, cuts):
        if group.size == 0:
            continue
        label = int(labels[group[0]])
        ids = sensor_ids[group].tolist()
        times = [ns_to_time(t) for t in stamps_ns[group].tolist()]
        if label < 0:
            msg.unassigned_sensor_ids = ids
            msg.unassigned_stamps = times
            msg.unassigned_velocities = velocities[group].tolist()
            msg.unassigned_lanes = lanes[group].tolist()
            msg.unassigned_lengths = lengths[group].tolist()
            continue
        tracks.append(
            Track(
                track_id=label,
                status=status,
                sensor_ids=ids,
                stamps=times,
                velocities=velocities[group].tolist(),
                positions=positions[group].tolist(),
                lanes=lanes[group].tolist(),
                lengths=lengths[group].tolist(),
            )
        )
    tracks.extend(Track(track_id=int(i), status=Track.STATUS_FINAL) for i in retired)
    msg.tracks = tracks
    return msg


def tracks_from_msg(msg: TrackArray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(sensor_ids, stamps_ns, velocities, labels) of every detection in the message;
    unassigned detections get label -1. :func:`track_lanes_from_msg` gives their lanes and
    lengths in the same order."""
    ids: list[int] = []
    stamps: list[int] = []
    vels: list[float] = []
    labels: list[int] = []
    for track in msg.tracks:
        ids.extend(track.sensor_ids)
        stamps.extend(time_to_ns(t) for t in track.stamps)
        vels.extend(track.velocities)
        labels.extend([int(track.track_id)] * len(track.sensor_ids))
    ids.extend(msg.unassigned_sensor_ids)
    stamps.extend(time_to_ns(t) for t in msg.unassigned_stamps)
    vels.extend(msg.unassigned_velocities)
    labels.extend([-1] * len(msg.unassigned_sensor_ids))
    return (
        np.asarray(ids, dtype=np.int64),
        np.asarray(stamps, dtype=np.int64),
        np.asarray(vels, dtype=float),
        np.asarray(labels, dtype=np.int64),
    )


def track_lanes_from_msg(msg: TrackArray) -> tuple[np.ndarray, np.ndarray]:
    """(lanes, lengths) of every detection in the order of :func:`tracks_from_msg`; a
    message without them (empty arrays) reads as lane -1 and length NaN. ValueError when a
    non-empty array is not parallel to its sensor ids."""
    lanes: list[int] = []
    lengths: list[float] = []

    def add(n: int, ln: Sequence[int], size: Sequence[float], what: str) -> None:
        if len(ln) not in (0, n) or len(size) not in (0, n):
            raise ValueError(f'{what}: lanes/lengths differ in length from sensor_ids')
        lanes.extend(ln if len(ln) else [LANE_UNKNOWN] * n)
        lengths.extend(size if len(size) else [math.nan] * n)

    for track in msg.tracks:
        add(len(track.sensor_ids), track.lanes, track.lengths, f'track {track.track_id}')
    add(len(msg.unassigned_sensor_ids), msg.unassigned_lanes, msg.unassigned_lengths, 'unassigned')
    lengths_arr = np.asarray(lengths, dtype=float)
    lengths_arr[lengths_arr == 0.0] = math.nan
    return np.asarray(lanes, dtype=np.int64), lengths_arr


# --- stream mode (an open road: TrackArray.MODE_STREAM) -------------------------------------

#: One detection of a stream TrackArray: (sensor id, stamp [ns], velocity [m/s], position [m],
#: lane (-1 unknown), length [m] (NaN unknown)).
StreamRow = tuple[int, int, float, float, int, float]


def stream_tracks_to_msg(
    *,
    method: str,
    tracks: Sequence[tuple[int, int, Sequence[StreamRow]]],
    unassigned: Sequence[StreamRow],
    committed_until_ns: int,
    solve_time: float,
    stamp_ns: int,
    run: int = 0,
    by_stamp: bool = False,
) -> TrackArray:
    """A stream-mode TrackArray: ``tracks`` are (track id, status, rows) of the tracks that
    changed, each with every detection it holds (ordered here by position, then stamp;
    ``by_stamp``: by stamp, then position, as on a road network);
    ``unassigned`` the detections that became unassigned; ``run`` the tracker run that
    numbered the tracks (TrackArray.run); episode_id 0, final false."""
    msg = TrackArray(
        header=header(stamp_ns),
        mode=TrackArray.MODE_STREAM,
        episode_id=0,
        method=method,
        final=False,
        solve_time=float(solve_time),
        committed_until=ns_to_time(max(int(committed_until_ns), 0)),
        run=int(run),
    )
    # numeric sequences as array.array: the message's setters then copy them whole instead
    # of checking every element (this runs for every TrackArray of stream mode)
    out = []
    for track_id, status, rows in tracks:
        rows = sorted(rows, key=(lambda r: (r[1], r[3], r[4])) if by_stamp else
                      (lambda r: (r[3], r[1], r[4])))  # fmt: skip
        out.append(
            Track(
                track_id=int(track_id),
                status=int(status),
                sensor_ids=array('I', [r[0] for r in rows]),
                stamps=[ns_to_time(r[1]) for r in rows],
                velocities=array('d', [r[2] for r in rows]),
                positions=array('d', [r[3] for r in rows]),
                lanes=array('h', [r[4] for r in rows]),
                lengths=array('d', [r[5] for r in rows]),
            )
        )
    msg.tracks = out
    msg.unassigned_sensor_ids = array('I', [r[0] for r in unassigned])
    msg.unassigned_stamps = [ns_to_time(r[1]) for r in unassigned]
    msg.unassigned_velocities = array('d', [r[2] for r in unassigned])
    msg.unassigned_lanes = array('h', [r[4] for r in unassigned])
    msg.unassigned_lengths = array('d', [r[5] for r in unassigned])
    return msg


@dataclass(frozen=True)
class StreamTracks:
    """The detections of a stream TrackArray as parallel arrays (unassigned ones last)."""

    sensor_ids: np.ndarray  # int64
    stamps_ns: np.ndarray  # int64
    lanes: np.ndarray  # int64, -1 unknown
    labels: np.ndarray  # int64 track id, -1 unassigned
    status: np.ndarray  # int64 Track.STATUS_* of the detection's track, -1 unassigned
    committed_until_ns: int
    run: int = 0  # TrackArray.run: the tracker run that numbered the tracks


def stream_tracks_from_msg(msg: TrackArray) -> StreamTracks:
    """Decode a stream TrackArray; ValueError when its parallel arrays disagree."""
    ids: list[int] = []
    stamps: list[int] = []
    lanes: list[int] = []
    labels: list[int] = []
    status: list[int] = []

    def add(n, sensor_ids, times, lane_values, velocities, label, state, what) -> None:
        if len(times) != n or len(velocities) != n or len(lane_values) not in (0, n):
            raise ValueError(f'{what}: parallel arrays differ in length')
        ids.extend(int(s) for s in sensor_ids)
        for t in times:
            if t.sec < 0 or t.nanosec >= NS_PER_S:
                raise ValueError(f'{what}: invalid time {t.sec} s {t.nanosec} ns')
            stamps.append(time_to_ns(t))
        if len(lane_values):
            lanes.extend(int(v) for v in lane_values)
        else:
            lanes.extend([-1] * n)
        labels.extend([label] * n)
        status.extend([state] * n)

    for t in msg.tracks:
        if len(t.positions) != len(t.sensor_ids):
            raise ValueError(f'track {t.track_id}: parallel arrays differ in length')
        add(
            len(t.sensor_ids),
            t.sensor_ids,
            t.stamps,
            t.lanes,
            t.velocities,
            int(t.track_id),
            int(t.status),
            f'track {t.track_id}',
        )
    add(
        len(msg.unassigned_sensor_ids),
        msg.unassigned_sensor_ids,
        msg.unassigned_stamps,
        msg.unassigned_lanes,
        msg.unassigned_velocities,
        -1,
        -1,
        'unassigned',
    )
    return StreamTracks(
        np.asarray(ids, np.int64),
        np.asarray(stamps, np.int64),
        np.asarray(lanes, np.int64),
        np.asarray(labels, np.int64),
        np.asarray(status, np.int64),
        time_to_ns(msg.committed_until),
        int(msg.run),
    )
