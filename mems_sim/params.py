"""Physical parameter specifications shared by every device and node.

Each device module declares its parameters once, as a tuple of
:class:`ParamSpec` (name, default, SI unit, valid range, source), so that the
core can validate a configuration without ROS and the node layer can declare
ROS parameters with descriptors built from the same table.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any


class ParameterError(ValueError):
    """A parameter value outside its documented range or of the wrong type."""


@dataclass(frozen=True)
class ParamSpec:
    """One physical parameter.

    Attributes:
        name: parameter name (ROS parameter name as well).
        default: default value, in ``unit``.
        unit: SI unit string (``"rad/s"``, ``"m/s^2/sqrt(Hz)"``, ``"-"``).
        description: one line: what it is.
        source: where the default comes from (document, table, equation).
        min: smallest allowed value (inclusive unless ``min_exclusive``).
        max: largest allowed value (inclusive).
        min_exclusive: True if ``min`` itself is not allowed.
        choices: allowed values for string parameters.
    """

    name: str
    default: Any
    unit: str
    description: str
    source: str = ""
    min: float | None = None
    max: float | None = None
    min_exclusive: bool = False
    choices: tuple[str, ...] | None = None

    def range_text(self) -> str:
        """Human-readable allowed range, e.g. ``(0, 1e3] s``."""
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if isinstance(self.default, bool):
            return "true or false"
        if isinstance(self.default, str):
            return "any string"
        lo = "-inf" if self.min is None else repr(self.min)
        hi = "inf" if self.max is None else repr(self.max)
        left = "(" if (self.min is None or self.min_exclusive) else "["
        right = ")" if self.max is None else "]"
        return f"{left}{lo}, {hi}{right} {self.unit}".rstrip()

    def validate(self, value: Any) -> Any:
        """Return ``value`` (converted to the default's type) or raise.

        Raises:
            ParameterError: naming the parameter, the value and the range.
        """
        if self.choices is not None:
            if value not in self.choices:
                raise ParameterError(
                    f"parameter '{self.name}' = {value!r} is invalid: allowed {self.range_text()}"
                )
            return value
        if isinstance(self.default, bool):
            if not isinstance(value, bool):
                raise ParameterError(
                    f"parameter '{self.name}' = {value!r} is invalid: expected true/false"
                )
            return value
        if isinstance(self.default, int) and not isinstance(self.default, bool):
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or (isinstance(value, float) and not value.is_integer())
            ):
                raise ParameterError(
                    f"parameter '{self.name}' = {value!r} is invalid: expected an integer "
                    f"in {self.range_text()}"
                )
            value = int(value)
        elif isinstance(self.default, float):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ParameterError(
                    f"parameter '{self.name}' = {value!r} is invalid: expected a number "
                    f"in {self.range_text()}"
                )
            value = float(value)
            if not math.isfinite(value):
                raise ParameterError(
                    f"parameter '{self.name}' = {value!r} is invalid: must be finite, "
                    f"allowed {self.range_text()}"
                )
        else:
            return value
        low_bad = self.min is not None and (
            value <= self.min if self.min_exclusive else value < self.min
        )
        high_bad = self.max is not None and value > self.max
        if low_bad or high_bad:
            raise ParameterError(
                f"parameter '{self.name}' = {value!r} is out of range: allowed {self.range_text()}"
            )
        return value


def spec_table(specs: Iterable[ParamSpec]) -> dict[str, ParamSpec]:
    """Index specs by name, refusing duplicates."""
    table: dict[str, ParamSpec] = {}
    for s in specs:
        if s.name in table:
            raise ValueError(f"duplicate parameter spec {s.name!r}")
        table[s.name] = s
    return table


def resolve(
    specs: Iterable[ParamSpec], overrides: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """Defaults of ``specs`` updated with validated ``overrides``.

    Raises:
        ParameterError: for an unknown name or an invalid value.
    """
    table = spec_table(specs)
    values = {name: s.default for name, s in table.items()}
    for name, value in (overrides or {}).items():
        if name not in table:
            raise ParameterError(
                f"unknown parameter '{name}': known are {', '.join(sorted(table))}"
            )
        values[name] = table[name].validate(value)
    return values
