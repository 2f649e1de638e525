"""The detections CSV's optional lane and length_m columns: a malformed value is refused with
its line number, and the valid rows keep their lanes and lengths; with --skip-invalid the rest
of the file is read."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from mlkm_core.csvio import InvalidRows, read_detections

HEADER = 'sensor_id,position_m,stamp_s,velocity_mps,target_id,lane,length_m'
GOOD = [
    '1,100.0,10.0,30.0,0,0,4.5',
    '1,100.0,10.0,25.0,1,2,16.0',  # same sensor and stamp, another lane: a second vehicle
    '2,200.0,13.3,30.0,0,,',  # lane and length unknown
    '2,200.0,14.0,25.0,1,-1,nan',
]


def write(tmp_path: Path, rows: list[str]) -> Path:
    path = tmp_path / 'd.csv'
    path.write_text('\n'.join([HEADER, *rows]) + '\n')
    return path


def test_lanes_and_lengths_are_read(tmp_path) -> None:
    data = read_detections(write(tmp_path, GOOD))
    d = data.detections
    assert d.lane.tolist() == [0, 2, -1, -1]
    assert d.length[:2].tolist() == [4.5, 16.0] and all(math.isnan(x) for x in d.length[2:])
    assert d.stamp[:2].tolist() == [10.0, 10.0]


@pytest.mark.parametrize(
    ('row', 'words'),
    [
        ('2,200.0,15.0,30.0,0,left,4.5', "lane is not an integer: 'left'"),
        ('2,200.0,15.0,30.0,0,-2,4.5', 'lane must be in [-1, 2^63), got -2'),
        ('2,200.0,15.0,30.0,0,1,long', "length_m is not a number: 'long'"),
        ('2,200.0,15.0,30.0,0,1,-4.5', 'length_m must be > 0 or nan, got -4.5'),
        ('2,200.0,15.0,30.0,0,1,inf', 'length_m must be > 0 or nan, got inf'),
        ('2,200.0,15.0,30.0,0,1.5,4.5', "lane is not an integer: '1.5'"),
    ],
)
def test_malformed_lane_or_length_is_refused_with_its_line(tmp_path, row, words) -> None:
    path = write(tmp_path, [*GOOD[:2], row, *GOOD[2:]])
    with pytest.raises(InvalidRows) as caught:
        read_detections(path)
    (problem,) = caught.value.problems
    assert (problem.line, problem.reason) == (4, 'malformed')
    assert words in problem.message
    assert f'line 4: {words}' in str(caught.value)
    kept = read_detections(path, skip_invalid=True)
    assert len(kept.detections) == 4 and kept.detections.lane.tolist() == [0, 2, -1, -1]


def test_duplicate_is_same_sensor_lane_and_stamp(tmp_path) -> None:
    with pytest.raises(InvalidRows) as caught:
        read_detections(write(tmp_path, [*GOOD, '1,100.0,10.0,29.0,2,2,4.0']))
    (problem,) = caught.value.problems
    assert (problem.line, problem.reason) == (6, 'duplicate')
    assert 'duplicate of line 3' in problem.message
