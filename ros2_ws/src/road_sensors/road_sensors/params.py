"""Declare a node's parameters from one table, with descriptors and validation.

Each parameter has a description with its unit, an optional range (shown by
``ros2 param describe``), a read-only flag for values a running node cannot apply, and an
optional check that returns the reason a value is refused. The same checks run for startup
values (``-p``, ``--params-file``) and for live ``ros2 param set`` calls; a refused startup
value raises :class:`ParameterError`, which the node's ``main`` turns into a clear message
and a nonzero exit.
"""

from __future__ import annotations

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

Check = Callable[[Any], str | None]


class ParameterError(ValueError):
    """A parameter value was refused; the message says which one and why."""


@dataclass(frozen=True)
class ParamSpec:
    name: str
    default: Any
    description: str  # meaning and unit, e.g. 'road length [m]'
    low: float | None = None  # inclusive range, advertised in the descriptor
    high: float | None = None
    read_only: bool = False
    check: Check | None = None  # returns a reason when the value is refused

    def descriptor(self) -> ParameterDescriptor:
        desc = ParameterDescriptor(name=self.name, description=self.description,
                                   read_only=self.read_only)
        if self.low is not None and self.high is not None:
            if isinstance(self.default, bool):
                pass
            elif isinstance(self.default, int):
                desc.integer_range = [IntegerRange(from_value=int(self.low),
                                                   to_value=int(self.high), step=0)]
            elif isinstance(self.default, float):
                desc.floating_point_range = [FloatingPointRange(
                    from_value=float(self.low), to_value=float(self.high), step=0.0)]
        return desc

    def refuse(self, value: Any) -> str | None:
        if self.check is not None:
            return self.check(value)
        return None


def positive(value: float) -> str | None:
    return None if value > 0 else 'must be > 0'


def non_negative(value: float) -> str | None:
    return None if value >= 0 else 'must be >= 0'


def declare_parameters(node: Node, specs: Sequence[ParamSpec],
                       on_change: Callable[[dict[str, Any]], None] | None = None
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
                    successful=False, reason=f'{p.name}={p.value!r} refused: {reason}')
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
