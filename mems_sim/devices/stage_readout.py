"""The stage's transimpedance readout: its electronic noise level and its ADC.

Electronic noise (never tuned to a result) is the sum of the documented physical sources
of the transimpedance readout, white over the ADC's Nyquist band B = fs/2 (brick-wall
anti-alias filter, no averaging across periods):

    S_y = 4 k T R_s + (i_n R_s)^2 + e_n^2 |1 + j 2 pi f R_s C_in|^2
    sigma_y^2 = (4 k T R_s + i_n^2 R_s^2) B + e_n^2 (B + (2 pi R_s C_in)^2 B^3 / 3)

(Johnson-Nyquist noise of R_s; the amplifier's current noise i_n through R_s and its
voltage noise e_n raised by the noise gain of the input capacitance C_in.) The ADC rounds
y / lsb to the nearest code, half to even, clipped to the signed 16-bit range.

ADC static errors (all off by default): with any of ``adc_offset_lsb``, ``adc_gain_error``,
``adc_inl_lsb``, ``adc_dnl_lsb``, ``adc_missing_codes`` non-zero, each channel's codes come
from its own :class:`~mems_sim.hardware.converter.Converter` (IEEE Std 1241-2010 transition
table: G T[k]/Q + V_os/Q = k - 1/2 + INL[k], DNL[k] = G W[k]/Q - 1), the same offset, gain
and INL bow on every channel and a DNL pattern (and missing-code draw) of its own, seeded by
:func:`adc_seed` from ``device_seed`` and the channel index. Its clipped count is the
converter's over-range flag (the input beyond half a code outside the code range).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from mems_sim.hardware.converter import (
    STATIC_ERRORS,
    Converter,
    device_converters,
    part_seed,
)

K_BOLTZMANN = 1.380649e-23  # J/K

#: The stage's ADC static-error parameters and the converter parameter each one sets.
ADC_ERRORS: dict[str, str] = {f"adc_{name}": conv for name, conv in STATIC_ERRORS.items()}


def readout_noise_std(p: Mapping[str, Any]) -> float:
    """RMS output noise of one transimpedance channel per sample [V] (module doc formula).

    ``p``: the stage's parameters (``sample_rate_hz`` [Hz], ``r_s_ohm`` [Ohm],
    ``readout_temperature_k`` [K], ``amp_current_noise`` [A/sqrt(Hz)],
    ``amp_voltage_noise`` [V/sqrt(Hz)], ``input_capacitance_f`` [F], optionally
    ``readout_noise_scale`` [-])."""
    B = p["sample_rate_hz"] / 2.0
    rs = p["r_s_ohm"]
    thermal = 4.0 * K_BOLTZMANN * p["readout_temperature_k"] * rs * B
    current = (p["amp_current_noise"] * rs) ** 2 * B
    k = 2.0 * math.pi * rs * p["input_capacitance_f"]
    voltage = p["amp_voltage_noise"] ** 2 * (B + k * k * B**3 / 3.0)
    return p.get("readout_noise_scale", 1.0) * math.sqrt(thermal + current + voltage)


def requantize(y: np.ndarray, inv_lsb: float, code_max: float) -> tuple[np.ndarray, int]:
    """The ADC of the stage's fused readout kernel on given readout voltages ``y`` (n, 4)
    [V]: codes rint(y / lsb) clipped to [-code_max - 1, code_max] (the same floats), and the
    number of clipped samples. ``inv_lsb`` [1/V], ``code_max`` [-]."""
    q = np.rint(y * inv_lsb)
    sat = int(np.count_nonzero((q > code_max) | (q < -code_max)))
    return np.clip(q, -code_max - 1.0, code_max).astype(np.int32), sat


def adc_seed(device_seed: int, channel: int) -> int:
    """Seed [-] of channel ``channel``'s converter (its DNL pattern and missing codes):
    :func:`~mems_sim.hardware.converter.part_seed` of ``device_seed``, tag "stage_adc" and
    the channel, so every channel of a device has its own part and every device its own
    four."""
    return part_seed(device_seed, "stage_adc", channel)


def channel_converters(p: Mapping[str, Any], n_channels: int) -> tuple[Converter, ...] | None:
    """One converter per channel with the stage's ADC static errors (module doc), or None
    when every error is 0: then the fused kernel's ideal ADC is the stage's ADC.

    ``p``: the stage's parameters (``adc_bits`` [bits], ``adc_full_scale_v`` [V],
    ``device_seed`` [-] and the :data:`ADC_ERRORS` [LSB, -], ``adc_inl_shape``);
    ``n_channels`` [-]."""
    seeds = [adc_seed(p["device_seed"], c) for c in range(n_channels)]
    return device_converters(p, "adc_", int(p["adc_bits"]), float(p["adc_full_scale_v"]), seeds)


def convert_channels(converters: tuple[Converter, ...], y: np.ndarray) -> tuple[np.ndarray, int]:
    """Codes (n, nch) int32 of readout voltages ``y`` (n, nch) [V], column c by
    ``converters[c]`` (:meth:`~mems_sim.hardware.converter.Converter.quantize`), and the
    number of over-range samples."""
    codes = np.empty(y.shape, np.int32)
    sat = 0
    for c, conv in enumerate(converters):
        codes[:, c], over = conv.quantize(y[:, c])
        sat += int(np.count_nonzero(over))
    return codes, sat
