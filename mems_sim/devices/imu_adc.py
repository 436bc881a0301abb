"""The IMU's analog-to-digital converters: the static errors of each axis' ADC (IEEE Std
1241-2010 terms) as parameters, and the converters they build
(:func:`~mems_sim.hardware.converter.device_converters`, the model the stage's readout ADCs
use too). All errors 0 (the default): no converter, the ideal quantiser round(x / LSB)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from mems_sim.hardware.converter import device_converters, inl_shape_spec, part_seed
from mems_sim.params import ParamSpec


def _adc_error_specs(s: str) -> tuple[ParamSpec, ...]:
    """The static errors of sensor ``s``'s ADC, one converter per axis (IEEE Std
    1241-2010 terms; mems_sim.hardware.converter), all 0 by default: the ideal quantiser."""
    src = (
        "nominal part: 0 (an ideal quantiser). MEMS IMU datasheets specify the digital "
        "output, not the converter's static errors (from memory, unchecked)"
    )
    return (
        ParamSpec(
            f"{s}_adc_offset_lsb",
            0.0,
            "LSB",
            f"offset error V_os/Q of each {s} axis' ADC (positive: codes above the input). "
            "Any static error non-zero: the codes come from a converter model per axis",
            src,
            min=-256.0,
            max=256.0,
        ),
        ParamSpec(
            f"{s}_adc_gain_error",
            0.0,
            "-",
            f"relative gain error G - 1 of each {s} axis' ADC",
            src,
            min=-0.1,
            max=0.1,
        ),
        ParamSpec(
            f"{s}_adc_inl_lsb",
            0.0,
            "LSB",
            f"peak of the smooth INL bow of each {s} axis' ADC (shape: {s}_adc_inl_shape)",
            src,
            min=-16.0,
            max=16.0,
        ),
        inl_shape_spec(f"{s}_adc_inl_shape"),
        ParamSpec(
            f"{s}_adc_dnl_lsb",
            0.0,
            "LSB",
            f"standard deviation of the seeded code-width pattern DNL[k] of each {s} axis' "
            "ADC (each axis its own pattern, from adc_part_seed)",
            src,
            min=0.0,
            max=0.5,
        ),
        ParamSpec(
            f"{s}_adc_missing_codes",
            0,
            "-",
            f"number of interior codes of each {s} axis' ADC drawn to be missing (zero "
            "width; from adc_part_seed)",
            "nominal part: none (more are a fault)",
            min=0,
            max=2**20 - 2,
        ),
    )


#: The ADCs' static errors of both sensors and the part they are drawn for.
ADC_ERROR_SPECS: tuple[ParamSpec, ...] = (
    _adc_error_specs("gyro")
    + _adc_error_specs("accel")
    + (
        ParamSpec(
            "adc_part_seed",
            0,
            "-",
            "the converter part: seed of every axis' DNL pattern and missing-code draw "
            "(with the axis; used only when an ADC static error is non-zero)",
            "assumption: one part per seed",
            min=0,
            max=2**63 - 1,
        ),
    )
)


def axis_converters(p: Mapping[str, Any], s: str, bits: int, first: int) -> tuple | None:
    """Sensor ``s``'s converters, one per axis, with its ADC static errors (``{s}_adc_*`` of
    the IMU's parameters ``p``; None when all are 0), their patterns drawn for
    ``adc_part_seed`` and the axis (:func:`~mems_sim.hardware.converter.part_seed`, tag
    "imu_adc", channels ``first`` .. ``first`` + 2 of gyro_x..z, accel_x..z); ``bits`` [-],
    full scale ``{s}_lsb`` 2^(bits-1) [rad/s or m/s^2]."""
    seeds = [part_seed(p["adc_part_seed"], "imu_adc", first + j) for j in range(3)]
    full_scale = p[f"{s}_lsb"] * 2.0 ** (bits - 1)
    return device_converters(p, f"{s}_adc_", bits, full_scale, seeds)
