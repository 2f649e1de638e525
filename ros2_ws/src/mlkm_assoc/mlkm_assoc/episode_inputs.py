"""The scorer's episodes mode, its plain parts: the settings, an open and a scored episode,
and the checks of a message's times and arrays (:mod:`mlkm_assoc.episode_scoring` keeps the
episodes; the scorer node checks its GroundTruth stamps with :func:`valid_stamp_ns` too).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mlkm_ros import conversions as conv
from road_sensor_msgs.msg import TrackArray

NS_PER_S = conv.NS_PER_S
Key = tuple[int, int, int]  # (sensor id, stamp ns, lane): the join key
Window = tuple[int, int, int]  # (num_targets, start ns, end ns) of an EpisodeInfo


@dataclass(frozen=True)
class ScorerConfig:
    """The scorer's episodes-mode settings (node parameters of the same names)."""

    truth_timeout: float = 10.0  # [s]
    forget_after: float = 300.0  # [s]
    max_open_episodes: int = 100  # [episodes]
    max_scored_episodes: int = 1000  # [episodes]
    max_buffered_truth: int = 1_000_000  # [messages]


@dataclass
class OpenEpisode:
    """One unscored episode of the current run."""

    last_rx: float  # monotonic time of its last input (info, truth, tracks) [s]
    window: Window | None = None
    started_ns: int | None = None  # publication stamp of its STARTED
    counts: dict[int, int] | None = None  # ENDED: {sensor id: detections published}
    truth: dict[Key, tuple[int, float]] = field(default_factory=dict)  # -> (target, true v)
    final: TrackArray | None = None

    def inside(self, stamp_ns: int) -> bool:
        return self.window is None or self.window[1] <= stamp_ns <= self.window[2]


@dataclass(frozen=True)
class ScoredEpisode:
    """What is remembered of a scored episode: its window and STARTED stamp."""

    window: Window | None
    started_ns: int | None


def valid_stamp_ns(stamp) -> int:
    """A message time in integer ns; ValueError when it is negative or malformed."""
    if stamp.sec < 0 or stamp.nanosec >= NS_PER_S:
        raise ValueError(f'invalid time {stamp.sec} s {stamp.nanosec} ns')
    return conv.time_to_ns(stamp)


def check_tracks(msg: TrackArray) -> list[int]:
    """Stamps [ns] of every detection in the tracks; ValueError when arrays disagree."""
    stamps = []
    for track in msg.tracks:
        n = len(track.sensor_ids)
        if not (len(track.stamps) == len(track.velocities) == len(track.positions) == n):
            raise ValueError(f'track {track.track_id}: parallel arrays differ in length')
        stamps.extend(valid_stamp_ns(t) for t in track.stamps)
    n = len(msg.unassigned_sensor_ids)
    if not (len(msg.unassigned_stamps) == len(msg.unassigned_velocities) == n):
        raise ValueError('unassigned_* arrays differ in length')
    stamps.extend(valid_stamp_ns(t) for t in msg.unassigned_stamps)
    conv.track_lanes_from_msg(msg)  # lanes/lengths empty or parallel to sensor_ids
    return stamps
