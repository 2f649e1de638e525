"""Self-calibration recovers the parameters of the simulator that generated the data.

``estimate_params`` is given only the detections; the simulator's settings are the truth.
Tolerances come from the spread over seeds, with the sampling error in mind: a data set of
100 targets x 30 sensors has about 2,800 consecutive links, so the stamp-noise variance
(a trimmed moment) has a relative standard error of about 3 % and the miss rate, over about
3,000 sensor slots, a standard error of about 0.004 (plus a small upward bias: tracks that
the first pass breaks count as misses).

What the data pin down less well is the split of speed variation between the fluctuation
(sigma, L) and the speed measurement noise at these sensor spacings; it is checked where there
is no measurement noise (paper mode), for the fluctuation strength sigma.
"""

from __future__ import annotations

import pytest

from mlkm_core.associators import canonical_order
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.simulator import SimConfig, simulate

CLUTTER = dict(miss_probability=0.05, false_alarm_rate=0.05, stamp_noise=0.2, velocity_noise=0.5)


def calibrated(config: SimConfig, seed: int):
    ds = simulate(config, seed)
    return estimate_params(ds.layout, ds.detections.subset(canonical_order(ds.detections)))


@pytest.mark.parametrize('seed', range(3))
def test_stamp_noise_and_miss_rate_are_recovered_in_clutter(seed):
    p = calibrated(SimConfig(n_targets=100, n_sensors=30, **CLUTTER), seed)
    assert p.stamp_noise == pytest.approx(0.2, rel=0.10)
    assert 0.04 <= p.p_miss <= 0.07


@pytest.mark.parametrize('seed', range(2))
def test_stamp_noise_is_recovered_on_a_longer_road(seed):
    config = SimConfig(
        n_targets=100,
        n_sensors=30,
        road_length=1000.0,
        stamp_noise=0.3,
        velocity_noise=0.3,
        velocity_variation=2.5,
        variation_length=500.0,
    )
    assert calibrated(config, seed).stamp_noise == pytest.approx(0.3, rel=0.10)


@pytest.mark.parametrize('seed', range(3))
def test_fluctuation_is_recovered_without_measurement_noise(seed):
    """Paper mode (exact stamps and speeds): sigma = 4 m/s, L = 300 m; the noises go to their
    floors. sigma spread 3.4 .. 4.5 m/s over eight seeds: 20 % tolerance."""
    p = calibrated(SimConfig(n_targets=100, n_sensors=30, miss_probability=0.05), seed)
    assert p.sigma == pytest.approx(4.0, rel=0.20)
    assert 100.0 <= p.length <= 900.0
    assert p.stamp_noise < 0.01
    assert p.velocity_noise < 0.1
