"""What the recorder and the player share that touches rclpy: QoS conversion, type import,
the start of their node and their exit statuses."""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.topic_endpoint_info import TopicEndpointInfo

from mlkm_ros import lifecycle
from mlkm_ros.params import ConfigError
from rosbag_mcap.definitions import split_type_name
from rosbag_mcap.storage import INFINITE_NS, QosSpec


def spec_from_profile(profile: QoSProfile) -> QosSpec:
    """An endpoint's QoS as rosbag2 records it (enum names, durations in ns)."""

    def ns(duration: Duration) -> int:
        return min(int(duration.nanoseconds), INFINITE_NS)

    return QosSpec(
        history=profile.history.name.lower(),
        depth=int(profile.depth),
        reliability=profile.reliability.name.lower(),
        durability=profile.durability.name.lower(),
        deadline=ns(profile.deadline),
        lifespan=ns(profile.lifespan),
        liveliness=profile.liveliness.name.lower(),
        liveliness_lease_duration=ns(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


def _policy(enum_type, name: str):
    try:
        value = enum_type[name.upper()]
    except KeyError:
        return enum_type.SYSTEM_DEFAULT
    return enum_type.SYSTEM_DEFAULT if value.name == 'UNKNOWN' else value


def profile_from_spec(spec: QosSpec) -> QoSProfile:
    """An rclpy QoSProfile for a QosSpec ('unknown' policies become system default)."""
    history = _policy(HistoryPolicy, spec.history)
    depth = spec.depth if spec.depth > 0 else 1
    if history == HistoryPolicy.KEEP_ALL:
        depth = 0
    return QoSProfile(
        history=history,
        depth=depth,
        reliability=_policy(ReliabilityPolicy, spec.reliability),
        durability=_policy(DurabilityPolicy, spec.durability),
        deadline=Duration(nanoseconds=spec.deadline),
        lifespan=Duration(nanoseconds=spec.lifespan),
        liveliness=_policy(LivelinessPolicy, spec.liveliness),
        liveliness_lease_duration=Duration(nanoseconds=spec.liveliness_lease_duration),
        avoid_ros_namespace_conventions=spec.avoid_ros_namespace_conventions,
    )


def request_profile(publishers: Sequence[TopicEndpointInfo]) -> QoSProfile:
    """What the recorder requests, adapted to the offers (rosbag2's rule) with keep_all.

    Reliable when every publisher offers reliable, transient_local when every publisher
    offers it (so latched messages published before the recorder started are received).
    History keep_all: the recorder never drops a message that reached it.
    """
    reliable = bool(publishers) and all(
        p.qos_profile.reliability == ReliabilityPolicy.RELIABLE for p in publishers
    )
    latched = bool(publishers) and all(
        p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publishers
    )
    return QoSProfile(
        history=HistoryPolicy.KEEP_ALL,
        depth=0,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


def import_message_type(type_name: str) -> type:
    """The Python class of 'pkg/msg/Type'; ImportError with the reason otherwise."""
    try:
        package, namespace, name = split_type_name(type_name)
    except ValueError as exc:
        raise ImportError(str(exc)) from None
    try:
        module = importlib.import_module(f'{package}.{namespace}')
        return getattr(module, name)
    except (ImportError, AttributeError) as exc:
        raise ImportError(
            f'message type {type_name} is not available (is its package built and sourced?): {exc}'
        ) from None


@dataclass(frozen=True)
class TopicSelection:
    """Which topics to take: explicit names, include regex, exclude regex (re.search)."""

    topics: tuple[str, ...] = ()
    include_regex: str = ''
    exclude_regex: str = ''
    include_hidden: bool = False

    def __post_init__(self) -> None:
        for label, pattern in (
            ('include_regex', self.include_regex),
            ('exclude_regex', self.exclude_regex),
        ):
            try:
                re.compile(pattern)
            except re.error as exc:
                raise ValueError(
                    f'{label} {pattern!r} is not a valid regular expression: {exc}'
                ) from None

    def selects(self, name: str) -> bool:
        if self.exclude_regex and re.search(self.exclude_regex, name):
            return False
        if name in self.topics:
            return True
        if not self.include_hidden and any(t.startswith('_') for t in name.split('/') if t):
            return False
        if not self.topics and not self.include_regex:
            return True
        return bool(self.include_regex) and re.search(self.include_regex, name) is not None


# Exit statuses shared by both executables.
EXIT_OK = 0
EXIT_REFUSED = 1  # the bag (or output) cannot be used; nothing played / recorded
EXIT_BAD_PARAMETER = 2  # a parameter value is invalid
EXIT_PARTIAL = 3  # bag_player: the bag is damaged; what was readable was played
EXIT_WRITE_FAILED = 4  # bag_recorder: writing failed (disk full); the bag keeps what was written


def start_tool[NodeT](
    name: str,
    factory: Callable[[], NodeT],
    args: list[str] | None,
    refused: type[BaseException],
    text: str,
) -> tuple[NodeT | None, int]:
    """rclpy.init and the construction of a bag tool's node (mlkm_ros.lifecycle.start_node):
    a refused parameter exits EXIT_BAD_PARAMETER, ``refused`` (the bag cannot be used)
    EXIT_REFUSED with ``<name>: <text><reason>``."""
    lifecycle.init_rclpy(args)
    return lifecycle.start_node(
        name,
        factory,
        [
            ((ConfigError, ParameterException), '', EXIT_BAD_PARAMETER),
            ((refused,), text, EXIT_REFUSED),
        ],
    )
