"""``log_source`` parameters: one table with descriptions, units and choices, and the frozen
config the node runs with. config/log_source.param.yaml repeats every default (a test keeps
them equal)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mlkm_ros.params import ParameterError, ParamSpec
from road_sensors.delivery import DeliveryConfig, delivery_specs

MODES = ('episodes', 'continuous')


def _check_mode(value: str) -> str | None:
    if value in MODES:
        return None
    return f'unknown value {value!r}; choose one of {", ".join(MODES)}'


SPECS = [
    ParamSpec(
        'log',
        '',
        'path of the detection log: the CSV `mlkm associate --input` reads (sensor_id, '
        'position_m, stamp_s, velocity_mps, optional target_id, lane, length_m); required [-]',
        read_only=True,
    ),
    ParamSpec(
        'layout',
        '',
        'path of the road layout file (YAML: road_length_m, stations with id, name, '
        'position_m, lanes; entries_m, exits_m) holding every sensor of the log; required [-]',
        read_only=True,
    ),
    ParamSpec(
        'mode',
        'episodes',
        "'episodes': the whole log is one episode, announced by EpisodeInfo STARTED and "
        "ENDED; 'continuous': a stream, no EpisodeInfo, episode_id 0 in ground truth [-]",
        read_only=True,
        check=_check_mode,
        constraints='one of: ' + ', '.join(MODES),
    ),
    *delivery_specs(
        {
            'real_time_factor': "pacing by the log's stamps: log seconds per wall second; 1.0 = "
            'as recorded, 0 = as fast as delivery allows (nothing is lost either way) [-]',
            'publish_clock': "publish /clock with the log's stamps (as published, >= 0) [-]",
            'wait_for_subscribers': 'before the start, wait until every detection topic has at '
            'least this many subscribers (association node, recorder, ...) [-]',
            'wait_for_truth_subscribers': 'before the start, wait until /road/ground_truth has at '
            'least this many subscribers (scorer, recorder, ...) [-]',
            'ack_timeout': 'at the end, wait at most this long for every subscriber to '
            'acknowledge every message [s]',
            'keep_running': 'stay up after the last row of the log (the latched layout stays '
            'available) [-]',
        }
    ),
]


@dataclass(frozen=True)
class LogSourceConfig(DeliveryConfig):
    """Everything the node needs, from its parameters (read once at startup)."""

    log: str
    layout: str
    mode: str

    @staticmethod
    def from_values(v: dict[str, Any]) -> LogSourceConfig:
        for name, what in (('log', 'detections CSV'), ('layout', 'layout file')):
            if not v[name].strip():
                raise ParameterError(
                    f'parameter {name} is required: the path of the {what} '
                    f'(--ros-args -p {name}:=<path>)'
                )
        return LogSourceConfig(
            log=v['log'], layout=v['layout'], mode=v['mode'], **DeliveryConfig.values(v)
        )
