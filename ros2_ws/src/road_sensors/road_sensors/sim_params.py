"""``sensor_sim``'s parameters: one read-only parameter per ``SimConfig`` field, the node's own
settings, and the frozen config built from them. config/sensor_sim.param.yaml repeats every
default (a test keeps them equal).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from mlkm_core.simulator import SimConfig
from mlkm_ros.params import ParameterError, ParamSpec
from road_sensors.delivery import DeliveryConfig, delivery_specs

#: Descriptions (with units) and inclusive ranges of the simulator's settings.
_SIM_DOCS: dict[str, tuple[str, float | None, float | None]] = {
    'road_length': ('road length D [m]', 1e-3, 1e9),
    'n_sensors': ('number of sensors N_S [-]', 1, 100000),
    'n_targets': ('number of targets N_A per episode [-]', 1, 10000000),
    'velocity_mean': ('mean cruise speed mu [m/s]', 1e-6, 1e6),
    'velocity_std': ('std of the cruise speed sigma [m/s]', 0.0, 1e6),
    'start_increment_min': ('t_min of the start-time increment U(t_min, t_max) [s]', -1e6, 1e6),
    'start_increment_max': ('t_max of the start-time increment U(t_min, t_max) [s]', -1e6, 1e6),
    'velocity_variation': (
        'stationary std of the speed fluctuation along the road [m/s]',
        0.0,
        1e6,
    ),
    'variation_length': ('correlation length of the speed fluctuation [m]', 1e-6, 1e9),
    'variation_step': ('grid step of the speed profile [m]', 1e-6, 1e9),
    'min_speed': ('speeds are clipped at this floor [m/s]', 1e-9, 1e6),
    'miss_probability': ('probability that a passage is not reported [-], in [0, 1)', 0.0, 1.0),
    'false_alarm_rate': ('expected false alarms per sensor per target [-]', 0.0, 1e6),
    'false_alarms_per_sensor': ('expected false alarms per sensor per episode [-]', 0.0, 1e9),
    'stamp_noise': ('std of the Gaussian stamp noise [s]', 0.0, 1e6),
    'velocity_noise': ('std of the Gaussian speed noise [m/s]', 0.0, 1e6),
}


def _sim_specs() -> list[ParamSpec]:
    """One read-only parameter per SimConfig field (all of them, whatever the core adds)."""
    specs = []
    defaults = SimConfig()
    for f in fields(SimConfig):
        value = getattr(defaults, f.name)
        if isinstance(value, int) and not isinstance(value, bool):
            value = int(value)
        elif isinstance(value, float):
            value = float(value)
        doc, low, high = _SIM_DOCS.get(f.name, (f'simulator setting {f.name}', None, None))
        specs.append(ParamSpec(f.name, value, doc, low, high, read_only=True))
    return specs


def _check_mode(value: str) -> str | None:
    if value in ('episodes', 'continuous'):
        return None
    return f'unknown mode {value!r}; choose episodes or continuous'


_NODE_SPECS = [
    ParamSpec(
        'mode',
        'episodes',
        "episodes: the paper's datasets one after another, each announced by EpisodeInfo; "
        'continuous: vehicles enter for ever, no episodes [-]',
        check=_check_mode,
        constraints='one of: episodes, continuous',
        read_only=True,
    ),
    ParamSpec(
        'duration',
        0.0,
        'continuous mode: stop after this much passage time; 0 = for ever [s]',
        0.0,
        1e9,
        read_only=True,
    ),
    ParamSpec(
        'arrival_rate',
        0.0,
        'continuous mode: vehicles enter as a Poisson stream of this rate; 0 = the '
        "paper's U(start_increment_min, start_increment_max) spacing [vehicles/s]",
        0.0,
        1e6,
        read_only=True,
    ),
    ParamSpec(
        'seed', 0, 'seed of the layout and of every episode [-]', 0, 2**31 - 1, read_only=True
    ),
    ParamSpec('episodes', 3, 'number of episodes to publish [-]', 1, 1000000, read_only=True),
    ParamSpec(
        'episode_gap',
        10.0,
        'passage-time gap between the last detection of one episode and the first of the next [s]',
        0.0,
        1e9,
        read_only=True,
    ),
    *delivery_specs(
        {
            'real_time_factor': 'pacing: passage seconds per wall second; 1.0 = real time, 0 = '
            'as fast as delivery allows (nothing is lost either way) [-]',
            'publish_clock': 'publish /clock with the passage time [-]',
            'wait_for_subscribers': 'before the first episode, wait until every detection topic '
            'has at least this many subscribers (association node, recorder, ...) [-]',
            'wait_for_truth_subscribers': 'before the first episode, wait until '
            '/road/ground_truth has at least this many subscribers (scorer, recorder, ...) [-]',
            'ack_timeout': 'at each episode end, wait at most this long for every subscriber to '
            'acknowledge every message [s]',
            'keep_running': 'stay up after the last episode (the latched layout stays '
            'available) [-]',
        }
    ),
]


@dataclass(frozen=True)
class SensorSimConfig(DeliveryConfig):
    """Everything the node needs, from its parameters (read once at startup)."""

    sim: SimConfig
    mode: str
    duration: float
    arrival_rate: float
    seed: int
    episodes: int
    episode_gap: float

    @staticmethod
    def from_values(values: dict[str, Any]) -> SensorSimConfig:
        sim_names = {f.name for f in fields(SimConfig)}
        try:
            sim = SimConfig(**{k: v for k, v in values.items() if k in sim_names})
        except (ValueError, TypeError) as exc:
            raise ParameterError(f'invalid simulator settings: {exc}') from None
        rest = {k: v for k, v in values.items() if k not in sim_names}
        if rest.get('mode') == 'continuous' and sim.false_alarms_per_sensor != 0:
            raise ParameterError(
                'false_alarms_per_sensor counts per episode; continuous mode needs 0 '
                '(use false_alarm_rate)'
            )
        return SensorSimConfig(sim=sim, **rest)
