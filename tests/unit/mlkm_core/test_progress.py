"""``mlkm_core.progress``: the fraction done reaches a listener through nested stages."""

import numpy as np
import pytest

from mlkm_core import progress
from mlkm_core.associators import make_associator
from mlkm_core.simulator import SimConfig, simulate


def test_stages_map_their_steps_onto_the_whole():
    seen = []
    with progress.reporting(seen.append):
        with progress.stage(0.0, 0.5):
            for k in range(1, 5):
                progress.advance(k, 4)  # 1/8, 2/8, 3/8, 4/8
        with progress.stage(0.5, 0.9):
            with progress.stage(0.0, 0.5):
                progress.advance(1, 2)  # half of the first half of [0.5, 0.9]
            with progress.stage(0.5, 1.0, detail=False):
                progress.advance(1, 2)  # not passed on: only the end of this part is
        progress.advance(1, 1)
    assert seen == pytest.approx([0.125, 0.25, 0.375, 0.5, 0.6, 0.7, 0.9, 1.0])


def test_the_fraction_never_goes_back_and_steps_below_the_minimum_are_dropped():
    seen = []
    with progress.reporting(seen.append):
        progress.advance(5, 10)
        progress.advance(2, 10)  # a second pass over the same part: no step back
        progress.advance(5.00001, 10)  # below MIN_STEP
        progress.advance(10, 10)
    assert seen == [0.5, 1.0]


def test_without_a_listener_nothing_happens():
    with progress.stage(0.0, 0.5):
        progress.advance(1, 2)  # no error, no effect


@pytest.mark.parametrize('method', ['assignment', 'multiframe', 'mlkm_robust'])
def test_a_tracking_method_reports_a_rising_fraction_to_the_end(method):
    ds = simulate(SimConfig(n_targets=20, n_sensors=10, false_alarm_rate=0.05), 5)
    seen = []
    with progress.reporting(seen.append):
        labels = make_associator(method).associate(ds.layout, ds.detections, 20)
    plain = make_associator(method).associate(ds.layout, ds.detections, 20)
    assert np.array_equal(labels, plain)  # listening changes nothing
    assert len(seen) > 10  # link passes report sensor by sensor
    assert np.all(np.diff(seen) > 0) and 0 < seen[0] and seen[-1] == 1.0
