"""Physical parameter specifications shared by every device and node.

Each device module declares its parameters once, as a tuple of
:class:`ParamSpec` (name, default, SI unit, valid range, source), so that the
core can validate a configuration without ROS and the node layer can declare
ROS parameters with descriptors built from the same table.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np


class ParameterError(ValueError):
    """A parameter value outside its documented range or of the wrong type."""


@dataclass(frozen=True)
class Spread:
    """Manufacturing spread of a parameter: how one device of a batch differs from the
    nominal one.

    Attributes:
        kind: ``"uniform"`` (within +-width) or ``"normal"`` (standard deviation width).
        width: half-range or standard deviation, a fraction of the nominal value if
            ``relative`` (0.1 = +-10 %), else in the parameter's unit.
        relative: whether ``width`` is relative to the nominal value.
        source: where the spread comes from (datasheet, paper) or the stated assumption.
    """

    kind: str
    width: float
    relative: bool = True
    source: str = ""

    def __post_init__(self) -> None:
        if self.kind not in ("uniform", "normal") or not (self.width >= 0.0):
            raise ValueError(f"invalid spread {self.kind!r} +- {self.width!r}")

    def draw(self, nominal: float, rng: np.random.Generator) -> float:
        """One device's value around ``nominal``."""
        u = rng.uniform(-1.0, 1.0) if self.kind == "uniform" else rng.standard_normal()
        delta = self.width * u
        return nominal * (1.0 + delta) if self.relative else nominal + delta

    def text(self, unit: str) -> str:
        """Human-readable, e.g. ``+-10 % (uniform)``."""
        w = f"{100 * self.width:g} %" if self.relative else f"{self.width:g} {unit}"
        return f"{'+-' if self.kind == 'uniform' else 'sd '}{w} ({self.kind})"


