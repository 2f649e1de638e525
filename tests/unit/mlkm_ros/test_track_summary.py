"""The markers' reading of a serialized TrackArray equals the full deserialization."""

from __future__ import annotations

import math

import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import serialize_message

from mlkm_ros.track_summary import NS_PER_S, _from_message, summarize
from road_sensor_msgs.msg import Track, TrackArray


def _track(track_id: int, status: int, n: int) -> Track:
    return Track(
        track_id=track_id,
        status=status,
        sensor_ids=[40 + k for k in range(n)],
        stamps=[Time(sec=10 + k, nanosec=7 * k + 1) for k in range(n)],
        velocities=[20.0 + k / 3 for k in range(n)],
        positions=[100.0 * (k + 1) for k in range(n)],
        lanes=[k % 3 - 1 for k in range(n)],
        lengths=[math.nan if k % 2 else 4.5 for k in range(n)],
    )


@pytest.mark.parametrize('unassigned', [0, 1, 3])
@pytest.mark.parametrize('mode', [TrackArray.MODE_EPISODES, TrackArray.MODE_STREAM])
def test_summary_equals_the_deserialized_message(mode, unassigned) -> None:
    big = 1_764_210_000_000_000
    msg = TrackArray(
        mode=mode,
        episode_id=3,
        method='a method name of odd length',
        final=True,
        segments_done=2,
        segments_total=4,
        tracks=[_track(big + 1, 1, 3), _track(5, Track.STATUS_FINAL, 0), _track(big, 2, 1)],
        unassigned_sensor_ids=list(range(unassigned)),
        unassigned_stamps=[Time(sec=k) for k in range(unassigned)],
        unassigned_velocities=[1.0] * unassigned,
        unassigned_lanes=[-1] * unassigned,
        unassigned_lengths=[0.0] * unassigned,
        committed_until=Time(sec=12, nanosec=345),
        solve_time=0.25,
        run=big,
    )
    msg.header.frame_id = 'road'
    got = summarize(serialize_message(msg))
    assert got == _from_message(msg)
    assert got.committed_until_ns == 12 * NS_PER_S + 345
    assert got.run == big and got.mode == mode and got.final
    (first_id, first), (empty_id, empty), _ = got.tracks
    assert (first_id, empty_id, empty) == (big + 1, 5, None)
    assert (first.position, first.stamp_ns, first.velocity, first.sensor_id) == (
        300.0,
        12 * NS_PER_S + 15,
        20.0 + 2 / 3,
        42,
    )
