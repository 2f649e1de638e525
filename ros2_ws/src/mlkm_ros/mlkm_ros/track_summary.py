"""What /mlkm/markers needs of a serialized TrackArray, read without building the message.

Deserializing a TrackArray into Python objects costs one object per detection stamp; the
markers need only, per track, its id, status and latest passage (last station, stamp,
speed), and the array's mode, episode, segments, committed_until and run. :func:`summarize`
reads those straight from the CDR bytes (little-endian XCDR1, what rmw_fastrtps writes),
jumping over the per-detection arrays; any other encoding falls back to
``deserialize_message``. tests/unit/mlkm_ros/test_track_summary.py keeps it equal to the
full deserialization of the message definition.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from rclpy.serialization import deserialize_message

from road_sensor_msgs.msg import TrackArray

NS_PER_S = 1_000_000_000
_CDR_LE = b'\x00\x01'  # encapsulation: plain CDR, little endian


@dataclass(frozen=True)
class Passage:
    """A track's latest passage (its last detection in the track's order: by position on a
    road, by stamp on a network): its station's position [m], stamp [ns], speed [m/s] and
    sensor; the track's status."""

    track_id: int
    status: int
    position: float
    stamp_ns: int
    velocity: float
    sensor_id: int = -1


@dataclass
class Summary:
    mode: int
    episode_id: int
    final: bool
    segments_done: int
    segments_total: int
    committed_until_ns: int
    run: int
    # the tracks in the array: a Passage, or (track id, None) for a track without detections
    tracks: list[tuple[int, Passage | None]] = field(default_factory=list)


class _Cursor:
    def __init__(self, data: bytes) -> None:
        self.data = data
        self.at = 4  # past the encapsulation header; alignment counts from here

    def align(self, n: int) -> None:
        self.at += (-(self.at - 4)) % n

    def take(self, fmt: str, size: int, align: int = 0):
        self.align(align or size)
        value = struct.unpack_from('<' + fmt, self.data, self.at)
        self.at += size
        return value

    def u8(self) -> int:
        value = self.data[self.at]
        self.at += 1
        return value

    def u32(self) -> int:
        return self.take('I', 4)[0]

    def u64(self) -> int:
        return self.take('Q', 8)[0]

    def f64(self) -> float:
        return self.take('d', 8)[0]

    def time_ns(self) -> int:
        sec, nanosec = self.take('iI', 8, 4)  # builtin_interfaces/Time
        return sec * NS_PER_S + nanosec

    def string(self) -> None:
        n = self.u32()
        self.at += n

    def sequence(self, item_size: int, align: int) -> tuple[int, int]:
        """(count, offset of the first item) of a sequence of fixed-size items, jumped over."""
        n = self.u32()
        if n:
            self.align(align)
        start = self.at
        self.at += n * item_size
        return n, start

    def last(self, fmt: str, size: int, count: int, start: int):
        return struct.unpack_from('<' + fmt, self.data, start + (count - 1) * size)


def summarize(data: bytes) -> Summary:
    """The :class:`Summary` of a serialized road_sensor_msgs/TrackArray."""
    if data[:2] != _CDR_LE:
        return _from_message(deserialize_message(data, TrackArray))
    c = _Cursor(data)
    c.time_ns()  # header.stamp
    c.string()  # header.frame_id
    mode = c.u8()
    episode_id = c.u32()
    c.string()  # method
    final = bool(c.u8())
    segments_done = c.u32()
    segments_total = c.u32()
    tracks: list[tuple[int, Passage | None]] = []
    for _ in range(c.u32()):
        track_id = c.u64()
        status = c.u8()
        _, ids = c.sequence(4, 4)  # sensor_ids
        n, stamps = c.sequence(8, 4)
        _, velocities = c.sequence(8, 8)
        _, positions = c.sequence(8, 8)
        c.sequence(2, 2)  # lanes
        c.sequence(8, 8)  # lengths
        if n == 0:
            tracks.append((track_id, None))
            continue
        sec, nanosec = c.last('iI', 8, n, stamps)
        passage = Passage(
            track_id,
            status,
            c.last('d', 8, n, positions)[0],
            sec * NS_PER_S + nanosec,
            c.last('d', 8, n, velocities)[0],
            c.last('I', 4, n, ids)[0],
        )
        tracks.append((track_id, passage))
    c.sequence(4, 4)  # unassigned_sensor_ids
    c.sequence(8, 4)  # unassigned_stamps
    c.sequence(8, 8)  # unassigned_velocities
    c.sequence(2, 2)  # unassigned_lanes
    c.sequence(8, 8)  # unassigned_lengths
    committed_until_ns = c.time_ns()
    c.f64()  # solve_time
    run = c.u64()
    return Summary(
        mode,
        episode_id,
        final,
        segments_done,
        segments_total,
        committed_until_ns,
        run,
        tracks,
    )


def _from_message(msg: TrackArray) -> Summary:
    def ns(t) -> int:
        return t.sec * NS_PER_S + t.nanosec

    tracks: list[tuple[int, Passage | None]] = []
    for t in msg.tracks:
        passage = None
        if len(t.positions):
            passage = Passage(
                int(t.track_id),
                int(t.status),
                float(t.positions[-1]),
                ns(t.stamps[-1]),
                float(t.velocities[-1]),
                int(t.sensor_ids[-1]),
            )
        tracks.append((int(t.track_id), passage))
    return Summary(
        int(msg.mode),
        int(msg.episode_id),
        bool(msg.final),
        int(msg.segments_done),
        int(msg.segments_total),
        ns(msg.committed_until),
        int(msg.run),
        tracks,
    )