@dataclass(frozen=True)
class TempCo:
    """Linear temperature coefficient of a parameter around a reference temperature:
    value(T) = value(T_ref) * (1 + coefficient (T - T_ref)) if ``relative`` (coefficient in
    1/K), else value(T_ref) + coefficient (T - T_ref) (coefficient in unit/K).

    Attributes:
        coefficient: 1/K (relative) or the parameter's unit per K.
        relative: whether the coefficient is relative.
        source: where it comes from (material property, datasheet, paper).
    """

    coefficient: float
    relative: bool = True
    source: str = ""

    def at(self, value: float, delta_k: float) -> float:
        """The value ``delta_k`` kelvin away from the reference temperature."""
        if self.relative:
            return value * (1.0 + self.coefficient * delta_k)
        return value + self.coefficient * delta_k

    def text(self, unit: str) -> str:
        """Human-readable, e.g. ``-30 ppm/K``."""
        if self.relative:
            return f"{self.coefficient * 1e6:+g} ppm/K"
        return f"{self.coefficient:+g} {unit}/K"


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
        max: largest allowed value (inclusive unless ``max_exclusive``).
        min_exclusive: True if ``min`` itself is not allowed.
        max_exclusive: True if ``max`` itself is not allowed.
        choices: allowed values for string parameters.
        spread: manufacturing spread (:class:`Spread`), where physics gives one.
        tempco: temperature coefficient (:class:`TempCo`), where physics gives one.
        realistic: the value of a real part under the ``realistic`` hardware profile
            (:func:`profile_specs`), where it differs from ``default`` (then the idealised
            device's value); None: the same under both profiles.
        realistic_source: where ``realistic`` comes from (datasheet, paper, assumption).
    """

    name: str
    default: Any
    unit: str
    description: str
    source: str = ""
    min: float | None = None
    max: float | None = None
    min_exclusive: bool = False
    max_exclusive: bool = False
    choices: tuple[str, ...] | None = None
    spread: Spread | None = None
    tempco: TempCo | None = None
    realistic: Any = None
    realistic_source: str = ""

    def __post_init__(self) -> None:
        if self.realistic is not None:
            try:
                self.validate(self.realistic)
            except ParameterError as exc:
                raise ValueError(f"realistic value of {self.name!r}: {exc}") from None

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
        right = ")" if (self.max is None or self.max_exclusive) else "]"
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
        high_bad = self.max is not None and (
            value >= self.max if self.max_exclusive else value > self.max
        )
        if low_bad or high_bad:
            raise ParameterError(
                f"parameter '{self.name}' = {value!r} is out of range: allowed {self.range_text()}"
            )
        return value


#: Hardware profiles: ``ideal`` (every real-part term at its idealised value, the devices of
#: the papers) and ``realistic`` (each term at the level its datasheet or paper gives).
HARDWARE_PROFILES: tuple[str, ...] = ("ideal", "realistic")

#: The ``hardware`` parameter of every emulator: the profile whose defaults it starts from.
HARDWARE_SPEC = ParamSpec(
    "hardware",
    "ideal",
    "-",
    "hardware profile of the defaults: 'ideal' (real-part terms off: the idealised device) or "
    "'realistic' (each term at its datasheet or paper level); a parameter set explicitly wins",
    "'ideal' reproduces the devices of the references bit for bit",
    choices=HARDWARE_PROFILES,
)


def profile_specs(specs: Iterable[ParamSpec], profile: str) -> tuple[ParamSpec, ...]:
    """``specs`` with the defaults of hardware ``profile`` (:data:`HARDWARE_PROFILES`):
    unchanged for ``ideal``; for ``realistic`` each spec's ``realistic`` value, where it has
    one, as its default (its source the ``realistic_source``).

    Raises:
        ParameterError: for an unknown profile.
    """
    profile = HARDWARE_SPEC.validate(profile)
    if profile == "ideal":
        return tuple(specs)
    return tuple(
        s
        if s.realistic is None
        else replace(s, default=s.realistic, source=s.realistic_source or s.source)
        for s in specs
    )


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


def draw_device(
    specs: Iterable[ParamSpec],
    values: Mapping[str, Any],
    device_seed: int | None = None,
    delta_k: float = 0.0,
    fixed: Iterable[str] = (),
) -> dict[str, Any]:
    """One device: ``values`` with every parameter that has a :class:`Spread` drawn around
    its value (``device_seed`` None or negative: the nominal device, nothing drawn) and
    every parameter with a :class:`TempCo` moved ``delta_k`` kelvin from its reference
    temperature. Names in ``fixed`` (values a user set explicitly) are left as given.

    Each parameter's draw depends only on the device seed and the parameter's name
    (``np.random.default_rng([seed, crc32(name)])``), so adding a parameter to a table
    does not change the others' draws. A drawn or temperature-moved value outside the
    parameter's range is clipped into it (a spread is a batch, not a fault).
    """
    out = dict(values)
    fixed = set(fixed)
    for spec in specs:
        if spec.name in fixed or spec.name not in out:
            continue
        value = out[spec.name]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            continue
        v = float(value)
        if spec.spread is not None and device_seed is not None and device_seed >= 0:
            rng = np.random.default_rng([int(device_seed), zlib.crc32(spec.name.encode())])
            v = spec.spread.draw(v, rng)
        if spec.tempco is not None and delta_k != 0.0:
            v = spec.tempco.at(v, delta_k)
        if spec.min is not None and v < spec.min:
            v = spec.min
        if spec.max is not None and v > spec.max:
            v = spec.max
        out[spec.name] = int(round(v)) if isinstance(spec.default, int) else v
    return out


# ----------------------------------------------------------------------------- materials
#: Relative temperature coefficient of the Young's modulus of silicon, about -60 ppm/K near
#: room temperature (Hopcroft, Nix & Kenny, "What is the Young's modulus of silicon?",
#: J. Microelectromech. Syst. 19(2), 2010); a flexure's stiffness is proportional to E.
SILICON_STIFFNESS_TEMPCO = TempCo(
    -60e-6,
    source="Young's modulus of silicon about -60 ppm/K (Hopcroft, Nix & Kenny, JMEMS 19(2) "
    "2010); stiffness proportional to E",
)
#: A resonance f = sqrt(k/m)/(2 pi) of a silicon flexure moves half as much: -30 ppm/K.
SILICON_RESONANCE_TEMPCO = TempCo(
    -30e-6,
    source="f proportional to sqrt(E), E of silicon about -60 ppm/K (Hopcroft, Nix & Kenny, "
    "JMEMS 19(2) 2010): -30 ppm/K",
)
#: Linear thermal expansion of silicon, 2.6e-6/K at 300 K (Okada & Tokumaru, J. Appl. Phys.
#: 56(2), 1984); a length of the structure (a gap, a comb's capacitance at fixed
#: proportions) scales with it.
SILICON_EXPANSION_TEMPCO = TempCo(
    2.6e-6,
    source="thermal expansion of silicon 2.6e-6/K at 300 K (Okada & Tokumaru, J. Appl. Phys. "
    "56(2) 1984); assumption: the length scales with the silicon",
)
#: Dynamic viscosity of air, Sutherland's law mu ~ T^1.5 / (T + 110.4 K): d ln mu / dT =
#: 1.5/T - 1/(T + 110.4 K) = +0.26 %/K at 300 K (White, Viscous Fluid Flow, 3rd ed., eq.
#: 1-36); squeeze-film and viscous damping are proportional to mu.
AIR_DAMPING_TEMPCO = TempCo(
    2.6e-3,
    source="air viscosity, Sutherland's law (White, Viscous Fluid Flow, eq. 1-36): "
    "+0.26 %/K at 300 K; assumption: the damping is gas damping, proportional to mu",
)
#: A quality factor limited by gas damping falls as the viscosity rises.
AIR_QUALITY_FACTOR_TEMPCO = TempCo(
    -2.6e-3,
    source="Q proportional to 1/mu, air viscosity +0.26 %/K at 300 K (Sutherland's law, "
    "White, Viscous Fluid Flow, eq. 1-36); assumption: gas damping dominates",
)
#: The device's own temperature in kelvin follows the temperature input one to one.
KELVIN_TEMPCO = TempCo(1.0, relative=False, source="the device's temperature: 1 K per K")


def batch_spread(width: float, what: str) -> Spread:
    """Uniform +-``width`` (relative) batch spread, its source the stated assumption ``what``."""
    return Spread("uniform", width, source=f"assumption: {what}")
