"""What the two nodes share that touches rclpy: QoS conversion, type import, parameters."""

from __future__ import annotations

import importlib
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.topic_endpoint_info import TopicEndpointInfo

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
        p.qos_profile.reliability == ReliabilityPolicy.RELIABLE for p in publishers)
    latched = bool(publishers) and all(
        p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publishers)
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
        raise ImportError(f'message type {type_name} is not available '
                          f'(is its package built and sourced?): {exc}') from None


@dataclass(frozen=True)
class TopicSelection:
    """Which topics to take: explicit names, include regex, exclude regex (re.search)."""

    topics: tuple[str, ...] = ()
    include_regex: str = ''
    exclude_regex: str = ''
    include_hidden: bool = False

    def __post_init__(self) -> None:
        for label, pattern in (('include_regex', self.include_regex),
                               ('exclude_regex', self.exclude_regex)):
            try:
                re.compile(pattern)
            except re.error as exc:
                raise ValueError(f'{label} {pattern!r} is not a valid regular expression: '
                                 f'{exc}') from None

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


class ConfigError(ValueError):
    """A parameter value the node cannot work with; the message says which and why."""


# Exit statuses shared by both executables.
EXIT_OK = 0
EXIT_REFUSED = 1  # the bag (or output) cannot be used; nothing played / recorded
EXIT_BAD_PARAMETER = 2  # a parameter value is invalid
EXIT_PARTIAL = 3  # bag_player: the bag is damaged; what was readable was played


def declare_number(node: Node, name: str, default: float, description: str, low: float,
                   high: float, *, integer: bool = False, read_only: bool = True) -> float:
    """Declare a numeric parameter (int or float accepted on the command line); validate it."""
    descriptor = ParameterDescriptor(description=description, read_only=read_only,
                                     dynamic_typing=True)
    if integer:
        descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high))]
    else:
        descriptor.floating_point_range = [FloatingPointRange(from_value=float(low),
                                                              to_value=float(high))]
    kind = 'an integer' if integer else 'a number'
    refusal = f'expected {kind} in [{low:g}, {high:g}] ({description})'
    try:
        node.declare_parameter(name, default, descriptor)
    except ParameterException as exc:
        raise ConfigError(f'parameter {name} refused: {refusal}; rclpy: {exc}') from None
    value = node.get_parameter(name).value
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    if ok and integer and isinstance(value, float):
        ok = value.is_integer()
    if not ok or not math.isfinite(value) or not low <= value <= high:
        raise ConfigError(f'parameter {name}={value!r} refused: {refusal}')
    return int(value) if integer else float(value)


def declare_bool(node: Node, name: str, default: bool, description: str) -> bool:
    node.declare_parameter(name, default,
                           ParameterDescriptor(description=description, read_only=True))
    return bool(node.get_parameter(name).value)


def declare_string(node: Node, name: str, default: str, description: str) -> str:
    node.declare_parameter(name, default,
                           ParameterDescriptor(description=description, read_only=True))
    return str(node.get_parameter(name).value)


def declare_strings(node: Node, name: str, description: str) -> tuple[str, ...]:
    """A read-only string-array parameter, empty unless set (``-p name:='[a, b]'``)."""
    node.declare_parameter(name, Parameter.Type.STRING_ARRAY,
                           ParameterDescriptor(description=description, read_only=True))
    value = node.get_parameter_or(name, None)
    if value is None or value.type_ == Parameter.Type.NOT_SET:
        return ()
    if value.type_ != Parameter.Type.STRING_ARRAY:
        raise ConfigError(f'parameter {name} must be a list of strings, got {value.value!r}')
    return tuple(v for v in value.value if v)
