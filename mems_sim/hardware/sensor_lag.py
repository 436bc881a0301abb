"""A device's temperature sensor: first-order thermal lag, offset, white noise, resolution.

The sensing element follows the temperature T of the part it measures (degC) through a
first-order lag of time constant tau, tau dy/dt = T - y, discretised exactly for an input
held over each sample period (the zero-order-hold equivalent Phi = exp(F Ts),
Gamma = integral_0^Ts exp(F s) G ds of Franklin, Powell & Workman, Digital Control of
Dynamic Systems, 3rd ed., Ch. 4, with F = -1/tau, G = 1/tau)::

    y[k+1] = a y[k] + (1 - a) T[k],   a = exp(-Ts / tau),   y[0] = T[0]

(the initial state is the first input unless one is given; tau = 0 is no lag, y[k] = T[k]).
The reading adds an offset and white noise and is rounded to the resolution::

    r[k] = T_0 + q round((y[k] + offset + sigma n[k] - T_0) / q),   n[k] ~ N(0, 1)

with q the resolution (K/LSB; q = 0: no rounding) and T_0 the temperature of code 0.

Streaming: the state is carried between calls, so blocks give the bits of one call (the lag
runs in ``scipy.signal.lfilter``, a sequential recursion; the noise draws one standard
normal per sample whether the noise is on or off). No transcendental function of an array:
a is one scalar ``math.exp``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.signal import lfilter

from mems_sim.params import ParameterError, ParamSpec, Spread, draw_device, resolve

__all__ = [
    "SAMPLE_PERIOD_SPEC",
    "TEMPERATURE_SENSOR_SPECS",
    "LaggedTemperatureSensor",
    "TemperatureBlock",
    "draw_temperature_sensor",
    "lag_coefficient",
    "ramp_lag_k",
    "temperature_sensor_values",
]

#: Sample period of the temperature readings.
SAMPLE_PERIOD_SPEC = ParamSpec(
    "temp_sensor_sample_period_s",
    0.01,
    "s",
    "period Ts of the temperature readings (the device's output data period)",
    "the device's output data rate (e.g. 100 Hz)",
    min=0.0,
    max=1.0e4,
    min_exclusive=True,
)

TEMPERATURE_SENSOR_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "temp_sensor_time_constant_s",
        1.0,
        "s",
        "first-order lag tau of the sensing element behind the measured part (0: no lag)",
        "assumption: the thermal time constant between a MEMS die and the ASIC die carrying "
        "the sensor in a stacked LGA package, of the order of a second; IMU datasheets "
        "(LSM6DSM, ICM-42688-P, BMI088) give none",
        min=0.0,
        max=1.0e5,
        spread=Spread(
            "uniform",
            0.2,
            source="assumption: +-20 % package-to-package (die attach and mould thickness)",
        ),
    ),
    ParamSpec(
        "temp_sensor_noise_k",
        0.01,
        "K",
        "white noise of each reading, standard deviation sigma",
        "assumption: a few LSB of the LSM6DSM's 1/256 K; the datasheets give no noise figure",
        min=0.0,
        max=10.0,
    ),
    ParamSpec(
        "temp_sensor_offset_k",
        0.0,
        "K",
        "offset of the reading from the sensing element's temperature",
        "nominal device 0; batch: LSM6DSM datasheet, temperature offset Toff -15 to +15 degC",
        min=-50.0,
        max=50.0,
        spread=Spread(
            "uniform",
            15.0,
            relative=False,
            source="LSM6DSM datasheet: temperature offset Toff between -15 and +15 degC",
        ),
    ),
    ParamSpec(
        "temp_sensor_resolution_k",
        1.0 / 256.0,
        "K/LSB",
        "resolution q of the reading, one code (0: no rounding)",
        "LSM6DSM datasheet: 256 LSB/degC (ICM-42688-P: 132.48 LSB/degC; BMI088: 0.125 K/LSB)",
        min=0.0,
        max=10.0,
    ),
    ParamSpec(
        "temp_sensor_zero_code_c",
        25.0,
        "degC",
        "temperature T_0 of code 0 (the codes count LSBs from it)",
        "LSM6DSM and ICM-42688-P datasheets: output 0 at 25 degC (BMI088: 23 degC)",
        min=-100.0,
        max=200.0,
    ),
)


def temperature_sensor_values(params: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Defaults of :data:`TEMPERATURE_SENSOR_SPECS` updated with validated ``params``.

    Raises:
        ParameterError: for an unknown name or an out-of-range value.
    """
    return resolve(TEMPERATURE_SENSOR_SPECS, params)


def draw_temperature_sensor(
    values: Mapping[str, Any], device_seed: int | None, fixed: Iterable[str] = ()
) -> dict[str, Any]:
    """One sensor of a batch: offset and lag drawn within their spreads
    (:func:`~mems_sim.params.draw_device`); ``device_seed`` None or negative: ``values``."""
    return draw_device(TEMPERATURE_SENSOR_SPECS, values, device_seed, fixed=fixed)


