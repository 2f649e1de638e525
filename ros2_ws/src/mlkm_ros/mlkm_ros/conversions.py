"""Messages <-> arrays: the one place where ROS messages meet the ROS-free core.

Times travel as ``builtin_interfaces/Time`` and are handled here as integer nanoseconds
(the join key of detections, tracks and ground truth is (sensor id, lane, stamp in ns), lane
-1 where unknown); the core gets seconds as float64 via :func:`ns_to_seconds`. A vehicle
length travels as float64 metres, NaN (or the unset 0) where it was not measured. Every
node, script and test converts through these functions, so a detection's stamp means the
same everywhere.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from mlkm_core.types import Layout
from road_sensor_msgs.msg import (
    AssociationScore,
    Detection,
    EpisodeInfo,
    GroundTruth,
    SensorLayout,
    Track,
    TrackArray,
)

NS_PER_S = 1_000_000_000
FRAME_ID = 'road'
#: GroundTruth.target_id of a false alarm.
FALSE_ALARM_ID = GroundTruth.FALSE_ALARM
#: Detection.lane of a sensor that does not report lanes.
LANE_UNKNOWN = Detection.LANE_UNKNOWN


# --- time ---------------------------------------------------------------------------------


def seconds_to_ns(seconds: float) -> int:
    """A time in seconds (float) -> integer nanoseconds, rounded to the nearest ns."""
    return int(round(float(seconds) * NS_PER_S))


def seconds_to_ns_array(seconds: np.ndarray) -> np.ndarray:
    return np.rint(np.asarray(seconds, dtype=float) * NS_PER_S).astype(np.int64)


def ns_to_seconds(ns: np.ndarray | Sequence[int]) -> np.ndarray:
    """Integer nanoseconds -> seconds as float64 (what the core works with)."""
    return np.asarray(ns, dtype=np.int64) / NS_PER_S


def ns_to_time(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def time_to_ns(stamp: Time) -> int:
    return stamp.sec * NS_PER_S + stamp.nanosec


def header(stamp_ns: int) -> Header:
    return Header(stamp=ns_to_time(stamp_ns), frame_id=FRAME_ID)


# --- layout -------------------------------------------------------------------------------


def layout_to_msg(
    layout: Layout,
    stamp_ns: int,
    lane_counts: Sequence[int] | np.ndarray | None = None,
    entry_positions: Sequence[float] | np.ndarray = (),
    exit_positions: Sequence[float] | np.ndarray = (),
) -> SensorLayout:
    """``lane_counts``: lanes watched by each sensor (None: unknown); ``entry_positions`` /
    ``exit_positions``: on- and off-ramps between the sensors [m]."""
    msg = SensorLayout(header=header(stamp_ns), road_length=float(layout.road_length))
    msg.sensor_ids = [int(s) for s in layout.sensor_ids]
    msg.sensor_names = list(layout.names)
    msg.positions = [float(p) for p in layout.positions]
    msg.lane_counts = [] if lane_counts is None else [int(n) for n in lane_counts]
    msg.entry_positions = [float(x) for x in entry_positions]
    msg.exit_positions = [float(x) for x in exit_positions]
    return msg


def layout_from_msg(msg: SensorLayout) -> Layout:
    """Raises ValueError with the reason when the message is not a valid layout: a finite
    positive road length, at least one sensor, finite strictly increasing positions inside
    (0, road_length), unique ids and unique non-empty names; lane_counts empty or one count
    >= 1 per sensor; entry and exit positions finite and inside (0, road_length)."""
    n = len(msg.positions)
    if len(msg.sensor_ids) != n or len(msg.sensor_names) != n:
        raise ValueError('sensor_ids, sensor_names and positions differ in length')
    road_length = float(msg.road_length)
    if not (math.isfinite(road_length) and road_length > 0):
        raise ValueError(f'road_length must be finite and > 0, got {road_length!r}')
    if any(not name for name in msg.sensor_names):
        raise ValueError('sensor names must not be empty')
    lane_counts_from_msg(msg)
    for field in ('entry_positions', 'exit_positions'):
        for x in getattr(msg, field):
            if not (math.isfinite(x) and 0 < x < road_length):
                raise ValueError(f'{field}: {x!r} m is not inside the road (0, {road_length:g}) m')
    return Layout(
        road_length=road_length,
        positions=np.asarray(msg.positions, dtype=float),
        sensor_ids=np.asarray(msg.sensor_ids, dtype=np.int64),
        names=tuple(msg.sensor_names),
    )


def lane_counts_from_msg(msg: SensorLayout) -> tuple[int, ...] | None:
    """Lanes per sensor, parallel to sensor_ids, or None when the layout does not say;
    ValueError when the array is neither empty nor one count >= 1 per sensor."""
    counts = [int(c) for c in msg.lane_counts]
    if not counts:
        return None
    if len(counts) != len(msg.sensor_ids):
        raise ValueError(
            f'lane_counts has {len(counts)} entries for {len(msg.sensor_ids)} sensors '
            '(give none or one per sensor)'
        )
    if min(counts) < 1:
        raise ValueError(f'lane_counts must be >= 1, got {min(counts)}')
    return tuple(counts)


# --- detections, ground truth, episodes ---------------------------------------------------


def detection_to_msg(
    sensor_id: int,
    stamp_ns: int,
    position: float,
    velocity: float,
    lane: int = LANE_UNKNOWN,
    length: float = math.nan,
) -> Detection:
    """``lane``: index from the right, -1 unknown; ``length``: vehicle length [m], NaN
    unknown."""
    return Detection(
        header=header(stamp_ns),
        sensor_id=int(sensor_id),
        position=float(position),
        velocity=float(velocity),
        lane=int(lane),
        length=float(length),
    )


def detection_length(msg: Detection) -> float:
    """The measured vehicle length [m] of a detection; NaN when unknown (NaN or the unset
    0 in the message)."""
    return math.nan if msg.length == 0.0 else float(msg.length)


def ground_truth_to_msg(
    episode_id: int,
    sensor_id: int,
    stamp_ns: int,
    target: int,
    true_velocity: float,
    lane: int = LANE_UNKNOWN,
    vehicle_id: str = '',
) -> GroundTruth:
    """``target`` < 0 marks a false alarm; ``vehicle_id`` is the source's own name of the
    target (a SUMO vehicle id), empty when none."""
    false_alarm = target < 0
    return GroundTruth(
        header=header(stamp_ns),
        episode_id=int(episode_id),
        sensor_id=int(sensor_id),
        target_id=FALSE_ALARM_ID if false_alarm else int(target),
        false_alarm=bool(false_alarm),
        true_velocity=float(true_velocity),
        lane=int(lane),
        vehicle_id=str(vehicle_id),
    )


def ground_truth_target(msg: GroundTruth) -> int:
    """The core's target id of a ground-truth message: FALSE_ALARM (-1) for clutter."""
    return -1 if (msg.false_alarm or msg.target_id == FALSE_ALARM_ID) else int(msg.target_id)


