"""The stage's transimpedance readout: its electronic noise level and its ADC.

Electronic noise (never tuned to a result) is the sum of the documented physical sources
of the transimpedance readout, white over the ADC's Nyquist band B = fs/2 (brick-wall
anti-alias filter, no averaging across periods):

    S_y = 4 k T R_s + (i_n R_s)^2 + e_n^2 |1 + j 2 pi f R_s C_in|^2
    sigma_y^2 = (4 k T R_s + i_n^2 R_s^2) B + e_n^2 (B + (2 pi R_s C_in)^2 B^3 / 3)

(Johnson-Nyquist noise of R_s; the amplifier's current noise i_n through R_s and its
voltage noise e_n raised by the noise gain of the input capacitance C_in.) The ADC rounds
y / lsb to the nearest code, half to even, clipped to the signed 16-bit range.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

K_BOLTZMANN = 1.380649e-23  # J/K


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
