"""The measurement model on synthetic passages (no SUMO): rates and noise as configured."""

import numpy as np
import pytest

from mlkm_sumo.measurement import (
    DOUBLE_REPORT,
    FALSE_ALARM,
    PASSAGE,
    MeasurementConfig,
    MeasurementStats,
    Passages,
    apply,
)

N = 20000
LANES = np.array([3, 3, 2, 4, 3])


def synthetic(n=N, double_every=0, seed=0) -> Passages:
    rng = np.random.default_rng(seed)
    kind = np.full(n, PASSAGE)
    if double_every:
        kind[::double_every] = DOUBLE_REPORT
    station = rng.integers(0, LANES.size, n)
    return Passages(
        time=np.sort(rng.uniform(0, 3600, n)),
        station=station,
        lane=rng.integers(0, LANES[station]),
        speed=rng.uniform(20, 35, n),
        length=rng.choice([4.0, 4.6, 12.0], n),
        vehicle=np.array([f'v{k}' for k in range(n)], object),
        kind=kind,
    )


def test_default_model_changes_nothing():
    p = synthetic(500, double_every=50)
    out = apply(MeasurementConfig(), p, LANES, 0, 3600, np.random.default_rng(1))
    for name in ('time', 'station', 'lane', 'speed', 'length', 'vehicle', 'kind'):
        assert np.array_equal(getattr(out, name), getattr(p, name)), name


def test_noise_has_the_configured_spread():
    p = synthetic()
    cfg = MeasurementConfig(stamp_jitter=0.05, speed_noise=0.8, length_noise=0.3)
    out = apply(cfg, p, LANES, 0, 3600, np.random.default_rng(2))
    back = {v: k for k, v in enumerate(p.vehicle)}
    idx = np.array([back[v] for v in out.vehicle])
    # The sample std of N normal draws is within 5 % of the truth with overwhelming odds.
    for got, true, sd in (
        (out.time, p.time, 0.05),
        (out.speed, p.speed, 0.8),
        (out.length, p.length, 0.3),
    ):
        err = got - true[idx]
        assert abs(err.mean()) < 4 * sd / np.sqrt(N)
        assert err.std() == pytest.approx(sd, rel=0.05)
    assert np.all(np.diff(out.time) >= 0), 'output is sorted by noisy time'


def test_misses_come_at_the_configured_rate():
    p = synthetic()
    stats = MeasurementStats()
    out = apply(
        MeasurementConfig(miss_rate=0.1), p, LANES, 0, 3600, np.random.default_rng(3), stats
    )
    missed = N - len(out)
    sd = np.sqrt(N * 0.1 * 0.9)
    assert abs(missed - 0.1 * N) < 5 * sd
    assert stats.missed == missed and stats.passages == N


def test_false_alarms_come_at_the_configured_rate():
    p = synthetic(100)
    rate, hours = 40.0, 10.0
    stats = MeasurementStats()
    out = apply(
        MeasurementConfig(false_alarm_rate=rate, false_alarm_speed=(10.0, 20.0)),
        p,
        LANES,
        0,
        hours * 3600,
        np.random.default_rng(4),
        stats,
    )
    fa = out.subset(out.kind == FALSE_ALARM)
    expected = rate * LANES.size * hours  # Poisson mean 2000
    assert abs(len(fa) - expected) < 5 * np.sqrt(expected)
    assert stats.false_alarms == len(fa) and len(out) == 100 + len(fa)
    assert np.all(fa.lane < LANES[fa.station]) and np.all(fa.lane >= 0)
    assert np.all((fa.speed >= 10.0) & (fa.speed <= 20.0))
    assert set(fa.vehicle) == {''}
    per_station = np.bincount(fa.station, minlength=LANES.size)
    assert np.all(np.abs(per_station - expected / LANES.size) < 5 * np.sqrt(expected / LANES.size))


def test_double_reports_are_kept_or_removed_and_counted():
    p = synthetic(1000, double_every=10)
    keep = apply(MeasurementConfig(), p, LANES, 0, 3600, np.random.default_rng(5))
    assert int(np.sum(keep.kind == DOUBLE_REPORT)) == 100
    stats = MeasurementStats()
    cfg = MeasurementConfig(double_reports=False)
    drop = apply(cfg, p, LANES, 0, 3600, np.random.default_rng(5), stats)
    assert len(drop) == 900 and not np.any(drop.kind == DOUBLE_REPORT)
    assert stats.double_reports == 100 and stats.double_reports_removed == 100


def test_noisy_values_stay_positive():
    p = synthetic(2000)
    p.speed[:] = 0.2
    p.length[:] = 0.6
    out = apply(
        MeasurementConfig(speed_noise=5.0, length_noise=5.0), p, LANES, 0, 3600,
        np.random.default_rng(6),
    )  # fmt: skip
    assert out.speed.min() > 0 and out.length.min() > 0


@pytest.mark.parametrize(
    'kwargs',
    [{'miss_rate': 1.5}, {'speed_noise': -1.0}, {'false_alarm_rate': float('nan')},
     {'false_alarm_speed': (0.0, 3.0)}],
)  # fmt: skip
def test_bad_parameters_are_rejected(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        MeasurementConfig(**kwargs)
