"""Messages <-> arrays: the one place where ROS messages meet the ROS-free core.

Times travel as ``builtin_interfaces/Time`` and are handled here as integer nanoseconds
(the join key of detections, tracks and ground truth is (sensor id, stamp in ns)); the core
gets seconds as float64 via :func:`ns_to_seconds`. Every node, script and test converts
through these functions, so a detection's stamp means the same everywhere.
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


def layout_to_msg(layout: Layout, stamp_ns: int) -> SensorLayout:
    msg = SensorLayout(header=header(stamp_ns), road_length=float(layout.road_length))
    msg.sensor_ids = [int(s) for s in layout.sensor_ids]
    msg.sensor_names = list(layout.names)
    msg.positions = [float(p) for p in layout.positions]
    return msg


def layout_from_msg(msg: SensorLayout) -> Layout:
    """Raises ValueError with the reason when the message is not a valid layout: a finite
    positive road length, at least one sensor, finite strictly increasing positions inside
    (0, road_length), unique ids and unique non-empty names."""
    n = len(msg.positions)
    if len(msg.sensor_ids) != n or len(msg.sensor_names) != n:
        raise ValueError('sensor_ids, sensor_names and positions differ in length')
    road_length = float(msg.road_length)
    if not (math.isfinite(road_length) and road_length > 0):
        raise ValueError(f'road_length must be finite and > 0, got {road_length!r}')
    if any(not name for name in msg.sensor_names):
        raise ValueError('sensor names must not be empty')
    return Layout(
        road_length=road_length,
        positions=np.asarray(msg.positions, dtype=float),
        sensor_ids=np.asarray(msg.sensor_ids, dtype=np.int64),
        names=tuple(msg.sensor_names),
    )


# --- detections, ground truth, episodes ---------------------------------------------------


def detection_to_msg(sensor_id: int, stamp_ns: int, position: float, velocity: float) -> Detection:
    return Detection(
        header=header(stamp_ns),
        sensor_id=int(sensor_id),
        position=float(position),
        velocity=float(velocity),
    )


def ground_truth_to_msg(
    episode_id: int, sensor_id: int, stamp_ns: int, target: int, true_velocity: float
) -> GroundTruth:
    false_alarm = target < 0
    return GroundTruth(
        header=header(stamp_ns),
        episode_id=int(episode_id),
        sensor_id=int(sensor_id),
        target_id=FALSE_ALARM_ID if false_alarm else int(target),
        false_alarm=bool(false_alarm),
        true_velocity=float(true_velocity),
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
) -> TrackArray:
    """Group detections by label into Tracks (each ordered by position, then stamp).

    ``labels[i]`` is the track id of detection i, or -1 (unassigned).
    """
    labels = np.asarray(labels, dtype=np.int64)
    sensor_ids = np.asarray(sensor_ids, dtype=np.int64)
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    velocities = np.asarray(velocities, dtype=float)
    positions = np.asarray(positions, dtype=float)
    order = np.lexsort((stamps_ns, positions, labels))
    sorted_labels = labels[order]
    cuts = np.flatnonzero(np.diff(sorted_labels)) + 1
    msg = TrackArray(
        header=header(stamp_ns),
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
            continue
        tracks.append(
            Track(
                track_id=label,
                sensor_ids=ids,
                stamps=times,
                velocities=velocities[group].tolist(),
                positions=positions[group].tolist(),
            )
        )
    msg.tracks = tracks
    return msg


def tracks_from_msg(msg: TrackArray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(sensor_ids, stamps_ns, velocities, labels) of every detection in the message;
    unassigned detections get label -1."""
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
