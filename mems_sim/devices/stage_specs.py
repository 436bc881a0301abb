"""Parameter table of the 2-DOF micro-stage model (:mod:`mems_sim.devices.stage`).

Every parameter of the stage, its capacitive readout, the LDV reference and the drive with
unit, range and source (:class:`~mems_sim.params.ParamSpec`; Chen 2018, chapter 3);
docs/stage.md.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Mapping
from typing import Any

import numpy as np

from mems_sim.devices.stage_readout import ADC_ERRORS
from mems_sim.hardware.converter import DEVICE_MAX_BITS, inl_shape_spec
from mems_sim.params import ParameterError, ParamSpec, Spread, spec_table

__all__ = ["STAGE_SPECS", "validate_params", "draw_spread"]

#: Largest ADC resolution with static errors: each channel's converter table holds 2^N + 1
#: floats (and its construction a few times that), 8 MB at 20 bits, 134 MB at 24.
ADC_ERROR_MAX_BITS = DEVICE_MAX_BITS

STAGE_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "sample_rate_hz",
        625.0e3,
        "Hz",
        "stage sample rate (DAC, ADC, LDV)",
        "Chen 2018 sec. 3.5.2: saved at 625 kHz",
        min=0.0,
        max=1.0e8,
        min_exclusive=True,
    ),
    ParamSpec(
        "natural_freq_hz",
        1714.5,
        "Hz",
        "tilt-mode natural frequency wn/2pi",
        "Chen 2018 Table 3.3",
        min=1.0,
        max=1.0e6,
    ),
    ParamSpec(
        "damping_ratio",
        0.005,
        "-",
        "tilt-mode damping ratio zeta (nominal; one device of the batch is drawn +-10 % "
        "around it from device_seed unless idealised or set explicitly)",
        "Table 3.3; spread: assumption +-10 % (uniform): air/squeeze-film damping follows "
        "gap and viscosity, which vary from device to device",
        min=0.0,
        max=0.7,
        min_exclusive=True,
        spread=Spread("uniform", 0.10, source="assumption: +-10 % batch spread of zeta"),
    ),
    ParamSpec(
        "b_c",
        3782.5,
        "rad/s^2/V",
        "input gain b_c of eq. (33)",
        "Table 3.3",
        min=0.0,
        max=1.0e8,
        min_exclusive=True,
    ),
    ParamSpec(
        "off_axis_coupling",
        0.001,
        "-",
        "off-axis tilt / main-axis tilt",
        "sec. 3.3.1: < 0.1 % with compensation [17]",
        min=0.0,
        max=1.0,
    ),
    ParamSpec(
        "neutral_gap_m",
        19.2e-6,
        "m",
        "neutral plate distance D_n at T_ref",
        "Table 3.3",
        min=1.0e-6,
        max=1.0e-3,
    ),
    ParamSpec(
        "gap_tempco_per_k",
        4.0e-4,
        "1/K",
        "relative change of D_n per kelvin",
        "assumption (paper re-identifies D_n at 35.7 C, gives no value)",
        min=-1.0e-2,
        max=1.0e-2,
    ),
    ParamSpec(
        "freq_tempco_per_k",
        -30e-6,
        "1/K",
        "relative change of wn per kelvin (0 when idealised)",
        "silicon: Young's modulus about -60 ppm/K near room temperature (Hopcroft, Nix & "
        "Kenny, J. Microelectromech. Syst. 19(2) 2010), wn ~ sqrt(E): -30 ppm/K. Chen 2018 "
        "gives wn at room temperature only (Table 3.3)",
        min=-1e-2,
        max=1e-2,
    ),
    ParamSpec(
        "b_c_tempco_per_k",
        1.0e-3,
        "1/K",
        "relative change of the actuator gain b_c per kelvin (0 when idealised)",
        "soft PZT: d31 rises with temperature near room temperature, order +0.1 %/K "
        "(domain-wall contribution; Zhang, Wang, Kim & Cross, J. Appl. Phys. 75(1) 454, "
        "1994); the exact value is an assumption. Chen 2018 gives b_c at room temperature "
        "only (Table 3.3) and re-identifies only D_n, eta (sec. 3.5.3)",
        min=-1e-1,
        max=1e-1,
    ),
    ParamSpec(
        "readout_gain_tempco_per_k",
        25e-6,
        "1/K",
        "relative change of the transimpedance R_s (so of eta = -V_bias R_s, eq. 44) per "
        "kelvin (0 when idealised)",
        "thin-film feedback resistor, TCR +-25 ppm/K class (Vishay TNPW e3 datasheet); the "
        "sign is an assumption. Chen 2018 re-identifies eta at 35.7 C (sec. 3.6.3)",
        min=-1e-2,
        max=1e-2,
    ),
    ParamSpec(
        "stator_offset_y_m",
        0.0,
        "m",
        "misregistration of the stator layer against the rotor along Y (nominal 0; one "
        "device of the batch is drawn +-0.5 um around it from device_seed unless idealised "
        "or set explicitly): makes the off-axis leakage first order (eqs. 56-57)",
        "assumption: +-0.5 um (uniform) lithographic/bonding overlay; Table A.2 is symmetric in Y",
        min=-20e-6,
        max=20e-6,
        spread=Spread("uniform", 0.5e-6, relative=False, source="assumption: +-0.5 um overlay"),
    ),
    ParamSpec(
        "idealised",
        False,
        "-",
        "true: the drift-free stage (no temperature coefficient on wn, b_c, eta; nominal "
        "zeta and stator registration, nothing drawn); D_n still moves with gap_tempco",
        "study switch: the stage of Chen 2018 Table 3.3 at every temperature",
    ),
    ParamSpec(
        "ref_temperature_c",
        22.9,
        "degC",
        "reference temperature T_ref",
        "Table 3.2 (room temperature run)",
        min=-60.0,
        max=150.0,
    ),
    ParamSpec(
        "temperature_c",
        22.9,
        "degC",
        "stage temperature",
        "Table 3.2: 22.9 / 35.7 C",
        min=-60.0,
        max=150.0,
    ),
    ParamSpec(
        "w_sa_m",
        400e-6,
        "m",
        "width of large stator electrode W_SA",
        "Table A.2",
        min=1e-6,
        max=1e-2,
    ),
    ParamSpec(
        "w_sb_m",
        320e-6,
        "m",
        "width of small stator electrode W_SB",
        "Table A.2",
        min=1e-6,
        max=1e-2,
    ),
    ParamSpec(
        "w_r_m",
        520e-6,
        "m",
        "width of each rotor electrode W_R (>= stator: the overlap is the stator area)",
        "Table A.2",
        min=1e-6,
        max=1e-2,
    ),
    ParamSpec("w_m", 2780e-6, "m", "width of sensing stage W", "Table A.2", min=1e-5, max=0.1),
    ParamSpec("d_w_m", 195e-6, "m", "distance between stators D_W", "Table A.2", min=0.0, max=1e-2),
    ParamSpec("eps_r", 1.0, "-", "relative permittivity", "sec. 3.4.3 (air)", min=1.0, max=100.0),
    ParamSpec(
        "v_bias",
        10.0,
        "V",
        "sensing bias V_bias (eq. 29)",
        "assumption: V_bias R_s = |eta| of Table 3.3",
        min=0.0,
        max=200.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "r_s_ohm",
        2.40752e6,
        "ohm",
        "transimpedance feedback resistance R_s (eq. 28)",
        "|eta| / V_bias, Table 3.3",
        min=1.0,
        max=1.0e10,
    ),
    ParamSpec(
        "channel_gain_mismatch",
        0.01,
        "-",
        "std of the per-channel relative gain "
        "mismatch of the readout (fixed per channel from the seed)",
        "assumption: 1 % resistor/amplifier tolerance",
        min=0.0,
        max=0.2,
    ),
    ParamSpec(
        "device_seed",
        2018,
        "-",
        "seed of the manufacturing tolerances (channel gain "
        "mismatch): fixed per emulated device, independent of the run seed",
        "deterministic: manufacturing spread is drawn from its own device seed",
        min=0,
        max=2**62,
    ),
    ParamSpec(
        "feedthrough_cap_f",
        50e-15,
        "F",
        "mean parasitic drive-to-sense capacitance "
        "C_ft (channels 1A..2B use 0.8, 1.1, 0.9, 1.2 times it)",
        "assumption; sec. 3.4.2 (feedthrough from parasitic capacitance)",
        min=0.0,
        max=1e-9,
    ),
    ParamSpec(
        "amp_voltage_noise",
        7.0e-9,
        "V/sqrt(Hz)",
        "amplifier input voltage noise e_n",
        "typical JFET-input op-amp",
        min=0.0,
        max=1e-5,
    ),
    ParamSpec(
        "amp_current_noise",
        1.5e-15,
        "A/sqrt(Hz)",
        "amplifier input current noise i_n",
        "typical JFET-input op-amp",
        min=0.0,
        max=1e-9,
    ),
    ParamSpec(
        "input_capacitance_f",
        5.0e-12,
        "F",
        "total capacitance at the amplifier input (sensor, pads, op-amp input)",
        "assumption",
        min=0.0,
        max=1e-8,
    ),
    ParamSpec(
        "readout_temperature_k",
        296.0,
        "K",
        "temperature of R_s (thermal noise)",
        "room temperature (0 allowed for noise-free studies)",
        min=0.0,
        max=500.0,
    ),
    ParamSpec(
        "readout_noise_scale",
        1.0,
        "-",
        "factor on the RMS electronic noise of the "
        "readout (1: the physical sources above; other values only for sensitivity "
        "studies, Fig. 3.16)",
        "study knob",
        min=0.0,
        max=1000.0,
    ),
    ParamSpec("adc_bits", 16, "bits", "ADC resolution", "assumption", min=4, max=24),
    ParamSpec(
        "adc_full_scale_v",
        0.02,
        "V",
        "ADC full scale (+-)",
        "assumption: fits signal + feedthrough at 1.3 V drive",
        min=1e-6,
        max=100.0,
    ),
    ParamSpec(
        "adc_offset_lsb",
        0.0,
        "LSB",
        "offset error V_os/Q of each channel's ADC (IEEE Std 1241-2010 independently based "
        "offset; positive: codes above the input). Any static error non-zero: the codes come "
        "from a converter model per channel (mems_sim.hardware.converter)",
        "nominal part: 0 (an ideal quantiser). A 16-bit SAR part is specified at a few LSB "
        "(from memory, unchecked)",
        min=-256.0,
        max=256.0,
    ),
    ParamSpec(
        "adc_gain_error",
        0.0,
        "-",
        "relative gain error G - 1 of each channel's ADC (positive: codes grow faster than the "
        "input)",
        "nominal part: 0. A 16-bit SAR part is specified at order 1e-3 of full scale (from "
        "memory, unchecked)",
        min=-0.1,
        max=0.1,
    ),
    ParamSpec(
        "adc_inl_lsb",
        0.0,
        "LSB",
        "peak of the smooth INL bow of each channel's ADC (shape: adc_inl_shape)",
        "nominal part: 0. A 16-bit SAR part is specified at +-1 to +-3 LSB INL (from memory, "
        "unchecked)",
        min=-16.0,
        max=16.0,
    ),
    inl_shape_spec("adc_inl_shape"),
    ParamSpec(
        "adc_dnl_lsb",
        0.0,
        "LSB",
        "standard deviation of the seeded code-width pattern DNL[k]; each channel has its own "
        "pattern, drawn from device_seed and the channel index",
        "nominal part: 0. A 16-bit SAR part is specified at +-0.5 to +-1 LSB DNL max, no "
        "missing codes (from memory, unchecked)",
        min=0.0,
        max=0.5,
    ),
    ParamSpec(
        "adc_missing_codes",
        0,
        "-",
        "number of interior codes of each channel's ADC drawn to be missing (zero width; "
        "drawn from device_seed and the channel index)",
        "nominal part: none (a datasheet guarantees no missing codes; more are a fault)",
        min=0,
        max=2**24 - 2,
    ),
    ParamSpec(
        "drive_noise_density",
        1.0e-6,
        "V/sqrt(Hz)",
        "drive amplifier output voltage noise (process noise of the stage)",
        "assumption",
        min=0.0,
        max=1e-2,
    ),
    ParamSpec(
        "safe_tilt_rad",
        0.005,
        "rad",
        "largest tilt amplitude the schedule may ask (gap closes at D_n/(W/2) = 0.0138 rad)",
        "sec. 3.5.2: +-0.005 rad",
        min=0.0,
        max=0.05,
        min_exclusive=True,
    ),
    ParamSpec(
        "bias_switching",
        True,
        "-",
        "switch the sensing bias on/off on alternate drive "
        "periods (feedthrough cancellation); false: always on",
        "sec. 3.5.4",
    ),
    ParamSpec("feedthrough_enabled", True, "-", "model the drive feedthrough", "sec. 3.4.2"),
    ParamSpec(
        "ldv_noise_std",
        0.02,
        "rad/s",
        "LDV angular-rate noise per sample",
        "assumption (Polytec OFV-534 + VD-09 20 mm/s/V class)",
        min=0.0,
        max=10.0,
    ),
    ParamSpec(
        "ldv_delay_s", 6.9e-6, "s", "LDV output delay", "sec. 3.5.4: ~6.9 us", min=0.0, max=1e-3
    ),
    ParamSpec(
        "ldv_bias",
        0.05,
        "rad/s",
        "LDV constant bias",
        "sec. 3.5.4 (constant bias)",
        min=-10.0,
        max=10.0,
    ),
)


def validate_params(p: Mapping[str, Any]) -> None:
    """Cross-parameter checks: drive frequency content below Nyquist, stators fit, W_R >= W_SA,
    missing ADC codes fewer than the interior codes, ADC static errors at most
    :data:`ADC_ERROR_MAX_BITS` bits."""
    if p["natural_freq_hz"] >= p["sample_rate_hz"] / 2:
        raise ParameterError(
            f"parameter 'natural_freq_hz' = {p['natural_freq_hz']!r} is out of "
            f"range: must be below sample_rate_hz/2 = {p['sample_rate_hz'] / 2!r}"
        )
    if 2 * (p["w_sa_m"] + p["d_w_m"] + p["w_sb_m"]) > p["w_m"]:
        raise ParameterError(
            f"parameter 'w_m' = {p['w_m']!r} is out of range: must hold two "
            "stator pairs, >= 2 (W_SA + D_W + W_SB)"
        )
    if p["adc_bits"] > ADC_ERROR_MAX_BITS and any(p[k] != 0 for k in ADC_ERRORS):
        raise ParameterError(
            f"parameter 'adc_bits' = {p['adc_bits']!r} is out of range: with ADC static errors "
            f"at most {ADC_ERROR_MAX_BITS} (each channel's converter holds a table of 2^N "
            "transitions)"
        )
    if p["adc_missing_codes"] > 2 ** p["adc_bits"] - 2:
        raise ParameterError(
            f"parameter 'adc_missing_codes' = {p['adc_missing_codes']!r} is out of range: a "
            f"{p['adc_bits']}-bit ADC has {2 ** p['adc_bits'] - 2} interior codes"
        )
    if p["w_r_m"] < p["w_sa_m"]:
        raise ParameterError(
            f"parameter 'w_r_m' = {p['w_r_m']!r} is out of range: the rotor "
            f"must cover the stator, >= w_sa_m = {p['w_sa_m']!r}"
        )


def draw_spread(p: Mapping[str, Any], fixed: set[str] | frozenset[str] = frozenset()) -> dict:
    """One device of the batch: every parameter of :data:`STAGE_SPECS` with a
    :class:`~mems_sim.params.Spread` (``damping_ratio`` +-10 %, ``stator_offset_y_m``
    +-0.5 um) drawn around its value in ``p`` from ``device_seed`` and the parameter's
    name (``np.random.default_rng([device_seed, crc32(name)])``: adding a parameter does
    not change the others' draws), names in ``fixed`` left as given; clipped into range."""
    out = dict(p)
    for spec in spec_table(STAGE_SPECS).values():
        if spec.spread is None or spec.name in fixed:
            continue
        rng = np.random.default_rng([int(p["device_seed"]), zlib.crc32(spec.name.encode())])
        v = spec.spread.draw(float(p[spec.name]), rng)
        lo = -math.inf if spec.min is None else spec.min
        hi = math.inf if spec.max is None else spec.max
        if spec.min_exclusive and v <= lo:
            v = float(p[spec.name])
        out[spec.name] = min(max(v, lo), hi)
    return out
