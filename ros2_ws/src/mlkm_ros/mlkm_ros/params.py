"""Declare a node's parameters from one table, with descriptors and validation.

Each parameter has a description with its unit, an optional range (shown by
``ros2 param describe``), a read-only flag for values a running node cannot apply, and an
optional check that returns the reason a value is refused. The same checks run for startup
values (``-p``, ``--params-file``) and for live ``ros2 param set`` calls; a refused startup
value raises :class:`ParameterError`, which the node's ``main`` turns into a clear message
and a nonzero exit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter

Check = Callable[[Any], str | None]


class ParameterError(ValueError):
    """A parameter value was refused; the message says which one and why."""


#: The bag tools' name for the same refusal.
ConfigError = ParameterError


@dataclass(frozen=True)
class ParamSpec:
    name: str
    default: Any
    description: str  # meaning and unit, e.g. 'road length [m]'
    low: float | None = None  # inclusive range, advertised in the descriptor
    high: float | None = None
    read_only: bool = False
    check: Check | None = None  # returns a reason when the value is refused
    constraints: str = ''  # free text for ``ros2 param describe``, e.g. the allowed choices

    def descriptor(self) -> ParameterDescriptor:
        desc = ParameterDescriptor(
            name=self.name,
            description=self.description,
            read_only=self.read_only,
            additional_constraints=self.constraints,
        )
        if self.low is not None and self.high is not None:
            if isinstance(self.default, bool):
                pass
            elif isinstance(self.default, int):
                desc.integer_range = [
                    IntegerRange(from_value=int(self.low), to_value=int(self.high), step=0)
                ]
            elif isinstance(self.default, float):
                desc.floating_point_range = [
                    FloatingPointRange(
                        from_value=float(self.low), to_value=float(self.high), step=0.0
                    )
                ]
        return desc

    def refuse(self, value: Any) -> str | None:
        if self.check is not None:
            return self.check(value)
        return None


def positive(value: float) -> str | None:
    return None if value > 0 else 'must be > 0'


def non_negative(value: float) -> str | None:
    return None if value >= 0 else 'must be >= 0'


def declare_parameters(
    node: Node,
    specs: Sequence[ParamSpec],
    on_change: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Declare ``specs`` on ``node``; return {name: value} of the startup values.

    Registers one on-set callback that refuses a value with its spec's reason. Accepted live
    changes are passed to ``on_change`` (after they are set). Raises ParameterError when a
    startup value is refused.
    """
    by_name = {s.name: s for s in specs}

    def validate(params) -> SetParametersResult:
        for p in params:
            spec = by_name.get(p.name)
            if spec is None:
                continue
            reason = spec.refuse(p.value)
            if reason:
                return SetParametersResult(
                    successful=False, reason=f'{p.name}={p.value!r} refused: {reason}'
                )
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(validate)
    values: dict[str, Any] = {}
    for spec in specs:
        try:
            param = node.declare_parameter(spec.name, spec.default, spec.descriptor())
        except ParameterException as exc:
            raise ParameterError(_explain(spec, exc)) from None
        values[spec.name] = param.value
    if on_change is not None:

        def post(params) -> None:
            changed = {p.name: p.value for p in params if p.name in by_name}
            if changed:
                on_change(changed)

        node.add_post_set_parameters_callback(post)
    return values


def _explain(spec: ParamSpec, exc: ParameterException) -> str:
    text = exc.args[0] if exc.args else str(exc)
    return f'{text} (parameter {spec.name}: {spec.description})'


# Single declarations, for nodes whose parameters are read once at start-up.


def declare_number(
    node: Node,
    name: str,
    default: float,
    description: str,
    low: float,
    high: float,
    *,
    integer: bool = False,
    read_only: bool = True,
) -> float:
    """Declare a numeric parameter (int or float accepted on the command line); validate it."""
    descriptor = ParameterDescriptor(
        description=description, read_only=read_only, dynamic_typing=True
    )
    if integer:
        descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high))]
    else:
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(low), to_value=float(high))
        ]
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
    node.declare_parameter(
        name, default, ParameterDescriptor(description=description, read_only=True)
    )
    return bool(node.get_parameter(name).value)


def declare_string(node: Node, name: str, default: str, description: str) -> str:
    node.declare_parameter(
        name, default, ParameterDescriptor(description=description, read_only=True)
    )
    return str(node.get_parameter(name).value)


def declare_strings(node: Node, name: str, description: str) -> tuple[str, ...]:
    """A read-only string-array parameter, empty unless set (``-p name:='[a, b]'``)."""
    node.declare_parameter(
        name,
        Parameter.Type.STRING_ARRAY,
        ParameterDescriptor(description=description, read_only=True),
    )
    value = node.get_parameter_or(name, None)
    if value is None or value.type_ == Parameter.Type.NOT_SET:
        return ()
    if value.type_ != Parameter.Type.STRING_ARRAY:
        raise ConfigError(f'parameter {name} must be a list of strings, got {value.value!r}')
    return tuple(v for v in value.value if v)


@dataclass(frozen=True)
class StartupParam:
    """One row of a table of read-only parameters read once at start-up: its kind follows
    its default (a number, integer when ``integer``; a bool; a string; ``()`` for a string
    list, empty unless set), validated by the single declarations above."""

    name: str
    default: Any
    description: str  # meaning and unit, e.g. 'graph poll period [s]'
    low: float = -math.inf  # inclusive range of a number
    high: float = math.inf
    integer: bool = False

    def declare(self, node: Node) -> Any:
        if isinstance(self.default, tuple):
            return declare_strings(node, self.name, self.description)
        if isinstance(self.default, bool):
            return declare_bool(node, self.name, self.default, self.description)
        if isinstance(self.default, str):
            return declare_string(node, self.name, self.default, self.description)
        return declare_number(
            node,
            self.name,
            self.default,
            self.description,
            self.low,
            self.high,
            integer=self.integer,
        )


def declare_startup(node: Node, table: Sequence[StartupParam]) -> dict[str, Any]:
    """Declare every row of ``table`` on ``node``; {name: value}. Raises ConfigError when a
    value is refused."""
    return {row.name: row.declare(node) for row in table}
