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
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from mlkm_core.types import Layout
from mlkm_ros.stamps import (
    FRAME_ID,
    NS_PER_S,
    header,
    ns_to_seconds,
    ns_to_time,
    seconds_to_ns,
    seconds_to_ns_array,
    time_to_ns,
)
from mlkm_ros.track_conversions import (
    LANE_UNKNOWN,
    StreamRow,
    StreamTracks,
    stream_tracks_from_msg,
    stream_tracks_to_msg,
    track_lanes_from_msg,
    tracks_from_msg,
    tracks_to_msg,
)
from road_sensor_msgs.msg import (
    AssociationScore,
    Detection,
    EpisodeInfo,
    GroundTruth,
    SensorLayout,
)

#: Time helpers and TrackArray conversions live in mlkm_ros.stamps and
#: mlkm_ros.track_conversions; every name stays importable from here.
__all__ = [
    'FALSE_ALARM_ID',
    'FRAME_ID',
    'LANE_UNKNOWN',
    'NS_PER_S',
    'EpisodeFields',
    'StreamRow',
    'StreamTracks',
    'detection_length',
    'detection_to_msg',
    'diagnostics_to_msg',
    'diagnostics_values',
    'episode_counts',
    'episode_ended_msg',
    'episode_from_msg',
    'episode_started_msg',
    'ground_truth_target',
    'ground_truth_to_msg',
    'header',
    'lane_counts_from_msg',
    'layout_from_msg',
    'layout_ramps',
    'layout_to_msg',
    'ns_to_seconds',
    'ns_to_time',
    'score_to_msg',
    'seconds_to_ns',
    'seconds_to_ns_array',
    'stream_tracks_from_msg',
    'stream_tracks_to_msg',
    'time_to_ns',
    'track_lanes_from_msg',
    'tracks_from_msg',
    'tracks_to_msg',
]

#: GroundTruth.target_id of a false alarm.
FALSE_ALARM_ID = GroundTruth.FALSE_ALARM


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
    positive road length, at least one sensor, finite strictly increasing positions on the
    road [0, road_length], unique ids and unique non-empty names; lane_counts empty or one count
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


def layout_ramps(msg: SensorLayout) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(entry positions, exit positions) [m] of a layout: its on- and off-ramps."""
    return tuple(float(x) for x in msg.entry_positions), tuple(
        float(x) for x in msg.exit_positions
    )


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
