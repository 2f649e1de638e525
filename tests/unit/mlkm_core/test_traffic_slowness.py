"""The traffic's own slowness at each station over time (hand-made road works that slow every
vehicle to 55 % of its own speed at the middle two of four stations)."""

import numpy as np
import pytest

from mlkm_core.associators import calibration, make_associator
from mlkm_core.associators.calibration import estimate_params
from mlkm_core.metrics import accuracy
from mlkm_core.model.traffic import estimate_traffic
from mlkm_core.streaming.solve import CarriedModel
from mlkm_core.types import Detections, Layout

POSITIONS = np.array([0.0, 800.0, 1600.0, 2400.0])
CRUISE = 28.0  # mean cruise speed [m/s]
SLOW = 0.55  # speed factor inside the works


def road_works(seed: int, factor=(1.0, SLOW, SLOW, 1.0), n: int = 100):
    """``n`` vehicles 1-3 s apart, each at its own cruise speed (28 +- 3 m/s) times the
    station's ``factor``, measured within 0.3 m/s; travel times from the speeds at both ends."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(1.0, 3.0, n))
    own = rng.normal(CRUISE, 3.0, n)
    sensor, stamp, speed, target = [], [], [], []
    before = None
    for s, x in enumerate(POSITIONS):
        v = own * factor[s] + rng.normal(0.0, 0.3, n)
        if before is not None:
            t = t + (x - POSITIONS[s - 1]) * (1 / v + 1 / before) / 2
        before = v
        sensor += [s] * n
        stamp += t.tolist()
        speed += v.tolist()
        target += list(range(n))
    layout = Layout(2600.0, POSITIONS.copy())
    d = Detections(np.array(sensor), np.array(stamp), np.array(speed), target=np.array(target))
    return layout, d


def test_the_field_shows_the_change_every_vehicle_shares() -> None:
    layout, d = road_works(1)
    field = estimate_traffic(layout, d)
    assert field is not None
    first, second = (d.stamp[d.sensor_index == s] for s in (0, 1))
    change = float(np.median(field.change(0.0, first, 800.0, second)))
    # the median vehicle's slowness rises from 1/28 to 1/(0.55 * 28) s/m
    assert change == pytest.approx(1 / (SLOW * CRUISE) - 1 / CRUISE, rel=0.05)
    assert abs(float(np.median(field.change(800.0, second, 1600.0, second)))) < 0.1 * change


def test_free_flow_shows_no_field() -> None:
    layout, d = road_works(1, factor=(1.0, 1.0, 1.0, 1.0))
    assert estimate_traffic(layout, d) is None


def test_the_model_follows_the_field(monkeypatch) -> None:
    """With the field the fitted speed noise stays small and multiframe links the works;
    without it the shared slowdown is taken for noise and speed jumps."""
    layout, d = road_works(2)
    with_field = estimate_params(layout, d)
    assert with_field.traffic is not None and with_field.velocity_noise < 0.2
    found = accuracy(make_associator('multiframe').associate(layout, d, 100), d.target)
    assert found.accuracy >= 0.95
    monkeypatch.setattr(calibration, 'estimate_traffic', lambda *args, **kwargs: None)
    without = estimate_params(layout, d)
    assert without.traffic is None and without.velocity_noise > 0.4
    lost = accuracy(make_associator('multiframe').associate(layout, d, 100), d.target)
    assert lost.accuracy <= found.accuracy - 0.05


def test_a_carried_model_takes_the_field_of_each_window() -> None:
    layout, d = road_works(3)
    carried = CarriedModel.of(estimate_params(layout, d))
    assert carried.traffic and carried.params.traffic is None
    later = Detections(d.sensor_index, d.stamp + 3600.0, d.velocity, target=d.target)
    field = carried.bind(layout, later).traffic
    assert field is not None and field.times[0][0] == pytest.approx(later.stamp.min())
