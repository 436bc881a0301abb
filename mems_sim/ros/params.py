"""Declare ROS parameters from the core's ParamSpec tables and validate them.

Each device keeps one table of :class:`~mems_sim.params.ParamSpec` (unit,
range, source). This module turns it into ROS parameter declarations with
descriptors and guards them for the life of the node:

* the descriptor carries the description with unit and source, the allowed range in
  words (``additional_constraints``, with "set at start" for the parameters the node
  reads only when it starts) and, for numbers with a range, ``floating_point_range`` or
  ``integer_range`` (step 0; an unbounded side is +-inf or the int64 limit), so that
  ``ros2 param describe`` and the DescribeParameters service show it and rclpy enforces it;
* a whole number given for a float parameter (``-p realtime_factor:=200`` on the command
  line, an INTEGER through the SetParameters service) is accepted and stored as a double;
* the values the node was started with are validated with :meth:`ParamSpec.validate`, so
  that an invalid value is refused with the parameter, the value and the allowed range
  (:class:`~mems_sim.params.ParameterError`);
* at runtime, a set request is validated the same way, and a parameter the node reads only
  at start is refused with a reason that says so (it is not ``read_only`` in the
  descriptor: rclpy would then refuse before the range is checked).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from mems_sim.params import ParameterError, ParamSpec, spec_table

INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1


def is_float_spec(spec: ParamSpec) -> bool:
    """True for a real-valued parameter (float default, no choices)."""
    return isinstance(spec.default, float) and spec.choices is None


def is_int_spec(spec: ParamSpec) -> bool:
    """True for an integer parameter (int default that is not a bool, no choices)."""
    return (
        isinstance(spec.default, int)
        and not isinstance(spec.default, bool)
        and spec.choices is None
    )


def _int_bound(value: float | None, fallback: int, rounding) -> int:
    return fallback if value is None else max(INT64_MIN, min(INT64_MAX, int(rounding(value))))


def descriptor(spec: ParamSpec, *, runtime: bool = False) -> ParameterDescriptor:
    """ParameterDescriptor of ``spec``: unit, range and source in its text, the numeric range
    as ``floating_point_range`` / ``integer_range``; "set at start" unless ``runtime``."""
    text = f"{spec.description} [{spec.unit}]"
    if spec.source:
        text += f"; source: {spec.source}"
    when = "can be changed while the node runs" if runtime else "set at start"
    desc = ParameterDescriptor(
        description=text, additional_constraints=f"allowed {spec.range_text()}; {when}"
    )
    desc.type = Parameter.Type.from_parameter_value(spec.default).value
    if is_float_spec(spec):
        desc.floating_point_range = [
            FloatingPointRange(
                from_value=-math.inf if spec.min is None else float(spec.min),
                to_value=math.inf if spec.max is None else float(spec.max),
                step=0.0,
            )
        ]
    elif is_int_spec(spec):
        low = _int_bound(spec.min, INT64_MIN, math.ceil)
        if spec.min_exclusive and spec.min is not None and float(spec.min).is_integer():
            low += 1
        high = _int_bound(spec.max, INT64_MAX, math.floor)
        if spec.max_exclusive and spec.max is not None and float(spec.max).is_integer():
            high -= 1
        desc.integer_range = [IntegerRange(from_value=low, to_value=high, step=0)]
    return desc


def _start_descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """Descriptor for the declaration: any type for float specs (a whole number is a valid
    double), no range (the value is then checked by :meth:`ParamSpec.validate`)."""
    text = descriptor(spec)
    desc = ParameterDescriptor(
        description=text.description, additional_constraints=text.additional_constraints
    )
    desc.dynamic_typing = is_float_spec(spec)
    return desc


class ParameterGuard:
    """Runtime checks of the declared specs of one node (rclpy parameter callbacks).

    ``values`` is the dict :func:`declare_specs` returned; it is kept up to date with the
    accepted changes, and ``on_change(name, value)`` is called after each.
    """

    def __init__(
        self,
        node: Node,
        specs: Iterable[ParamSpec],
        values: dict[str, Any],
        runtime: Iterable[str] = (),
        on_change: Callable[[str, Any], None] | None = None,
    ) -> None:
        self.table = spec_table(specs)
        self.values = values
        self.runtime = frozenset(runtime)
        unknown = self.runtime - set(self.table)
        if unknown:
            raise KeyError(f"runtime parameters without a spec: {sorted(unknown)}")
        self.on_change = on_change
        node.add_pre_set_parameters_callback(self.as_double)
        node.add_on_set_parameters_callback(self.check)
        node.add_post_set_parameters_callback(self.apply)

    def as_double(self, parameters: list[Parameter]) -> list[Parameter]:
        """A whole number for a float spec becomes a double (before rclpy checks the type)."""
        out = []
        for p in parameters:
            spec = self.table.get(p.name)
            if spec is not None and is_float_spec(spec) and p.type_ == Parameter.Type.INTEGER:
                p = Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            out.append(p)
        return out

    def check(self, parameters: list[Parameter]) -> SetParametersResult:
        """Refuse a value out of its spec, or a change of a parameter read at start."""
        for p in parameters:
            spec = self.table.get(p.name)
            if spec is None:
                continue
            try:
                value = spec.validate(p.value)
            except ParameterError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
            if p.name not in self.runtime and value != self.values[p.name]:
                return SetParametersResult(
                    successful=False,
                    reason=f"parameter '{p.name}' is read at start (set at start): "
                    f"restart the node to change it from {self.values[p.name]!r} to {value!r}",
                )
        return SetParametersResult(successful=True)

    def apply(self, parameters: list[Parameter]) -> None:
        """Store the accepted values and tell the node."""
        for p in parameters:
            spec = self.table.get(p.name)
            if spec is None:
                continue
            value = spec.validate(p.value)
            changed = value != self.values[p.name]
            self.values[p.name] = value
            if changed and self.on_change is not None:
                self.on_change(p.name, value)


def declare_specs(
    node: Node,
    specs: Iterable[ParamSpec],
    *,
    runtime: Iterable[str] = (),
    on_change: Callable[[str, Any], None] | None = None,
) -> dict[str, Any]:
    """Declare every spec on ``node``, validate the values, guard later changes.

    Args:
        node: the node.
        specs: its parameter table(s).
        runtime: names of the parameters that may be changed while the node runs;
            every other one is refused at runtime as "read at start".
        on_change: called with (name, new value) after a runtime change was accepted.

    Returns:
        The validated values (kept up to date with runtime changes).

    Raises:
        ParameterError: naming the first invalid parameter, its value and range.
    """
    specs = tuple(specs)
    runtime = frozenset(runtime)
    values: dict[str, Any] = {}
    for spec in specs:
        try:
            param = node.declare_parameter(spec.name, spec.default, _start_descriptor(spec))
        except Exception as exc:  # rclpy refuses a value of the wrong type
            raise ParameterError(
                f"parameter '{spec.name}' is invalid ({exc}): allowed {spec.range_text()}"
            ) from None
        values[spec.name] = spec.validate(param.value)
    for spec in specs:
        # the final descriptor (numeric range, static type); a whole number given for a
        # float parameter does not have its type, so the validated double replaces it
        value = Parameter(spec.name, value=values[spec.name]).get_parameter_value()
        node.set_descriptor(spec.name, descriptor(spec, runtime=spec.name in runtime), value)
    ParameterGuard(node, specs, values, runtime, on_change)
    return values
