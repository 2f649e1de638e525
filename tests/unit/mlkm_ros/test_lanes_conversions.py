"""Lane and vehicle length through the message conversions: detections, ground truth, the
layout (lanes per station, ramps) and tracks, each through a CDR round trip."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from mlkm_core.bounds import Bounds
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv
from road_sensor_msgs.msg import Detection, GroundTruth, SensorLayout, Track, TrackArray

LAYOUT = Layout(5000.0, np.array([500.0, 1500.0, 2500.0]), np.array([7, 8, 9]), ('a', 'b', 'c'))


def cdr(msg):
    return deserialize_message(serialize_message(msg), type(msg))


def test_detection_carries_lane_and_length() -> None:
    back = cdr(conv.detection_to_msg(8, 12 * conv.NS_PER_S + 5, 1500.0, 31.5, 2, 12.25))
    assert (back.sensor_id, back.lane, back.length) == (8, 2, 12.25)
    assert conv.time_to_ns(back.header.stamp) == 12 * conv.NS_PER_S + 5
    assert conv.detection_length(back) == 12.25


def test_detection_without_lane_or_length_reads_unknown() -> None:
    back = cdr(conv.detection_to_msg(8, 1, 1500.0, 31.5))
    assert back.lane == Detection.LANE_UNKNOWN == -1
    assert math.isnan(back.length) and math.isnan(conv.detection_length(back))
    # A source that leaves the field unset (0) measured no length either.
    assert math.isnan(conv.detection_length(Detection()))


def test_ground_truth_carries_lane_and_vehicle_id() -> None:
    back = cdr(conv.ground_truth_to_msg(3, 9, 77, 4, 30.0, lane=1, vehicle_id='v42'))
    assert (back.episode_id, back.sensor_id, back.target_id) == (3, 9, 4)
    assert (back.lane, back.vehicle_id, back.false_alarm) == (1, 'v42', False)
    fa = cdr(conv.ground_truth_to_msg(0, 9, 78, -1, 30.0, lane=2, vehicle_id='v42'))
    assert fa.false_alarm and fa.target_id == GroundTruth.FALSE_ALARM and fa.lane == 2
    assert cdr(conv.ground_truth_to_msg(0, 9, 78, 1, 30.0)).lane == -1


def test_layout_round_trip_with_lanes_and_ramps() -> None:
    msg = cdr(conv.layout_to_msg(LAYOUT, 5, [3, 2, 3], [1200.0], [2300.0, 4300.0]))
    assert list(msg.lane_counts) == [3, 2, 3]
    assert list(msg.entry_positions) == [1200.0]
    assert list(msg.exit_positions) == [2300.0, 4300.0]
    layout = conv.layout_from_msg(msg)
    assert layout.positions.tolist() == [500.0, 1500.0, 2500.0]
    assert conv.lane_counts_from_msg(msg) == (3, 2, 3)
    plain = cdr(conv.layout_to_msg(LAYOUT, 5))
    assert conv.lane_counts_from_msg(plain) is None
    assert list(plain.entry_positions) == list(plain.exit_positions) == []


@pytest.mark.parametrize(
    ('field', 'value', 'words'),
    [
        ('lane_counts', [3, 2], 'lane_counts has 2 entries for 3 sensors'),
        ('lane_counts', [3, 0, 1], 'lane_counts must be >= 1'),
        ('entry_positions', [math.nan], 'entry_positions: nan m is not inside the road'),
        ('exit_positions', [5000.0], 'exit_positions: 5000.0 m is not inside the road'),
        ('entry_positions', [-1.0], 'entry_positions: -1.0 m is not inside the road'),
        ('exit_positions', [math.inf], 'exit_positions: inf m is not inside the road'),
    ],
)
def test_layout_with_bad_lanes_or_ramps_is_refused(field, value, words) -> None:
    msg = conv.layout_to_msg(LAYOUT, 5, [3, 2, 3])
    setattr(msg, field, value)
    with pytest.raises(ValueError, match=words):
        conv.layout_from_msg(msg)


def tracks(final: bool) -> TrackArray:
    # Two vehicles pass sensor 7 in the same nanosecond, in lanes 0 and 2.
    return conv.tracks_to_msg(
        episode_id=4,
        method='mlkm',
        final=final,
        segments_done=1,
        segments_total=2,
        sensor_ids=[7, 7, 8, 8, 9],
        stamps_ns=[100, 100, 200, 210, 300],
        velocities=[30.0, 25.0, 30.0, 25.0, 28.0],
        positions=[500.0, 500.0, 1500.0, 1500.0, 2500.0],
        labels=[0, 1, 0, 1, -1],
        solve_time=0.5,
        stamp_ns=9,
        lanes=[2, 0, 2, 1, 1],
        lengths=[4.5, 16.0, 4.6, math.nan, 12.0],
    )


def test_tracks_carry_lanes_lengths_mode_and_status() -> None:
    msg = cdr(tracks(final=True))
    assert msg.mode == TrackArray.MODE_EPISODES
    assert [t.status for t in msg.tracks] == [Track.STATUS_FINAL] * 2
    by_id = {t.track_id: t for t in msg.tracks}
    assert list(by_id[0].lanes) == [2, 2] and list(by_id[0].lengths) == [4.5, 4.6]
    assert list(by_id[1].lanes) == [0, 1]
    assert by_id[1].lengths[0] == 16.0 and math.isnan(by_id[1].lengths[1])
    assert list(msg.unassigned_lanes) == [1] and list(msg.unassigned_lengths) == [12.0]
    ids, stamps, _, labels = conv.tracks_from_msg(msg)
    lanes, lengths = conv.track_lanes_from_msg(msg)
    rows = set(zip(ids.tolist(), stamps.tolist(), lanes.tolist(), labels.tolist()))
    assert rows == {
        (7, 100, 2, 0),
        (8, 200, 2, 0),
        (7, 100, 0, 1),
        (8, 210, 1, 1),
        (9, 300, 1, -1),
    }
    assert lengths.size == 5 and np.isnan(lengths).sum() == 1
    partial = cdr(tracks(final=False))
    assert [t.status for t in partial.tracks] == [Track.STATUS_CONFIRMED] * 2


def test_tracks_without_lanes_read_as_unknown() -> None:
    msg = conv.tracks_to_msg(
        episode_id=0,
        method='mlkm',
        final=True,
        segments_done=1,
        segments_total=1,
        sensor_ids=[7, 8],
        stamps_ns=[1, 2],
        velocities=[3.0, 3.0],
        positions=[500.0, 1500.0],
        labels=[0, 0],
        solve_time=0.0,
        stamp_ns=0,
    )
    assert list(msg.tracks[0].lanes) == [-1, -1]
    msg.tracks[0].lanes, msg.tracks[0].lengths = [], []  # an older source sends none
    lanes, lengths = conv.track_lanes_from_msg(msg)
    assert lanes.tolist() == [-1, -1] and np.isnan(lengths).all()
    msg.tracks[0].lanes = [0]
    with pytest.raises(ValueError, match='track 0'):
        conv.track_lanes_from_msg(msg)


def test_length_bounds() -> None:
    b = Bounds()
    assert b.refuse(1.0, 30.0) is None
    assert b.refuse(1.0, 30.0, math.nan) is None
    assert b.refuse(1.0, 30.0, 0.0) is None  # not measured
    assert b.refuse(1.0, 30.0, 18.75) is None
    for bad in (-4.0, 0.05, 100.5, math.inf, -math.inf):
        assert b.refuse(1.0, 30.0, bad) == 'length_out_of_range'
    assert 'vehicle length outside [0.1, 100] m' in b.describe('length_out_of_range')
    assert b.refuse_all(np.array([1.0, 2.0]), np.array([30.0, 30.0]), np.array([5.0, 1e9])) == [
        None,
        'length_out_of_range',
    ]
    with pytest.raises(ValueError, match='min_length < max_length'):
        Bounds(min_length=5.0, max_length=4.0)
    assert SensorLayout  # the message type is importable alongside


def test_retired_track_ids_are_empty_final_tracks() -> None:
    """An id an earlier message of the episode carried, now without detections, comes as an
    empty FINAL track; the detections and their labels are those of the other tracks."""
    msg = conv.tracks_to_msg(
        episode_id=4,
        method='mlkm',
        final=False,
        segments_done=2,
        segments_total=3,
        sensor_ids=[7, 8],
        stamps_ns=[100, 200],
        velocities=[30.0, 30.0],
        positions=[500.0, 1500.0],
        labels=[0, 0],
        solve_time=0.5,
        stamp_ns=9,
        retired=(3, 5),
    )
    back = cdr(msg)
    by_id = {t.track_id: t for t in back.tracks}
    assert sorted(by_id) == [0, 3, 5]
    assert by_id[0].status == Track.STATUS_CONFIRMED and len(by_id[0].sensor_ids) == 2
    for i in (3, 5):
        assert by_id[i].status == Track.STATUS_FINAL and len(by_id[i].sensor_ids) == 0
    ids, _, _, labels = conv.tracks_from_msg(back)
    assert ids.tolist() == [7, 8] and labels.tolist() == [0, 0]
