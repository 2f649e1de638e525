"""The SUMO datasets of the benchmark: generated once per run, pickled, shared by every method.

Two measurement settings:

- ``default``: ``MeasurementConfig()`` as ``mlkm_sumo.api.generate`` uses it (no noise,
  no misses, lane-change double reports kept as false alarms);
- ``clutter``: 5 % missed passages and 0.2 s stamp jitter (``CLUTTER``; the measurement
  model's speed and length noise keep their defaults, 0), plus false alarms at 0.05 per
  vehicle per station: the same expected count as the simulator's clutter mode. SUMO's
  measurement model states false alarms per station and hour, so they are drawn with
  ``measurement.false_alarms`` at the rate that gives that count over the simulated time.

The road's on- and off-ramp positions (``Road.ramps``) go with every dataset (``ramps``), for
the associators' ``AssociatorConfig.entries`` / ``exits``.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np

from mlkm_core.types import FALSE_ALARM, Dataset, Detections

from .common import time_speed_only

MEASUREMENTS = ('default', 'clutter')
#: the clutter setting's measurement model (``MeasurementConfig`` fields)
CLUTTER = {'miss_rate': 0.05, 'stamp_jitter': 0.2}
#: false alarms per vehicle per station in the clutter setting
FALSE_ALARMS_PER_VEHICLE = 0.05


def measurement_config(measurement: str):
    """The ``MeasurementConfig`` that ``generate`` measures with in this setting."""
    from mlkm_sumo.measurement import MeasurementConfig

    if measurement not in MEASUREMENTS:
        raise ValueError(f'unknown measurement {measurement!r}; one of {MEASUREMENTS}')
    return MeasurementConfig(**CLUTTER) if measurement == 'clutter' else MeasurementConfig()


def add_false_alarms(ds, vehicles: int, per_vehicle: float, rng: np.random.Generator) -> Dataset:
    """``ds`` (a ``SumoDataset``) with false alarms drawn over its simulated time, at the
    rate that gives ``per_vehicle`` x ``vehicles`` false alarms per station on average."""
    from mlkm_sumo.measurement import MeasurementConfig, false_alarms

    span = float(ds.stats['simulated_s'])
    rate = per_vehicle * vehicles * 3600.0 / span  # per station and hour
    fa = false_alarms(MeasurementConfig(false_alarm_rate=rate), ds.road.lanes, 0.0, span, rng)
    extra = Detections(
        fa.station, fa.time, fa.speed, np.full(len(fa), FALSE_ALARM), fa.lane, fa.length
    )
    det = Detections.concatenate([ds.detections, extra])
    det = det.subset(np.argsort(det.stamp, kind='stable'))
    return Dataset(ds.layout, det, ds.n_targets)


class DatasetCache:
    """SUMO datasets generated once per run, pickled under ``root``; SUMO's network files
    are cached under ``root/networks``."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def path(
        self, scenario: str, vehicles: int, stations: int, seed: int, measurement: str = 'default'
    ) -> Path:
        tag = '' if measurement == 'default' else f'_{measurement}'
        return self.root / f'{scenario}{tag}_{vehicles}x{stations}_seed{seed}.pkl'

    def get(
        self, scenario: str, vehicles: int, stations: int, seed: int, measurement: str = 'default'
    ) -> Path:
        path = self.path(scenario, vehicles, stations, seed, measurement)
        if not path.exists():
            from mlkm_sumo.api import generate

            ds = generate(
                scenario,
                vehicles,
                stations,
                seed,
                measurement=measurement_config(measurement),
                cache_dir=self.root / 'networks',
            )
            if measurement == 'clutter':
                rng = np.random.default_rng([seed, vehicles, stations])
                plain = add_false_alarms(ds, vehicles, FALSE_ALARMS_PER_VEHICLE, rng)
            else:
                plain = Dataset(ds.layout, ds.detections, ds.n_targets)
            tmp = path.with_suffix('.tmp')
            tmp.write_bytes(pickle.dumps(plain, protocol=pickle.HIGHEST_PROTOCOL))
            tmp.replace(path)
        return path

    def family(self, draw) -> Path:
        """The dataset of a ``mlkm_sumo.families.Draw`` (default measurement), generated
        once; its sources and network live under ``root/networks``."""
        from mlkm_sumo.family_sources import draw_key, generate_family

        path = self.root / f'family_{draw.family}_seed{draw.seed}_{draw_key(draw)}.pkl'
        if not path.exists():
            ds = generate_family(draw, self.root / 'networks')
            plain = Dataset(ds.layout, ds.detections, ds.n_targets)
            tmp = path.with_suffix('.tmp')
            tmp.write_bytes(pickle.dumps(plain, protocol=pickle.HIGHEST_PROTOCOL))
            tmp.replace(path)
        return path

    def ramps(
        self, scenario: str, stations: int, seed: int
    ) -> tuple[tuple[float, ...], tuple[float, ...], np.ndarray]:
        """On-ramp and off-ramp positions [m] of the dataset's road, and its stations."""
        from mlkm_sumo.api import road

        r = road(scenario, stations, seed, cache_dir=self.root / 'networks')
        entries = tuple(float(x.position) for x in r.ramps if x.kind == 'on')
        exits = tuple(float(x.position) for x in r.ramps if x.kind == 'off')
        return entries, exits, r.layout.positions


def load(path: Path, variant: str) -> Dataset:
    """A cached dataset; ``time_speed`` strips lane and length from its detections."""
    ds: Dataset = pickle.loads(Path(path).read_bytes())
    return time_speed_only(ds) if variant == 'time_speed' else ds
