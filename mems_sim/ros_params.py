"""Declare ROS parameters from the core's ParamSpec tables and validate them.

Each device keeps one table of :class:`~mems_sim.params.ParamSpec` (unit,
range, source). This module turns it into ROS parameter declarations with
descriptors (description with unit, range and source, read-only after start)
and validates the values the node was started with, so that an invalid value
is refused with the parameter, the value and the allowed range.
"""
from __future__ import annotations

from typing import Any, Iterable

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node

from mems_sim.params import ParameterError, ParamSpec


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """ParameterDescriptor carrying unit, range and source in its text."""
    text = f"{spec.description} [{spec.unit}]"
    constraints = f"allowed {spec.range_text()}"
    if spec.source:
        text += f"; source: {spec.source}"
    return ParameterDescriptor(description=text, additional_constraints=constraints,
                               read_only=True)


def declare_specs(node: Node, specs: Iterable[ParamSpec]) -> dict[str, Any]:
    """Declare every spec on ``node`` and return the validated values.

    Raises:
        ParameterError: naming the first invalid parameter, its value and range.
    """
    values: dict[str, Any] = {}
    for spec in specs:
        try:
            param = node.declare_parameter(spec.name, spec.default, descriptor(spec))
            value = param.value
        except Exception as exc:  # rclpy refuses a value of the wrong type
            raise ParameterError(
                f"parameter '{spec.name}' is invalid ({exc}): allowed {spec.range_text()}"
            ) from None
        values[spec.name] = spec.validate(value)
    return values
