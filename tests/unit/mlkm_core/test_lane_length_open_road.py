"""An open road (on- and off-ramps between sensors) declared to the associators."""

import numpy as np
import pytest

from mlkm_core.associators import AssociatorConfig
from mlkm_core.associators.likelihood import sequence_nll
from mlkm_core.model.motion import MotionParams
from mlkm_core.types import Detections, Layout

POSITIONS = 200.0 * np.arange(1, 11)


def test_openings_per_sensor():
    first, last = MotionParams.road_openings(POSITIONS, (650.0,), (1250.0,))
    # sensors 0..2 lie upstream of the entry at 650 m, 3.. downstream
    np.testing.assert_array_equal(first, [0, 0, 0, 3, 3, 3, 3, 3, 3, 3])
    # sensors 0..5 lie upstream of the exit at 1250 m
    np.testing.assert_array_equal(last, [5, 5, 5, 5, 5, 5, 9, 9, 9, 9])
    assert MotionParams.road_openings(POSITIONS, (), ()) is None


def test_config_refuses_non_finite_ramps():
    with pytest.raises(ValueError, match='entries'):
        AssociatorConfig(entries=(float('nan'),))
    assert AssociatorConfig(exits=[1250]).exits == (1250.0,)


def test_track_that_leaves_at_an_exit_pays_no_missed_sensors():
    layout = Layout(2200.0, POSITIONS)
    # one vehicle at 25 m/s seen at sensors 0..5 only
    d = Detections(np.arange(6), POSITIONS[:6] / 25.0, np.full(6, 25.0))
    seqs = np.arange(6)[None, :]
    ones = np.ones(1, bool)
    closed = MotionParams()
    opened = MotionParams(open_road=MotionParams.road_openings(POSITIONS, (), (1250.0,)))
    gap = sequence_nll(layout, d, seqs, closed, ones, ones) - sequence_nll(
        layout, d, seqs, opened, ones, ones
    )
    assert gap[0] == pytest.approx(4 * closed.miss_cost)
