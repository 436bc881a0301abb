"""Parameter table of the IMU error model (:mod:`mems_sim.devices.imu`) and its presets.

Every parameter of the gyro, the accelerometer and their deterministic and stochastic
error terms with unit, range and source (:class:`~mems_sim.params.ParamSpec`): Petkov &
Slavov's stochastic terms (ADIS16350, converted to SI, the conversions in each ``source``),
and the presets "adis16350" and "icm42688p" (datasheet values and tolerances); docs/imu.md.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable, Mapping
from dataclasses import replace
from typing import Any

from mems_sim.devices.imu_adc import ADC_ERROR_SPECS
from mems_sim.devices.imu_motion_specs import AXES, ENVIRONMENT_SPECS, VIBRATION_SPECS
from mems_sim.hardware.flicker import flicker_specs
from mems_sim.params import ParameterError, ParamSpec, Spread, draw_device, resolve

__all__ = [
    "G0",
    "DEG",
    "COMMON_SPECS",
    "GYRO_SPECS",
    "ACCEL_SPECS",
    "IMU_SPECS",
    "ERROR_SPECS",
    "FLICKER_SPECS",
    "LATENCY_SPEC",
    "ENVIRONMENT_SPECS",
    "VIBRATION_SPECS",
    "PRESET_SPEC",
    "PRESETS",
    "PRESETS_NAMES",
    "T_REF_C",
    "AXES",
    "SENSORS",
    "SENSOR_UNITS",
    "imu_specs",
    "imu_values",
    "draw_imu_device",
]

G0 = 9.80665  # standard gravity, m/s^2 (g -> m/s^2)
DEG = math.pi / 180.0  # deg -> rad
_FS_PAPER = 100.0  # ADIS16350 sample rate used by the paper, Hz
_DT_PAPER = 1.0 / _FS_PAPER  # 0.01 s

# --- defaults, converted to SI (the conversions are spelled out in `source`) ---------------
# Gyro (Petkov Sec. 3)
_GYRO_BIAS = -0.1027 * DEG
_GYRO_B = 1.55e-2 * DEG
_GYRO_T = 120.0
_GYRO_N = 0.581188 * DEG * math.sqrt(_DT_PAPER)
# Gyro RRW.  The paper's discrete model (7)-(8), rrw(k+1) = rrw(k) + dT*K*w(k)
# with sigma_w = 5 at dT = 0.01 s, has increments of std K*5*dT = K*5*sqrt(dT)*sqrt(dT)
# -> an Allan RRW coefficient of K*5*sqrt(dT) = K/2.  A random walk whose Allan
# coefficient is K (the paper's own Allan figure) needs sigma_w = 1/sqrt(dT) = 10.
# We implement the latter: increments of std K*sqrt(dT).
_GYRO_K = 9e-4 * DEG
_GYRO_LSB = 0.07326 * DEG
# Accelerometer (Petkov Sec. 4)
_ACC_B = 0.325e-3 * G0
_ACC_T = 80.0
_ACC_N = 5.57178e-3 * G0 * math.sqrt(_DT_PAPER)
# Accelerometer random walk.  The paper prints K = 0.206 m/s^2/sqrt(h) =
# 3.43e-3 m/s^2/sqrt(s).  That is inconsistent with its own eq. (9) budget:
# total 5.62452e-3 g, white 5.57178e-3 g and B = 0.325 mg leave
# sigma_rrw = sqrt(5.62452^2 - 5.57178^2 - 0.325^2) mg = 0.70 mg for the random walk
# over the 10,000 s record.  A random walk of Allan coefficient K has an rms of
# K*sqrt(T_rec/6) about its record mean (= 40.8 s^0.5 * K for T_rec = 10,000 s):
# K = 3.43e-3 gives 0.14 m/s^2 = 14 mg (20x the budget); K = 3.43e-4 realised
# through the paper's eqs. (7)-(8) with sigma_omega = 5 (= K/2, see the gyro note)
# gives 40.8 * 1.72e-4 = 7.0e-3 m/s^2 = 0.71 mg, matching the budget.  (The gyro
# budget, sigma_rrw = sqrt(0.581614^2 - 0.0155^2 - 0.581188^2) = 0.0160 deg/s,
# agrees in the same way: 40.8 * 9e-4/2 = 0.018 deg/s.)  The printed value is
# therefore read as a decimal-place misprint: K = 0.0206 m/s^2/sqrt(h), and we
# realise it as an Allan coefficient (increments of std K*sqrt(dT)).
_ACC_K = 0.0206 / 60.0
_ACC_LSB = 2.522e-3 * G0

COMMON_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "sample_rate_hz",
        100.0,
        "Hz",
        "output data rate fs of both sensors",
        "Petkov Sec. 3: ADIS16350 measured with fs = 100 Hz",
        min=0.0,
        max=1.0e5,
        min_exclusive=True,
    ),
    ParamSpec(
        "bits",
        14,
        "-",
        "ADC resolution (signed two's-complement codes)",
        "ADIS16350 datasheet: 14-bit gyro and accelerometer outputs",
        min=2,
        max=32,
    ),
)

GYRO_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "gyro_bias",
        _GYRO_BIAS,
        "rad/s",
        "constant bias (turn-on offset), every axis",
        "Petkov Sec. 3: -0.1027 deg/s * pi/180 = -1.79245e-3 rad/s",
        min=-1.0,
        max=1.0,
    ),
    ParamSpec(
        "gyro_bias_instability",
        _GYRO_B,
        "rad/s",
        "Gauss-Markov bias instability B = stationary std of x",
        "Petkov Sec. 3: B = 1.55e-2 deg/s (sigma_x = B) * pi/180 = 2.70526e-4 rad/s",
        min=0.0,
        max=1.0,
    ),
    ParamSpec(
        "gyro_correlation_time",
        _GYRO_T,
        "s",
        "Gauss-Markov correlation time T, eq. (3)",
        "Petkov Sec. 3: T = 120 s (from Fig. 3)",
        min=0.0,
        max=1.0e7,
        min_exclusive=True,
    ),
    ParamSpec(
        "gyro_noise_density",
        _GYRO_N,
        "rad/s/sqrt(Hz)",
        "angle random walk N (white-rate density); per-sample std N*sqrt(fs)",
        "Petkov eq. (9): sigma_arw = 0.581188 deg/s per sample at fs = 100 Hz -> "
        "N = 0.581188 deg/s * sqrt(0.01 s) * pi/180 = 1.01437e-3 rad/s/sqrt(Hz) "
        "(the paper's Allan value N = 5.75e-2 deg/sqrt(s) is 1.1 % lower)",
        min=0.0,
        max=1.0,
    ),
    ParamSpec(
        "gyro_random_walk",
        _GYRO_K,
        "rad/s/sqrt(s)",
        "rate random walk K; increments of std K*sqrt(dT)",
        "Petkov Sec. 3 Allan value K = 9e-4 deg/s/sqrt(s) * pi/180 = 1.5708e-5 "
        "rad/s/sqrt(s) (the paper's eq. (7)-(8) with sigma_omega = 5 realises only K/2)",
        min=0.0,
        max=1.0,
    ),
    ParamSpec(
        "gyro_lsb",
        _GYRO_LSB,
        "rad/s",
        "ADC resolution (one code)",
        "ADIS16350 datasheet: 0.07326 deg/s/LSB * pi/180 = 1.27863e-3 rad/s",
        min=0.0,
        max=10.0,
        min_exclusive=True,
    ),
)

ACCEL_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "accel_bias",
        0.0,
        "m/s^2",
        "constant bias (turn-on offset), every axis",
        "Petkov Sec. 4 reports none: 0",
        min=-100.0,
        max=100.0,
    ),
    ParamSpec(
        "accel_bias_instability",
        _ACC_B,
        "m/s^2",
        "Gauss-Markov bias instability B = stationary std of x",
        "Petkov Sec. 4: B = 0.325 mg * 9.80665e-3 = 3.18716e-3 m/s^2",
        min=0.0,
        max=10.0,
    ),
    ParamSpec(
        "accel_correlation_time",
        _ACC_T,
        "s",
        "Gauss-Markov correlation time T, eq. (3)",
        "Petkov Sec. 4: T = 80 s",
        min=0.0,
        max=1.0e7,
        min_exclusive=True,
    ),
    ParamSpec(
        "accel_noise_density",
        _ACC_N,
        "m/s^2/sqrt(Hz)",
        "velocity random walk N (white density); per-sample std N*sqrt(fs)",
        "Petkov Sec. 4: sigma_vrw = 5.57178e-3 g per sample at 100 Hz -> "
        "N = 5.57178e-3 * 9.80665 * sqrt(0.01 s) = 5.46405e-3 m/s^2/sqrt(Hz) "
        "(the paper's Allan N = 0.294 m/s/sqrt(h) = 4.9e-3 m/s^2/sqrt(Hz) is 11 % lower)",
        min=0.0,
        max=10.0,
    ),
    ParamSpec(
        "accel_random_walk",
        _ACC_K,
        "m/s^2/sqrt(s)",
        "acceleration random walk K; increments of std K*sqrt(dT)",
        "Petkov Sec. 4 prints 0.206 m/s^2/sqrt(h); read as 0.0206 m/s^2/sqrt(h) / 60 = "
        "3.43333e-4 m/s^2/sqrt(s) to agree with the paper's eq. (9) noise budget "
        "(decimal-place misprint, see module comment)",
        min=0.0,
        max=10.0,
    ),
    ParamSpec(
        "accel_lsb",
        _ACC_LSB,
        "m/s^2",
        "ADC resolution (one code)",
        "ADIS16350 datasheet: 2.522 mg/LSB * 9.80665e-3 = 2.47324e-2 m/s^2",
        min=0.0,
        max=100.0,
        min_exclusive=True,
    ),
)

T_REF_C = 25.0  # reference temperature of the temperature terms, degC
SENSORS = ("gyro", "accel")
#: SI unit of each sensor's output.
SENSOR_UNITS = {"gyro": "rad/s", "accel": "m/s^2"}
PRESETS_NAMES = ("petkov", "adis16350", "icm42688p")
#: Number of SeedSequence children: 8 of the stochastic terms, 2 of the turn-on biases.

PRESET_SPEC = ParamSpec(
    "preset",
    "petkov",
    "-",
    "parameter set of the device: 'petkov' (Petkov & Slavov's stochastic terms, no "
    "deterministic errors), 'adis16350' (with the ADIS16350 datasheet's deterministic "
    "errors), 'icm42688p' (TDK InvenSense ICM-42688-P); parameters given explicitly "
    "override the preset's values",
    "Petkov & Slavov Sec. 3-4; Analog Devices ADIS16350 datasheet; TDK InvenSense "
    "ICM-42688-P datasheet DS-000347",
    choices=PRESETS_NAMES,
)


def _off_axis() -> tuple[tuple[str, str], ...]:
    return tuple((a, b) for a in AXES for b in AXES if a != b)


def _error_specs(s: str) -> tuple[ParamSpec, ...]:
    """Deterministic-error and turn-on parameters of sensor ``s`` (eq. (1)), all 0 by
    default (the 'petkov' preset)."""
    u = SENSOR_UNITS[s]
    big = 1.0 if s == "gyro" else 100.0  # bias range, rad/s or m/s^2
    zero = "petkov preset: 0 (the paper models the stochastic terms only)"
    specs = [
        ParamSpec(
            f"{s}_axis_bias_{a}",
            0.0,
            u,
            f"constant bias of the {a} axis, added to {s}_bias (b_const, eq. (1))",
            zero,
            min=-big,
            max=big,
        )
        for a in AXES
    ]
    specs += [
        ParamSpec(
            f"{s}_turnon_bias_std_{a}",
            0.0,
            u,
            f"std of the turn-on (run-to-run) bias of the {a} axis, drawn N(0, std^2) at each "
            "power-up (b_turnon, eq. (1))",
            zero,
            min=0.0,
            max=big,
        )
        for a in AXES
    ]
    specs += [
        ParamSpec(
            f"{s}_scale_factor_{a}",
            0.0,
            "-",
            f"scale-factor error of the {a} axis as a fraction (0.01 = +1 % = 10,000 ppm): "
            f"C[{a},{a}] = 1 + sf",
            zero,
            min=-0.5,
            max=0.5,
        )
        for a in AXES
    ]
    specs += [
        ParamSpec(
            f"{s}_misalignment_{a}{b}",
            0.0,
            "-",
            f"cross-axis sensitivity C[{a},{b}]: output on {a} per unit input on {b} (small "
            "angle in rad; MATLAB AxesMisalignment in % / 100)",
            zero,
            min=-0.2,
            max=0.2,
        )
        for a, b in _off_axis()
    ]
    specs += [
        ParamSpec(
            f"{s}_bias_tempco_{a}",
            0.0,
            f"{u}/K",
            f"bias temperature coefficient of the {a} axis around {T_REF_C:g} C (b_T, eq. (1); "
            "MATLAB TemperatureBias)",
            zero,
            min=-big / 10.0,
            max=big / 10.0,
        )
        for a in AXES
    ]
    specs += [
        ParamSpec(
            f"{s}_sf_tempco_{a}",
            0.0,
            "1/K",
            f"relative gain change of output axis {a} per K around {T_REF_C:g} C (s_T, eq. (1); "
            "MATLAB TemperatureScaleFactor in %/C / 100)",
            zero,
            min=-0.01,
            max=0.01,
        )
        for a in AXES
    ]
    if s == "gyro":
        specs += [
            ParamSpec(
                f"gyro_g_sensitivity_{a}{b}",
                0.0,
                "rad/s/(m/s^2)",
                f"g-sensitivity G[{a},{b}]: rate error on gyro {a} per unit specific force "
                f"along {b} (eq. (1); MATLAB AccelerationBias is the diagonal)",
                zero,
                min=-0.1,
                max=0.1,
            )
            for a in AXES
            for b in AXES
        ]
        specs += [
            ParamSpec(
                f"gyro_g2_sensitivity_{a}{b}",
                0.0,
                "rad/s/(m/s^2)^2",
                f"g^2 sensitivity G2[{a},{b}]: rate error on gyro {a} per unit of the square of "
                f"the specific force along {b}; a vibration of variance sigma^2 along {b} "
                f"rectifies to a mean G2 sigma^2 (eq. (1))",
                zero + "; MEMS gyro datasheets give 'vibration rectification' of the order "
                "1e-4 to 1e-2 deg/s/g^2 (1.8e-8 to 1.8e-6 rad/s/(m/s^2)^2; order of magnitude, "
                "not one datasheet)",
                min=-1.0e-3,
                max=1.0e-3,
            )
            for a in AXES
            for b in AXES
        ]
    else:
        specs += [
            ParamSpec(
                f"accel_k2_{a}",
                0.0,
                "1/(m/s^2)",
                f"second-order (quadratic) coefficient K2 of the {a} axis: output += K2 f_{a}^2; "
                "a vibration of variance sigma^2 rectifies to a mean K2 sigma^2 (eq. (1); "
                "IEEE Std 1293-2018 accelerometer model K2)",
                zero + "; tactical and MEMS accelerometers: 10 to 1000 ug/g^2 (1e-6 to 1e-4 "
                "1/(m/s^2); order of magnitude, not one datasheet)",
                min=-1.0e-2,
                max=1.0e-2,
            )
            for a in AXES
        ]
    specs.append(
        ParamSpec(
            f"{s}_bandwidth",
            0.0,
            "Hz",
            "3 dB bandwidth of the first-order output low-pass (module docstring); 0: off",
            zero + " (no filter)",
            min=0.0,
            max=1.0e6,
        )
    )
    return tuple(specs)


LATENCY_SPEC = ParamSpec(
    "latency_s",
    0.0,
    "s",
    "sensor latency L: the sample stamped t measures the motion (rate, specific force) of "
    "t - L (a driver's or filter's delay, what Kalibr's time-offset calibration estimates); "
    "the truth topic carries the motion at t, truth_calibration the latency",
    "0: no delay (the references); real parts: group delay of the digital filter, e.g. "
    "a few ms at a 100 Hz ODR",
    min=0.0,
    max=10.0,
)

ERROR_SPECS: tuple[ParamSpec, ...] = (
    (PRESET_SPEC,) + _error_specs("gyro") + _error_specs("accel") + (LATENCY_SPEC,)
)

#: Flicker (1/f) bias instability of each sensor, on top of Petkov's Gauss-Markov term: the
#: flat Allan floor real parts show (IEEE Std 952-1997, Annex C); 0 (the default) is off.
FLICKER_SPECS: tuple[ParamSpec, ...] = flicker_specs(
    "gyro_flicker",
    "rad/s",
    coefficient_source="IEEE Std 952-1997, Annex C: bias instability B (Allan floor 0.664 B); "
    "0: off, Petkov's model has the Gauss-Markov term only",
) + flicker_specs(
    "accel_flicker",
    "m/s^2",
    coefficient_max=10.0,
    coefficient_source="IEEE Std 952-1997, Annex C, applied to the accelerometer (IEEE Std "
    "1293-2018); 0: off, Petkov's model has the Gauss-Markov term only",
)


IMU_SPECS: tuple[ParamSpec, ...] = (
    COMMON_SPECS
    + GYRO_SPECS
    + ACCEL_SPECS
    + ERROR_SPECS
    + ENVIRONMENT_SPECS
    + VIBRATION_SPECS
    + FLICKER_SPECS
    + ADC_ERROR_SPECS
)


# --- presets --------------------------------------------------------------------------------
def _per_axis(name: str, values, source: str, spread: Spread | None = None) -> dict:
    return {name.format(a=a): (float(v), source, spread) for a, v in zip(AXES, values)}


def _off(name: str, limit: float, source: str, spread: Spread | None) -> dict:
    """Off-diagonal elements of a sensor's misalignment: the nominal device has each at half
    the limit in a fixed sign pattern (+, -, -, +, +, - over xy, xz, yx, yz, zx, zy)."""
    signs = (1, -1, -1, 1, 1, -1)
    return {
        name.format(a=a, b=b): (0.5 * sgn * limit, source, spread)
        for (a, b), sgn in zip(_off_axis(), signs)
    }


def _uni(width: float, what: str) -> Spread:
    return Spread("uniform", width, relative=False, source=f"{what}; assumption: uniform")


def _nor(sd: float, what: str) -> Spread:
    return Spread("normal", sd, relative=False, source=f"{what}; assumption: normal")


_ADI = (
    "Analog Devices ADIS16350 datasheet, specifications table (transcribed, not yet re-checked "
    "against the current revision)"
)
_SIGNS = (1.0, -1.0, 1.0)  # nominal device: the datasheet magnitude with signs +, -, + on x, y, z


def _adis16350() -> dict:
    g_bias_sd = 3.0 * DEG
    a_bias_sd = 50e-3 * G0
    g_sf, a_sf = 0.01, 0.01
    g_mis, a_mis = 0.05 * DEG, 0.25 * DEG
    g_bt, a_bt = 0.1 * DEG, 2.5e-3 * G0
    g_st, a_st = 600e-6, 500e-6
    g_gs = 0.05 * DEG / G0
    out: dict = {}
    out |= {
        f"gyro_axis_bias_{a}": (
            0.0,
            f"{_ADI}: nominal 0",
            _nor(
                g_bias_sd,
                f"{_ADI}: initial bias error 3 deg/s (1 sigma) * pi/180 = 5.23599e-2 rad/s",
            ),
        )
        for a in AXES
    }
    out |= {
        f"accel_axis_bias_{a}": (
            0.0,
            f"{_ADI}: nominal 0",
            _nor(
                a_bias_sd,
                f"{_ADI}: initial bias error 50 mg (1 sigma) * 9.80665e-3 = 0.490333 m/s^2",
            ),
        )
        for a in AXES
    }
    for s, sf, what in (("gyro", g_sf, "1 %"), ("accel", a_sf, "1 %")):
        src = f"{_ADI}: initial sensitivity tolerance +-{what} -> +-{sf:g}"
        out |= _per_axis(
            f"{s}_scale_factor_{{a}}",
            [0.5 * sf * x for x in _SIGNS],
            src + " (nominal device: half, signs +-+)",
            _uni(sf, src),
        )
    out |= _off(
        "gyro_misalignment_{a}{b}",
        g_mis,
        f"{_ADI}: axis-to-axis misalignment +-0.05 deg = +-8.72665e-4 rad",
        _uni(g_mis, f"{_ADI}: axis-to-axis +-0.05 deg"),
    )
    out |= _off(
        "accel_misalignment_{a}{b}",
        a_mis,
        f"{_ADI}: axis-to-axis misalignment +-0.25 deg = +-4.36332e-3 rad",
        _uni(a_mis, f"{_ADI}: axis-to-axis +-0.25 deg"),
    )
    for name, val, text in (
        (
            "gyro_bias_tempco",
            g_bt,
            "bias temperature coefficient 0.1 deg/s/C * pi/180 = 1.74533e-3 rad/s/K",
        ),
        (
            "accel_bias_tempco",
            a_bt,
            "bias temperature coefficient 2.5 mg/C * 9.80665e-3 = 2.45166e-2 m/s^2/K",
        ),
        ("gyro_sf_tempco", g_st, "sensitivity temperature coefficient 600 ppm/C = 6e-4 1/K"),
        ("accel_sf_tempco", a_st, "sensitivity temperature coefficient 500 ppm/C = 5e-4 1/K"),
    ):
        src = f"{_ADI}: {text}"
        out |= _per_axis(
            name + "_{a}",
            [val * x for x in _SIGNS],
            src + " (nominal device: that magnitude, signs +-+)",
            _uni(val, src),
        )
    src = (
        f"{_ADI}: linear acceleration effect 0.05 deg/s/g * pi/180 / 9.80665 = "
        "8.89935e-5 rad/s/(m/s^2), any direction"
    )
    for a in AXES:
        for b in AXES:
            out[f"gyro_g_sensitivity_{a}{b}"] = (
                g_gs if a == b else 0.0,
                src + " (nominal device: on the diagonal)",
                _uni(g_gs, src),
            )
    for s in SENSORS:
        out[f"{s}_bandwidth"] = (350.0, f"{_ADI}: 3 dB bandwidth 350 Hz", None)
    return out


_ICM = (
    "TDK InvenSense ICM-42688-P datasheet DS-000347, Tables 1 (gyroscope) and 2 (accelerometer) "
    "(transcribed, not yet re-checked against the current revision)"
)
_ICM_ASSUMED = "not specified by the ICM-42688-P datasheet DS-000347; assumption"


def _icm42688p() -> dict:
    out: dict = {
        "sample_rate_hz": (100.0, f"{_ICM}: ODR 100 Hz (one of the selectable rates)", None),
        "bits": (16, f"{_ICM}: 16-bit gyro and accelerometer data registers", None),
        "gyro_bias": (0.0, f"{_ICM}: ZRO nominal 0", None),
        "gyro_lsb": (
            DEG / 131.0,
            f"{_ICM}: +-250 dps range, 131 LSB/(deg/s) -> pi/180/131 = 1.33229e-4 rad/s",
            None,
        ),
        "accel_lsb": (
            G0 / 8192.0,
            f"{_ICM}: +-4 g range, 8192 LSB/g -> 9.80665/8192 = 1.19710e-3 m/s^2",
            None,
        ),
        "gyro_noise_density": (
            0.0028 * DEG,
            f"{_ICM}: rate noise spectral density "
            "0.0028 deg/s/sqrt(Hz) * pi/180 = 4.88692e-5 rad/s/sqrt(Hz)",
            None,
        ),
        "accel_noise_density": (
            70e-6 * G0,
            f"{_ICM}: noise spectral density 70 ug/sqrt(Hz) * 9.80665 = 6.86466e-4 m/s^2/sqrt(Hz)",
            None,
        ),
        "gyro_bias_instability": (
            6.0 / 3600.0 * DEG,
            f"{_ICM_ASSUMED}: B = 6 deg/h = 2.90888e-5 rad/s",
            None,
        ),
        "gyro_correlation_time": (100.0, f"{_ICM_ASSUMED}: T = 100 s", None),
        "gyro_random_walk": (0.0, f"{_ICM_ASSUMED}: 0", None),
        "accel_bias_instability": (
            0.05e-3 * G0,
            f"{_ICM_ASSUMED}: B = 0.05 mg = 4.90333e-4 m/s^2",
            None,
        ),
        "accel_correlation_time": (100.0, f"{_ICM_ASSUMED}: T = 100 s", None),
        "accel_random_walk": (0.0, f"{_ICM_ASSUMED}: 0", None),
    }
    g_zro, a_zg = 0.5 * DEG, 20e-3 * G0
    out |= {
        f"gyro_axis_bias_{a}": (
            0.0,
            f"{_ICM}: nominal 0",
            _uni(g_zro, f"{_ICM}: initial ZRO tolerance +-0.5 deg/s * pi/180 = +-8.72665e-3 rad/s"),
        )
        for a in AXES
    }
    out |= {
        f"accel_axis_bias_{a}": (
            0.0,
            f"{_ICM}: nominal 0",
            _uni(a_zg, f"{_ICM}: initial zero-g tolerance +-20 mg * 9.80665e-3 = +-0.196133 m/s^2"),
        )
        for a in AXES
    }
    for s in SENSORS:
        src = f"{_ICM}: sensitivity scale factor tolerance +-0.5 % -> +-0.005"
        out |= _per_axis(
            f"{s}_scale_factor_{{a}}",
            [0.0025 * x for x in _SIGNS],
            src + " (nominal device: half, signs +-+)",
            _uni(0.005, src),
        )
    for s, lim in (("gyro", 0.0125), ("accel", 0.01)):
        src = f"{_ICM}: cross-axis sensitivity +-{100 * lim:g} % -> +-{lim:g}"
        out |= _off(
            f"{s}_misalignment_{{a}}{{b}}", lim, src + " (nominal device: half)", _uni(lim, src)
        )
    for name, val, text in (
        (
            "gyro_bias_tempco",
            0.005 * DEG,
            "ZRO variation over temperature +-0.005 deg/s/C * pi/180 = +-8.72665e-5 rad/s/K",
        ),
        (
            "accel_bias_tempco",
            0.15e-3 * G0,
            "zero-g level change vs. temperature +-0.15 mg/C * 9.80665e-3 = +-1.47100e-3 m/s^2/K",
        ),
        (
            "gyro_sf_tempco",
            5e-5,
            "sensitivity scale factor variation over temperature +-0.005 %/C = +-5e-5 1/K",
        ),
        ("accel_sf_tempco", 5e-5, "sensitivity change vs. temperature +-0.005 %/C = +-5e-5 1/K"),
    ):
        src = f"{_ICM}: {text}"
        out |= _per_axis(
            name + "_{a}",
            [val * x for x in _SIGNS],
            src + " (nominal device: that magnitude, signs +-+)",
            _uni(val, src),
        )
    for s in SENSORS:
        out[f"{s}_bandwidth"] = (
            25.0,
            f"{_ICM}: programmable UI filter; assumption: bandwidth ODR/4 = 25 Hz",
            None,
        )
    return out


#: Per preset: parameter -> (value, source, spread or None); parameters not named keep the
#: table's ('petkov') default.
PRESETS: dict[str, dict[str, tuple[Any, str, Spread | None]]] = {
    "petkov": {},
    "adis16350": _adis16350(),
    "icm42688p": _icm42688p(),
}


@functools.cache
def imu_specs(preset: str = "petkov") -> tuple[ParamSpec, ...]:
    """:data:`IMU_SPECS` with the defaults, sources and spreads of ``preset``.

    Args:
        preset: one of :data:`PRESETS_NAMES`.
    Raises:
        ParameterError: for an unknown preset.
    """
    preset = PRESET_SPEC.validate(preset)
    table = PRESETS[preset]
    out = []
    for spec in IMU_SPECS:
        if spec.name == "preset":
            out.append(replace(spec, default=preset))
        elif spec.name in table:
            value, source, spread = table[spec.name]
            out.append(replace(spec, default=value, source=source, spread=spread))
        else:
            out.append(spec)
    return tuple(out)


def imu_values(params: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The device's parameter values: the defaults of ``params['preset']`` (default 'petkov')
    updated with the other ``params`` (explicit values override the preset's), validated.

    Raises:
        ParameterError: for an unknown name or an invalid value.
    """
    preset = (params or {}).get("preset", "petkov")
    return resolve(imu_specs(preset), params)


