"""How a simulated source delivers its messages: the parameters ``sensor_sim`` and
``sumo_sensors`` share (pacing, /clock, the waits for subscribers and acknowledgements,
staying up) and the part of their frozen configs that holds them (read by
:class:`road_sensors.source.SensorSource`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from mlkm_ros.params import ParamSpec, non_negative


@dataclass(frozen=True)
class DeliveryConfig:
    """The delivery settings every source's frozen config carries (its base class)."""

    real_time_factor: float
    publish_clock: bool
    wait_for_subscribers: int
    wait_for_truth_subscribers: int
    wait_for_subscriptions: int
    wait_timeout: float
    start_delay: float
    ack_timeout: float
    keep_running: bool

    @staticmethod
    def values(values: dict[str, Any]) -> dict[str, Any]:
        """The delivery parameters among a node's parameter ``values``."""
        return {f.name: values[f.name] for f in fields(DeliveryConfig)}


#: What the descriptions of both sources say alike.
_WAIT_TIMEOUT = 'give up waiting for subscribers after this long and fail; 0 = wait forever [s]'
_START_DELAY = (
    'extra pause after the subscribers matched, before the first message: a count met says '
    'the source matched them, and a volatile subscriber drops what arrives before it has '
    'matched the source in turn [s]'
)


def delivery_specs(text: dict[str, str]) -> list[ParamSpec]:
    """The delivery parameters (names, defaults, ranges, checks) with a source's own
    descriptions: ``text[name]`` in its words (passage or SUMO time, episodes or not)."""
    return [
        ParamSpec('real_time_factor', 0.0, text['real_time_factor'], 0.0, 1e6, check=non_negative),
        ParamSpec('publish_clock', False, text['publish_clock'], read_only=True),
        ParamSpec(
            'wait_for_subscribers', 1, text['wait_for_subscribers'], 0, 1000, read_only=True
        ),
        ParamSpec(
            'wait_for_truth_subscribers',
            0,
            text['wait_for_truth_subscribers'],
            0,
            1000,
            read_only=True,
        ),
        ParamSpec(
            'wait_for_subscriptions',
            0,
            'before the start, also wait until the detection topics count this many '
            'subscriptions together (shards of a road: each subscribes to its own stations and '
            'its margins, so no single count per topic tells that all are there) [-]',
            0,
            10_000_000,
            read_only=True,
        ),
        ParamSpec('wait_timeout', 60.0, _WAIT_TIMEOUT, 0.0, 1e9, read_only=True),
        ParamSpec('start_delay', 1.0, _START_DELAY, 0.0, 1e6, read_only=True),
        ParamSpec('ack_timeout', 60.0, text['ack_timeout'], 0.0, 1e9, read_only=True),
        ParamSpec('keep_running', False, text['keep_running'], read_only=True),
    ]
