"""``sumo_sensors`` parameters: one table with descriptions, units, ranges and choices, and the
frozen config the node runs with. config/sumo_sensors.param.yaml repeats every default (a test
keeps them equal)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from mlkm_ros.params import ParameterError, ParamSpec, non_negative
from mlkm_sumo import SCENARIOS, MeasurementConfig
from mlkm_sumo.network_families import NETWORK_FAMILIES
from road_sensors.delivery import DeliveryConfig, delivery_specs

MODES = ('episodes', 'continuous')


def _one_of(choices: tuple[str, ...]):
    def check(value: str) -> str | None:
        if value in choices:
            return None
        return f'unknown value {value!r}; choose one of {", ".join(choices)}'

    return check


def parse_positions(text: str) -> tuple[float, ...]:
    """'500, 1200 2600' -> (500.0, 1200.0, 2600.0); ParameterError on anything else."""
    try:
        values = tuple(float(x) for x in text.replace(',', ' ').split())
    except ValueError:
        raise ParameterError(
            f'stations_at must list positions in metres separated by commas, got {text!r}'
        ) from None
    if not all(math.isfinite(v) for v in values):
        raise ParameterError(f'stations_at must be finite positions, got {text!r}')
    return values


def _check_positions(text: str) -> str | None:
    try:
        parse_positions(text)
    except ParameterError as exc:
        return str(exc)
    return None


SPECS = [
    ParamSpec(
        'scenario',
        'highway',
        'SUMO scenario, one of ' + ', '.join(SCENARIOS) + ' (described by mlkm sumo --help) [-]',
        read_only=True,
        check=_one_of(tuple(SCENARIOS)),
        constraints='one of: ' + ', '.join(SCENARIOS),
    ),
    ParamSpec(
        'network',
        '',
        'a road network of this family instead of the scenario, drawn for `seed` (as `mlkm '
        'sumo --network`): one of ' + ', '.join(NETWORK_FAMILIES) + '; empty = the '
        'single-road scenario [-]',
        read_only=True,
        check=_one_of(('', *NETWORK_FAMILIES)),
        constraints='empty or one of: ' + ', '.join(NETWORK_FAMILIES),
    ),
    ParamSpec(
        'mode',
        'episodes',
        "'episodes': batches of `vehicles` vehicles, each announced with EpisodeInfo and "
        "ended when all left the road; 'continuous': open-road traffic at the flow (on a "
        "network: its draw's), no EpisodeInfo, episode_id 0 in ground truth [-]",
        read_only=True,
        check=_one_of(MODES),
        constraints='one of: ' + ', '.join(MODES),
    ),
    ParamSpec('vehicles', 20, 'vehicles per episode (episodes mode) [-]', 1, 1_000_000, True),
    ParamSpec('episodes', 3, 'episodes to publish (episodes mode) [-]', 1, 1_000_000, True),
    ParamSpec(
        'duration',
        600.0,
        'simulated time of continuous traffic; 0 = forever (continuous mode) [s]',
        0.0,
        1e9,
        True,
        non_negative,
    ),
    ParamSpec('stations', 20, 'sensor stations placed at random (seeded) [-]', 1, 10_000, True),
    ParamSpec(
        'stations_at',
        '',
        'station positions instead of random ones, comma-separated, e.g. "500,1200"; '
        'empty = random [m]',
        read_only=True,
        check=_check_positions,
    ),
    ParamSpec('seed', 1, 'seed of SUMO, the layout and the measurement [-]', 0, 2**31 - 1, True),
    ParamSpec('flow', 0.0, "demand; 0 = the scenario's own [veh/h]", 0.0, 1e6, True, non_negative),
    ParamSpec('step_length', 0.2, 'SUMO simulation step [s]', 0.001, 1.0, True),
    ParamSpec('stamp_jitter', 0.0, 'std of the Gaussian stamp noise [s]', 0.0, 60.0, True),
    ParamSpec('speed_noise', 0.0, 'std of the Gaussian speed noise [m/s]', 0.0, 100.0, True),
    ParamSpec('length_noise', 0.0, 'std of the Gaussian length noise [m]', 0.0, 100.0, True),
    ParamSpec(
        'miss_probability', 0.0, 'probability that a passage is not reported [-]', 0.0, 1.0, True
    ),
    ParamSpec('false_alarm_rate', 0.0, 'false alarms per station and hour [1/h]', 0.0, 1e6, True),
    ParamSpec(
        'double_reports',
        True,
        'keep the second report of a vehicle changing lane on top of a station (published '
        'as a false alarm in ground truth) [-]',
        read_only=True,
    ),
    *delivery_specs(
        {
            'real_time_factor': 'pacing: simulated seconds per wall second; 1.0 = real time, 0 = '
            'as fast as delivery allows (nothing is lost either way) [-]',
            'publish_clock': 'publish /clock with the SUMO time [-]',
            'wait_for_subscribers': 'before the start, wait until every detection topic has at '
            'least this many subscribers [-]',
            'wait_for_truth_subscribers': 'before the start, wait until /road/ground_truth has at '
            'least this many subscribers [-]',
            'ack_timeout': 'at the end, wait at most this long for every subscriber to '
            'acknowledge every message [s]',
            'keep_running': 'stay up after the last message (the latched layout stays '
            'available) [-]',
        }
    ),
    ParamSpec(
        'cache_dir',
        '',
        'where built SUMO networks are cached; empty = $XDG_CACHE_HOME/mlkm_sumo [-]',
        read_only=True,
    ),
]


@dataclass(frozen=True)
class SumoSensorsConfig(DeliveryConfig):
    """Everything the node needs, from its parameters (read once at startup)."""

    scenario: str
    network: str | None  # a network family; None: the single-road scenario
    mode: str
    vehicles: int
    episodes: int
    duration: float | None  # None: forever
    stations: int
    stations_at: tuple[float, ...] | None
    seed: int
    flow: float | None  # None: the scenario's
    step_length: float
    measurement: MeasurementConfig
    cache_dir: str | None

    def sumo_options(self) -> dict[str, Any]:
        """The settings ``mlkm_sumo.episodes`` and ``mlkm_sumo.PassageStream`` share."""
        return {
            'n_stations': self.stations,
            'seed': self.seed,
            'stations_at': self.stations_at,
            'measurement': self.measurement,
            'cache_dir': self.cache_dir,
            'step_length': self.step_length,
            'flow': self.flow,
        }

    @staticmethod
    def from_values(v: dict[str, Any]) -> SumoSensorsConfig:
        try:
            measurement = MeasurementConfig(
                stamp_jitter=v['stamp_jitter'],
                speed_noise=v['speed_noise'],
                length_noise=v['length_noise'],
                miss_rate=v['miss_probability'],
                false_alarm_rate=v['false_alarm_rate'],
                double_reports=v['double_reports'],
            )
        except ValueError as exc:
            raise ParameterError(f'invalid measurement model: {exc}') from None
        return SumoSensorsConfig(
            scenario=v['scenario'],
            network=v['network'] or None,
            mode=v['mode'],
            vehicles=v['vehicles'],
            episodes=v['episodes'],
            duration=v['duration'] or None,
            stations=v['stations'],
            stations_at=parse_positions(v['stations_at']) or None,
            seed=v['seed'],
            flow=v['flow'] or None,
            step_length=v['step_length'],
            measurement=measurement,
            cache_dir=v['cache_dir'] or None,
            **DeliveryConfig.values(v),
        )