def draw_imu_device(
    values: Mapping[str, Any], device_seed: int | None, fixed: Iterable[str] = ()
) -> dict[str, Any]:
    """One device of the batch of ``values['preset']``: each parameter with a spread in the
    preset (per-axis biases, scale factors, misalignments, temperature coefficients,
    g-sensitivities) drawn within the datasheet tolerance around 0
    (:func:`~mems_sim.params.draw_device`, per-parameter streams of ``device_seed``);
    ``device_seed`` None or negative: ``values`` unchanged (the preset's nominal device).
    Names in ``fixed`` keep their values. Raises ParameterError for a ``device_seed`` >= 0 on a
    preset without spreads ('petkov': the paper gives no batch tolerances), where a drawn
    device would silently be the nominal one.
    """
    preset = values.get("preset", "petkov")
    specs = imu_specs(preset)
    fixed = set(fixed)
    if device_seed is None or device_seed < 0:
        return dict(values)
    if not any(spec.spread is not None for spec in specs):
        with_spreads = [p for p in PRESETS_NAMES if any(s.spread for s in imu_specs(p))]
        raise ParameterError(
            f"device_seed {device_seed}: the IMU preset '{preset}' has no batch spreads to "
            f"draw from (choose preset {' or '.join(with_spreads)})"
        )
    centred = dict(values)
    for spec in specs:
        if spec.spread is not None and spec.name not in fixed:
            centred[spec.name] = 0.0
    return draw_device(specs, centred, device_seed, 0.0, fixed=fixed)