def episode_started_msg(
    episode_id: int, num_targets: int, start_ns: int, end_ns: int, stamp_ns: int
) -> EpisodeInfo:
    return EpisodeInfo(
        header=header(stamp_ns),
        episode_id=int(episode_id),
        status=EpisodeInfo.STATUS_STARTED,
        num_targets=int(num_targets),
        start=ns_to_time(start_ns),
        end=ns_to_time(end_ns),
    )


def episode_ended_msg(
    episode_id: int,
    num_targets: int,
    start_ns: int,
    end_ns: int,
    stamp_ns: int,
    counts: Mapping[int, int],
) -> EpisodeInfo:
    msg = episode_started_msg(episode_id, num_targets, start_ns, end_ns, stamp_ns)
    msg.status = EpisodeInfo.STATUS_ENDED
    msg.sensor_ids = [int(s) for s in counts]
    msg.detection_counts = [int(c) for c in counts.values()]
    return msg


def episode_counts(msg: EpisodeInfo) -> dict[int, int]:
    """The ENDED message's per-sensor detection counts as {sensor id: count}."""
    if len(msg.sensor_ids) != len(msg.detection_counts):
        raise ValueError('sensor_ids and detection_counts differ in length')
    if len(set(msg.sensor_ids)) != len(msg.sensor_ids):
        raise ValueError('sensor_ids repeat a sensor')
    return {int(s): int(c) for s, c in zip(msg.sensor_ids, msg.detection_counts)}


@dataclass(frozen=True)
class EpisodeFields:
    """A validated EpisodeInfo as plain values."""

    episode_id: int
    num_targets: int
    start_ns: int
    end_ns: int
    counts: dict[int, int] | None  # ENDED: {sensor id: detections published}; STARTED: None
    published_ns: int  # header.stamp: when the message was published


