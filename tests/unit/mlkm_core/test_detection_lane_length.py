"""Detections carry the optional per-detection lane and vehicle length through subset/concat."""

import numpy as np
import pytest

from mlkm_core.types import UNKNOWN_LANE, Detections


def _dets(n, lane=None, length=None, offset=0.0):
    return Detections(
        np.arange(n) % 2, np.arange(n) + offset, np.full(n, 30.0), np.arange(n), lane, length
    )


def test_lane_and_length_default_to_absent():
    d = Detections([0, 1], [1.0, 2.0], [30.0, 31.0])
    assert d.lane is None and d.length is None
    assert d.subset(np.array([True, False])).lane is None


def test_subset_carries_lane_and_length():
    d = _dets(4, lane=[0, 2, 1, 0], length=[4.5, 12.0, np.nan, 5.0])
    s = d.subset(np.array([3, 1]))
    assert s.lane.tolist() == [0, 2]
    assert s.length.tolist() == [5.0, 12.0]
    assert s.lane.dtype == np.int64


def test_concatenate_keeps_columns_and_fills_unknown():
    a = _dets(2, lane=[1, 2], length=[4.0, 16.5])
    b = _dets(3)  # a sensor without lane/length
    c = Detections.concatenate([a, b])
    assert c.lane.tolist() == [1, 2, UNKNOWN_LANE, UNKNOWN_LANE, UNKNOWN_LANE]
    assert c.length[:2].tolist() == [4.0, 16.5] and np.isnan(c.length[2:]).all()
    plain = Detections.concatenate([b, _dets(1)])
    assert plain.lane is None and plain.length is None and len(plain) == 4


def test_lane_and_length_are_validated():
    with pytest.raises(ValueError, match='lane'):
        _dets(3, lane=[0, 1])
    with pytest.raises(ValueError, match='lane'):
        _dets(2, lane=[0, -2])
    with pytest.raises(ValueError, match='length'):
        _dets(2, length=[4.0])