def lag_coefficient(sample_period_s: float, time_constant_s: float) -> float:
    """Pole a = Phi = exp(-Ts / tau) of the zero-order-hold equivalent (Franklin, Powell &
    Workman, Ch. 4), Gamma = 1 - a; 0 for tau = 0.

    Args:
        sample_period_s: Ts, s.
        time_constant_s: tau, s.
    """
    if time_constant_s == 0.0:
        return 0.0
    return math.exp(-sample_period_s / time_constant_s)


def ramp_lag_k(sample_period_s: float, time_constant_s: float, rate_k_per_s: float) -> float:
    """Steady-state lag T[k] - y[k] of the discretised sensor on a ramp of ``rate_k_per_s``
    (K/s): r Ts / (1 - a) = r tau + r Ts / 2 + O(r Ts^2 / tau), the continuous lag r tau
    plus half a held sample. From y[k+1] = a y[k] + (1 - a) T[k] with y = T - L.

    Args:
        sample_period_s: Ts, s.
        time_constant_s: tau, s (0: no lag, 0 K).
        rate_k_per_s: ramp rate r, K/s.
    """
    if time_constant_s == 0.0:
        return 0.0
    a = lag_coefficient(sample_period_s, time_constant_s)
    return rate_k_per_s * sample_period_s / (1.0 - a)


@dataclass(frozen=True)
class TemperatureBlock:
    """A block of temperature readings.

    Attributes:
        lagged_c: y[k], the sensing element's temperature (the truth behind the reading), degC.
        reading_c: r[k], the reading, degC.
        codes: round((reading - T_0) / q) as int64, or None without rounding (q = 0).
    """

    lagged_c: np.ndarray
    reading_c: np.ndarray
    codes: np.ndarray | None


class LaggedTemperatureSensor:
    """The temperature sensor of one device, streamed in blocks.

    Args:
        sample_period_s: Ts, s.
        params: overrides of :data:`TEMPERATURE_SENSOR_SPECS` (validated).
        initial_c: the sensing element's temperature before the first sample, degC (None:
            the first input).

    Raises:
        ParameterError: for an invalid period or parameter.
    """

    def __init__(
        self,
        sample_period_s: float,
        params: Mapping[str, Any] | None = None,
        initial_c: float | None = None,
    ) -> None:
        self.period_s = SAMPLE_PERIOD_SPEC.validate(sample_period_s)
        self.values = temperature_sensor_values(params)
        self.a = lag_coefficient(self.period_s, self.values["temp_sensor_time_constant_s"])
        self._state = None if initial_c is None else _check_temperature(initial_c, "initial_c")

    def measure(self, temperature_c: np.ndarray, rng: np.random.Generator) -> TemperatureBlock:
        """Readings of the next block.

        Args:
            temperature_c: T[k], the measured part's temperature per sample, degC.
            rng: the device's seeded generator (one standard normal per sample).

        Raises:
            ValueError: for a temperature that is not finite or below absolute zero.
        """
        temp = np.asarray(temperature_c, dtype=float)
        if temp.ndim != 1:
            raise ValueError(f"temperature_c must be 1-D, got shape {temp.shape}")
        _check_temperature(temp, "temperature_c")
        lagged = self._lag(temp)
        v = self.values
        noisy = (lagged + v["temp_sensor_offset_k"]) + v["temp_sensor_noise_k"] * (
            rng.standard_normal(temp.size)
        )
        q, zero = v["temp_sensor_resolution_k"], v["temp_sensor_zero_code_c"]
        if q == 0.0:
            return TemperatureBlock(lagged, noisy, None)
        steps = np.round((noisy - zero) / q)
        return TemperatureBlock(lagged, zero + q * steps, steps.astype(np.int64))

    def _lag(self, temp: np.ndarray) -> np.ndarray:
        """y[k] of y[k+1] = a y[k] + (1 - a) T[k] from the carried state (the
        zero-order-hold equivalent); tau = 0: y = T."""
        if temp.size == 0:
            return temp.copy()
        if self.values["temp_sensor_time_constant_s"] == 0.0:
            self._state = float(temp[-1])
            return temp.copy()
        state = float(temp[0]) if self._state is None else self._state
        y, zf = lfilter([0.0, 1.0 - self.a], [1.0, -self.a], temp, zi=[state])
        self._state = float(zf[0])
        return y


def _check_temperature(temp: float | np.ndarray, name: str) -> float | np.ndarray:
    arr = np.asarray(temp, dtype=float)
    if arr.size and not (np.all(np.isfinite(arr)) and np.all(arr >= -273.15)):
        raise ParameterError(f"{name} must be finite and at least -273.15 degC")
    return float(arr) if arr.ndim == 0 else arr