def episode_from_msg(msg: EpisodeInfo) -> EpisodeFields:
    """Raises ValueError with the reason when the message is not a valid EpisodeInfo: a known
    status, at least one target, valid times (nanosec below 1 s, never negative) with
    start <= end, and for ENDED one count per distinct sensor."""
    if msg.status not in (EpisodeInfo.STATUS_STARTED, EpisodeInfo.STATUS_ENDED):
        raise ValueError(f'unknown status {msg.status}')
    if msg.num_targets < 1:
        raise ValueError(f'num_targets must be >= 1, got {msg.num_targets}')
    for field, stamp in (('start', msg.start), ('end', msg.end)):
        if stamp.sec < 0 or stamp.nanosec >= NS_PER_S:
            raise ValueError(f'{field} is not a valid time: {stamp.sec} s {stamp.nanosec} ns')
    start_ns, end_ns = time_to_ns(msg.start), time_to_ns(msg.end)
    if start_ns > end_ns:
        raise ValueError(f'window ends before it starts: [{start_ns}, {end_ns}] ns')
    counts = episode_counts(msg) if msg.status == EpisodeInfo.STATUS_ENDED else None
    return EpisodeFields(
        episode_id=int(msg.episode_id),
        num_targets=int(msg.num_targets),
        start_ns=start_ns,
        end_ns=end_ns,
        counts=counts,
        published_ns=time_to_ns(msg.header.stamp),
    )


# --- tracks -------------------------------------------------------------------------------


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
) -> TrackArray:
    """Group detections by label into Tracks (each ordered by position, then stamp, then
    lane) of an episodes-mode TrackArray: every track STATUS_FINAL in a final array,
    STATUS_CONFIRMED in a partial one.

    ``labels[i]`` is the track id of detection i, or -1 (unassigned); ``lanes`` (-1 unknown)
    and ``lengths`` [m] (NaN unknown) default to unknown.
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
    order = np.lexsort((lanes, stamps_ns, positions, labels))
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


# --- score, diagnostics -------------------------------------------------------------------


def score_to_msg(
    *,
    episode_id: int,
    method: str,
    score,
    mean_accuracy: float,
    episodes_scored: int,
    stamp_ns: int,
) -> AssociationScore:
    """``score`` is a ``mlkm_core.metrics.Score``."""
    return AssociationScore(
        header=header(stamp_ns),
        episode_id=int(episode_id),
        method=method,
        accuracy=float(score.accuracy),
        correct=int(score.correct),
        total=int(score.total),
        link_recall=float(score.link_recall),
        link_precision=float(score.link_precision),
        identity_switches=int(score.identity_switches),
        adjusted_rand_index=float(score.adjusted_rand_index),
        mean_accuracy=float(mean_accuracy),
        episodes_scored=int(episodes_scored),
    )


def diagnostics_to_msg(
    *,
    name: str,
    hardware_id: str,
    level: int,
    message: str,
    values: Mapping[str, object],
    stamp_ns: int,
) -> DiagnosticArray:
    status = DiagnosticStatus(
        level=bytes([level]),
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
    )
    return DiagnosticArray(header=header(stamp_ns), status=[status])


def diagnostics_values(msg: DiagnosticArray, name: str) -> dict[str, str] | None:
    """The key-values of the status called ``name`` in a DiagnosticArray, if present."""
    for status in msg.status:
        if status.name == name:
            return {kv.key: kv.value for kv in status.values}
    return None


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
) -> TrackArray:
    """A stream-mode TrackArray: ``tracks`` are (track id, status, rows) of the tracks that
    changed, each with every detection it holds (ordered here by position, then stamp);
    ``unassigned`` the detections that became unassigned; episode_id 0, final false."""
    msg = TrackArray(
        header=header(stamp_ns),
        mode=TrackArray.MODE_STREAM,
        episode_id=0,
        method=method,
        final=False,
        solve_time=float(solve_time),
        committed_until=ns_to_time(max(int(committed_until_ns), 0)),
    )
    out = []
    for track_id, status, rows in tracks:
        rows = sorted(rows, key=lambda r: (r[3], r[1], r[4]))
        out.append(
            Track(
                track_id=int(track_id),
                status=int(status),
                sensor_ids=[int(r[0]) for r in rows],
                stamps=[ns_to_time(r[1]) for r in rows],
                velocities=[float(r[2]) for r in rows],
                positions=[float(r[3]) for r in rows],
                lanes=[int(r[4]) for r in rows],
                lengths=[float(r[5]) for r in rows],
            )
        )
    msg.tracks = out
    msg.unassigned_sensor_ids = [int(r[0]) for r in unassigned]
    msg.unassigned_stamps = [ns_to_time(r[1]) for r in unassigned]
    msg.unassigned_velocities = [float(r[2]) for r in unassigned]
    msg.unassigned_lanes = [int(r[4]) for r in unassigned]
    msg.unassigned_lengths = [float(r[5]) for r in unassigned]
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
    )


def layout_ramps(msg: SensorLayout) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(entry positions, exit positions) [m] of a layout: its on- and off-ramps."""
    return tuple(float(x) for x in msg.entry_positions), tuple(
        float(x) for x in msg.exit_positions
    )
