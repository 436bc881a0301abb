"""Micro-scanner with SHARED drive/sense electrodes and the AMDM read-out chain (chapter 5).

Source: Y. Chen, "High-accuracy Motion Estimation for MEMS Devices with Capacitive Sensors",
PhD thesis, U. Michigan 2018, chapter 5: dynamics eqs. (80)-(81), drive/carrier eqs.
(94)-(96), AMDM chain eqs. (92)-(104), capacitance eq. (105), Table 5.1 (settings), Table
5.2 (identified device parameters). The mechanics and the Gaussian comb capacitance are
those of :mod:`mems_sim.devices.scanner` (chapter-4 module, public API:
:meth:`ScannerParams.from_physical`, :func:`simulate_mechanics`, :func:`capacitance`,
:func:`dcap_dtheta`), here with the Table 5.2 device (theta_th = 0, drive comb = sense comb:
the electrodes are shared).

Signal chain, simulated at ``internal_rate_hz`` (default 10 MHz, 20 samples per carrier period),
published decimated to ``internal_rate_hz / output_decimation`` (default 1 MHz)::

    V(t)   = V_dr(t) + V_c(t)                       eq. (94)
    V_dr   = V_max/2 (1 - cos phi_dr(t))            unipolar 0..V_max (eq. (95) + offset, Table 5.1)
    V_c    = V_c0 sin(2 pi f_c t)                   eq. (96)
    J theta'' + b theta' + k theta = 1/2 dC_s/dtheta V^2     eq. (81) (V held per internal sample)
    V_o1   = -R_f d/dt[V (C_s(theta) + C_p)]        eq. (92)  (inverting transimpedance stage)
           = -R_f (dV/dt C_t + V dC_s/dtheta omega)        eq. (93)
    V_o2   = HPF(V_o1)        Butterworth high-pass (removes the drive feed-through, keeps the
                              carrier band f_c +- f_dr), eq. (99)
    V_o3   = a_d V_o2 + b_d V_o2^2                  square-law envelope detector, eq. (100)
    V_lp   = LPF(V_o3)        Bessel low-pass (keeps the envelope, removes f_c, 2 f_c), eq. (103)
    y_cap  = g V_lp + V_off   output stage (gain g < 0, offset) -> sampled every
             ``output_decimation`` internal samples, + white noise of variance R, 16-bit ADC.

Output-stage calibration (how Table 5.2's a_cir, b_cir are realised): the envelope of V_o2 is
A C_t with A = R_f |H_hpf(f_c)| 2 pi f_c V_c0, so after the square law and the low-pass
y = g b_d A^2/2 (C_s + C_p)^2 + V_off.  g and V_off are set so that this is tangent to
eq. (104), y = a_cir C_s + b_cir, at C_s = ``calibration_capacitance`` (the chain is "identified
in steady state", Sec. 5.5.1).  The chain is therefore only approximately linear in C_s
(residual g b_d A^2/2 (C_s - C_ref)^2, a few mV here) and delays the envelope by the filters'
group delay :func:`chain_delay` (Sec. 5.3.3: "phase shifts ... calibrated"); both are real
model errors the estimators see.

Inconsistency in Chen 2018: with Table 5.2 (zeta = b/(2 sqrt(Jk)) = 0.00265,
C0/theta0^2 = 1.43e-10 F/rad^2) the stiffness modulation of a 0..V_max drive is
h = V_max^2/2 C0/theta0^2 / k, and parametric resonance needs h > 4 zeta, i.e.
V_max > ~128 V: the 0-60 V of Table 5.1 produces no motion (checked numerically, see tests).
The default stays the paper's 60 V; scenarios that need motion set ``drive_voltage_max``.
Also eq. (92)-(103): sign and unit of the gains are not given; the square law makes the
chain quadratic in C_t, (103)-(104) keep only the tangent.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numba
import numpy as np
import scipy.signal

from mems_sim.devices.scanner import ScannerParams, capacitance, rk4_step
from mems_sim.params import (
    AIR_DAMPING_TEMPCO,
    SILICON_EXPANSION_TEMPCO,
    SILICON_STIFFNESS_TEMPCO,
    ParameterError,
    ParamSpec,
    batch_spread,
    resolve,
)

__all__ = [
    "DEVICE_SPECS",
    "CIRCUIT_SPECS",
    "DRIVE_SPECS",
    "AMDM_SPECS",
    "resolve_amdm",
    "device_params",
    "measurement_model",
    "AmdmChain",
    "chain_delay",
    "AmdmFrame",
    "AmdmScannerDevice",
    "drive_phase",
    "drive_voltage",
    "parametric_threshold_voltage",
]

_T52 = "Chen 2018 Table 5.2"

#: Chapter-5 device (Table 5.2): mechanics and Gaussian capacitance (105).
DEVICE_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "inertia",
        1.15e-14,
        "kg m^2",
        "moment of inertia J",
        _T52,
        min=0.0,
        max=1.0e-6,
        min_exclusive=True,
        spread=batch_spread(0.02, "+-2 % mirror inertia (thickness tolerance)"),
    ),
    ParamSpec(
        "spring_constant",
        1.10e-4,
        "N m/rad",
        "torsional spring constant k",
        _T52,
        min=0.0,
        max=1.0e3,
        min_exclusive=True,
        spread=batch_spread(0.10, "+-10 % spring constant (torsion bar width tolerance)"),
        tempco=SILICON_STIFFNESS_TEMPCO,
    ),
    ParamSpec(
        "damping",
        5.95e-12,
        "N m s/rad",
        "viscous damping coefficient b_v",
        _T52,
        min=0.0,
        max=1.0,
        min_exclusive=True,
        spread=batch_spread(0.20, "+-20 % damping (gap tolerance of the air films)"),
        tempco=AIR_DAMPING_TEMPCO,
    ),
    ParamSpec(
        "cap_theta0",
        0.2,
        "rad",
        "Gaussian width theta_0 of C_s, eq. (105)",
        _T52,
        min=1.0e-3,
        max=2.0,
        min_exclusive=False,
        spread=batch_spread(0.10, "+-10 % comb width (finger length tolerance)"),
    ),
    ParamSpec(
        "cap_c0",
        5.71e-12,
        "F",
        "Gaussian amplitude C_0 of C_s, eq. (105)",
        _T52,
        min=0.0,
        max=1.0e-9,
        min_exclusive=True,
        spread=batch_spread(0.20, "+-20 % comb gain (finger gap and overlap tolerance)"),
        tempco=SILICON_EXPANSION_TEMPCO,
    ),
    ParamSpec(
        "cap_cb", 9.79e-12, "F", "capacitance bias C_b of C_s, eq. (105)", _T52, min=0.0, max=1.0e-9
    ),
    ParamSpec(
        "circuit_gain",
        -0.3574e12,
        "V/F",
        "a_cir of y = a_cir C_s + b_cir, eq. (104)",
        _T52 + " (-0.3574 V/pF)",
        min=-1.0e15,
        max=1.0e15,
    ),
    ParamSpec("circuit_bias", 6.3945, "V", "b_cir of eq. (104)", _T52, min=-100.0, max=100.0),
    ParamSpec(
        "output_noise_var",
        1.92e-4,
        "V^2",
        "variance R of the white noise at the AMDM output",
        _T52,
        min=0.0,
        max=100.0,
    ),
)

#: AMDM circuit, eqs. (92)-(103), Table 5.1.
CIRCUIT_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "parasitic_capacitance",
        10.0e-12,
        "F",
        "C_p in parallel with C_s, eq. (92)",
        "chosen (not identified in Chen 2018); keeps the carrier at V_o1 ~ 9 V",
        min=0.0,
        max=1.0e-9,
    ),
    ParamSpec(
        "feedback_resistance",
        17.86e3,
        "Ohm",
        "transimpedance feedback resistor R_f",
        "Chen 2018 Table 5.1",
        min=0.0,
        max=1.0e9,
        min_exclusive=True,
    ),
    ParamSpec(
        "carrier_amplitude",
        6.0,
        "V",
        "carrier amplitude V_c0, eq. (96)",
        "Chen 2018 Table 5.1 (6 V; 12 V in the sweeps)",
        min=0.0,
        max=100.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "carrier_freq_hz",
        500.0e3,
        "Hz",
        "carrier frequency f_c",
        "Chen 2018 Table 5.1",
        min=1.0e3,
        max=1.0e9,
    ),
    ParamSpec(
        "hpf_cutoff_hz",
        200.0e3,
        "Hz",
        "cut-off of the Butterworth high-pass (eq. (99))",
        "chosen: between 2 f_dr (62 kHz) and f_c - f_dr (469 kHz)",
        min=1.0,
        max=1.0e9,
    ),
    ParamSpec("hpf_order", 4, "-", "order of the high-pass", "chosen", min=1, max=10),
    ParamSpec(
        "lpf_cutoff_hz",
        150.0e3,
        "Hz",
        "cut-off of the Bessel low-pass (eq. (103))",
        "chosen: passes the envelope harmonics f_dr, 2 f_dr, rejects f_c",
        min=1.0,
        max=1.0e9,
    ),
    ParamSpec(
        "lpf_order",
        6,
        "-",
        "order of the low-pass",
        "chosen (carrier residue < noise)",
        min=1,
        max=12,
    ),
    ParamSpec(
        "detector_linear_gain",
        0.05,
        "-",
        "a_d of the square-law detector, eq. (100)",
        "chosen",
        min=-10.0,
        max=10.0,
    ),
    ParamSpec(
        "detector_square_gain",
        0.1,
        "1/V",
        "b_d of the square-law detector, eq. (100)",
        "chosen",
        min=0.0,
        max=100.0,
        min_exclusive=True,
    ),
    ParamSpec(
        "calibration_capacitance",
        14.3e-12,
        "F",
        "C_s at which the output stage makes the chain tangent to eq. (104)",
        "chosen: mid-range of C_s over |theta| <= 0.15 rad",
        min=0.0,
        max=1.0e-9,
        min_exclusive=True,
    ),
    ParamSpec(
        "internal_rate_hz",
        10.0e6,
        "Hz",
        "internal simulation rate of mechanics + chain",
        "chosen: 20 samples per carrier period",
        min=1.0e3,
        max=1.0e10,
    ),
    ParamSpec(
        "output_decimation",
        10,
        "-",
        "internal samples per published sample",
        "chosen: 1 MHz output (the DAQ rate of Sec. 5.4.1)",
        min=1,
        max=100000,
    ),
    ParamSpec(
        "adc_bits", 16, "bits", "resolution of the output ADC", "Sec. 5.4.1 (16 bit)", min=2, max=31
    ),
    ParamSpec(
        "adc_full_scale",
        10.0,
        "V",
        "ADC input range +-full scale",
        "Sec. 5.4.1 (+-10 V)",
        min=0.0,
        max=1.0e3,
        min_exclusive=True,
    ),
)

#: Drive programme and initial state.
DRIVE_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "drive_voltage_max",
        60.0,
        "V",
        "peak of the unipolar drive 0..V_max",
        "Chen 2018 Sec. 5.4.2 / Table 5.1 (0-60 V; see module doc: below the "
        "parametric threshold of Table 5.2)",
        min=0.0,
        max=500.0,
    ),
    ParamSpec(
        "sweep_start_hz",
        31.15e3,
        "Hz",
        "drive frequency at t = 0",
        "Chen 2018 Sec. 5.4.2 (31.15 kHz)",
        min=1.0,
        max=1.0e9,
    ),
    ParamSpec(
        "sweep_end_hz",
        31.10e3,
        "Hz",
        "drive frequency after the linear sweep (held)",
        "Chen 2018 Sec. 5.4.2 (31.10 kHz)",
        min=1.0,
        max=1.0e9,
    ),
    ParamSpec(
        "sweep_start_s",
        0.0,
        "s",
        "start of the linear sweep (f = sweep_start before)",
        "chosen",
        min=0.0,
        max=1.0e6,
    ),
    ParamSpec(
        "sweep_time_s", 0.02, "s", "duration of the linear sweep", "chosen", min=0.0, max=1.0e6
    ),
    ParamSpec(
        "initial_angle",
        0.02,
        "rad",
        "theta at t = 0 (seed of the parametric growth)",
        "chosen",
        min=-1.0,
        max=1.0,
    ),
    ParamSpec(
        "torque_noise_std",
        0.0,
        "N m",
        "std of a white process torque held per internal sample",
        "chosen (none)",
        min=0.0,
        max=1.0e-3,
    ),
)

AMDM_SPECS: tuple[ParamSpec, ...] = DEVICE_SPECS + CIRCUIT_SPECS + DRIVE_SPECS

#: The drive of the shared-electrode study (Chen 2018 Sec. 5.4, Figs. 5.8-5.9, as the
#: scenario runs it): 150 V swept down 31.32 -> 31.26 kHz over 0.06 s through the
#: parametric resonance, from 0.02 rad; the values of :data:`DRIVE_SPECS` it sets.
SWEEP_STUDY = dict(
    drive_voltage_max=150.0,
    sweep_start_hz=31.32e3,
    sweep_end_hz=31.26e3,
    sweep_start_s=0.0,
    sweep_time_s=0.06,
    initial_angle=0.02,
)


def resolve_amdm(overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Validated parameters of :data:`AMDM_SPECS` with the cross checks of the chain.

    Raises:
        ParameterError: unknown name, out-of-range value, or frequencies that break the
            chain (carrier above the internal Nyquist rate, filters not separating the bands,
            drive above the output Nyquist rate).
    """
    p = resolve(AMDM_SPECS, overrides)
    f_int = p["internal_rate_hz"]
    f_out = f_int / p["output_decimation"]
    if not p["carrier_freq_hz"] < f_int / 4:
        raise ParameterError(
            f"parameter 'carrier_freq_hz' = {p['carrier_freq_hz']!r} is out of "
            f"range: must be below internal_rate_hz/4 = {f_int / 4!r} Hz"
        )
    for name in ("hpf_cutoff_hz", "lpf_cutoff_hz"):
        if not p[name] < f_int / 2:
            raise ParameterError(
                f"parameter '{name}' = {p[name]!r} is out of range: must be "
                f"below internal_rate_hz/2 = {f_int / 2!r} Hz"
            )
    if not p["lpf_cutoff_hz"] < p["carrier_freq_hz"]:
        raise ParameterError(
            f"parameter 'lpf_cutoff_hz' = {p['lpf_cutoff_hz']!r} is out of "
            f"range: must be below carrier_freq_hz = {p['carrier_freq_hz']!r} Hz"
        )
    if not p["hpf_cutoff_hz"] < p["carrier_freq_hz"]:
        raise ParameterError(
            f"parameter 'hpf_cutoff_hz' = {p['hpf_cutoff_hz']!r} is out of "
            f"range: must be below carrier_freq_hz = {p['carrier_freq_hz']!r} Hz"
        )
    for name in ("sweep_start_hz", "sweep_end_hz"):
        if not p[name] < f_out / 4:
            raise ParameterError(
                f"parameter '{name}' = {p[name]!r} is out of range: must be "
                f"below the output rate / 4 = {f_out / 4!r} Hz"
            )
    return p


def device_params(p: Mapping[str, Any]) -> ScannerParams:
    """Table 5.2 device as :class:`mems_sim.devices.scanner.ScannerParams` (theta_th = 0,
    drive comb = sense comb: shared electrodes)."""
    return ScannerParams.from_physical(
        p["inertia"],
        p["spring_constant"],
        p["damping"],
        0.0,
        p["cap_c0"],
        p["cap_theta0"],
        p["cap_cb"],
    )


def measurement_model(theta, p: Mapping[str, Any]):
    """y = a_cir (C_0 exp(-(theta/theta_0)^2) + C_b) + b_cir [V] -- eqs. (104)-(106).

    Args:
        theta: angle [rad] (scalar or array).
        p: dict with cap_c0 [F], cap_theta0 [rad], cap_cb [F], circuit_gain [V/F],
            circuit_bias [V].
    """
    u = np.asarray(theta, dtype=float) / p["cap_theta0"]
    return p["circuit_gain"] * (p["cap_c0"] * np.exp(-u * u) + p["cap_cb"]) + p["circuit_bias"]


def parametric_threshold_voltage(p: Mapping[str, Any]) -> float:
    """Smallest V_max of the unipolar drive for parametric resonance (linearised, small angle).

    V^2 = V_max^2 (1 - cos phi)^2 / 4 has a component V_max^2/2 cos(phi) at the drive
    frequency; with dC/dtheta ~ -2 C_0 theta/theta_0^2 the torque (80) modulates the
    stiffness by h k, h = V_max^2/2 C_0/theta_0^2 / k.  The Mathieu equation
    theta'' + 2 zeta wn theta' + wn^2 (1 + h cos 2 wn t) theta = 0 grows when h > 4 zeta.
    Returns V_max [V] with h = 4 zeta.
    """
    k, J, b = p["spring_constant"], p["inertia"], p["damping"]
    zeta = b / (2.0 * math.sqrt(J * k))
    return math.sqrt(4.0 * zeta * k * 2.0 * p["cap_theta0"] ** 2 / p["cap_c0"])


# ----------------------------------------------------------------------------- drive
def drive_phase(t: np.ndarray, p: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Drive phase phi_dr(t) = 2 pi int_0^t f_dr [rad] and frequency f_dr(t) [Hz].

    f_dr = sweep_start_hz until sweep_start_s, then linear to sweep_end_hz over sweep_time_s,
    then held (analytic, so frames concatenate exactly).
    """
    t = np.asarray(t, dtype=float)
    f0, f1, ts, tw = p["sweep_start_hz"], p["sweep_end_hz"], p["sweep_start_s"], p["sweep_time_s"]
    te = ts + tw
    rate = (f1 - f0) / tw if tw > 0 else 0.0
    s = np.clip(t - ts, 0.0, tw)
    cyc = f0 * np.minimum(t, ts) + f0 * s + 0.5 * rate * s * s + f1 * np.maximum(t - te, 0.0)
    f = np.where(t < ts, f0, np.where(t < te, f0 + rate * s, f1))
    return 2.0 * math.pi * cyc, f


def drive_voltage(t: np.ndarray, p: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Unipolar drive V_dr = V_max/2 (1 - cos phi_dr) [V] and its derivative dV_dr/dt [V/s]."""
    phi, f = drive_phase(t, p)
    vm = p["drive_voltage_max"]
    return 0.5 * vm * (1.0 - np.cos(phi)), 0.5 * vm * np.sin(phi) * 2.0 * math.pi * f


# ----------------------------------------------------------------------------- chain
def _group_delay_sos(sos: np.ndarray, f: float, fs: float) -> float:
    """Group delay [s] of a digital SOS filter at frequency f [Hz] (numerical d phase/d omega)."""
    df = max(f * 1e-4, fs * 1e-9)
    w, h = scipy.signal.sosfreqz(sos, worN=[f - df, f + df], fs=fs)
    dphi = np.angle(h[1] / h[0])
    return float(-dphi / (2.0 * math.pi * 2.0 * df))


class AmdmChain(NamedTuple):
    """Designed AMDM chain: filters (SOS at the internal rate) and output-stage constants.

    hpf, lpf: SOS arrays. carrier_gain: A = R_f |H_hpf(f_c)| 2 pi f_c V_c0 [V/F].
    out_gain g [-], out_offset V_off [V] (see module doc). delay: envelope delay [s].
    """

    hpf: np.ndarray
    lpf: np.ndarray
    carrier_gain: float
    out_gain: float
    out_offset: float
    delay: float


def design_chain(p: Mapping[str, Any]) -> AmdmChain:
    """Filters and output-stage calibration of the AMDM chain (module doc, eqs. (99)-(104))."""
    f_int = p["internal_rate_hz"]
    hpf = scipy.signal.butter(
        p["hpf_order"], p["hpf_cutoff_hz"], "highpass", fs=f_int, output="sos"
    )
    lpf = scipy.signal.bessel(
        p["lpf_order"], p["lpf_cutoff_hz"], "lowpass", fs=f_int, output="sos", norm="mag"
    )
    fc = p["carrier_freq_hz"]
    _, h = scipy.signal.sosfreqz(hpf, worN=[fc], fs=f_int)
    A = p["feedback_resistance"] * abs(h[0]) * 2.0 * math.pi * fc * p["carrier_amplitude"]
    cp, cref = p["parasitic_capacitance"], p["calibration_capacitance"]
    a_cir, b_cir, bd = p["circuit_gain"], p["circuit_bias"], p["detector_square_gain"]
    g = a_cir / (bd * A * A * (cref + cp))
    off = b_cir + a_cir * cref - 0.5 * g * bd * A * A * (cref + cp) ** 2
    f_env = 0.5 * (p["sweep_start_hz"] + p["sweep_end_hz"])
    delay = _group_delay_sos(hpf, fc, f_int) + _group_delay_sos(lpf, f_env, f_int)
    return AmdmChain(hpf, lpf, float(A), float(g), float(off), float(delay))


def chain_delay(p: Mapping[str, Any] | None = None) -> float:
    """Envelope delay of the AMDM chain [s]: group delay of the high-pass at f_c plus that of
    the low-pass at the drive frequency (the 'calibrated' phase shift of Sec. 5.3.3)."""
    return design_chain(
        resolve_amdm(p) if p is None or set(p) != {s.name for s in AMDM_SPECS} else p
    ).delay


class AmdmFrame(NamedTuple):
    """One published frame (n output samples from ``first_index``).

    codes: (n,) int32 ADC codes of y_cap. y: (n,) y_cap [V] (with noise, before quantisation).
    y_clean: (n,) y_cap without noise [V]. drive: (n,) V_dr at the output instants [V].
    drive_freq: (n,) f_dr [Hz]. theta [rad], omega [rad/s]: truth at the output instants.
    saturated: samples clipped by the ADC.
    """

    first_index: int
    codes: np.ndarray
    y: np.ndarray
    y_clean: np.ndarray
    drive: np.ndarray
    drive_freq: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    saturated: int


class AmdmScannerDevice:
    """Streaming chapter-5 scanner + AMDM chain (module doc), frame by frame.

    Deterministic: ``SeedSequence(seed).spawn(2)`` -> output noise, torque noise; drawn frame
    by frame so that frames concatenate bit-identically to one long run.

    Args:
        overrides: parameters of :data:`AMDM_SPECS` (validated, ParameterError on bad input).
        seed: run seed.
    """

    def __init__(self, overrides: Mapping[str, Any] | None = None, seed: int = 0) -> None:
        self.p = p = resolve_amdm(overrides)
        self.mech = device_params(p)
        self.chain = design_chain(p)
        self.decimation = p["output_decimation"]
        self.f_int = p["internal_rate_hz"]
        self.fs = self.f_int / self.decimation
        ss = np.random.SeedSequence(int(seed)).spawn(2)
        self._rng_y, self._rng_tau = (np.random.Generator(np.random.PCG64(s)) for s in ss)
        self._state = (float(p["initial_angle"]), 0.0)
        self._zi_h = np.zeros((self.chain.hpf.shape[0], 2))
        ct0 = float(capacitance(p["initial_angle"], self.mech)) + p["parasitic_capacitance"]
        dc = 0.5 * p["detector_square_gain"] * (self.chain.carrier_gain * ct0) ** 2
        self._zi_l = scipy.signal.sosfilt_zi(self.chain.lpf) * dc
        # pre-roll: the circuit has been running (mirror held at initial_angle) for 100 us
        # before t = 0, so the published record starts without filter start-up transients
        t = -np.arange(int(round(1e-4 * self.f_int)), 0, -1) / self.f_int
        vdr, dvdr = drive_voltage(t, p)
        wc = 2.0 * math.pi * p["carrier_freq_hz"]
        vc0 = p["carrier_amplitude"]
        vo1 = -p["feedback_resistance"] * (dvdr + vc0 * wc * np.cos(wc * t)) * ct0
        vo2, self._zi_h = scipy.signal.sosfilt(self.chain.hpf, vo1, zi=self._zi_h)
        vo3 = p["detector_linear_gain"] * vo2 + p["detector_square_gain"] * vo2 * vo2
        _, self._zi_l = scipy.signal.sosfilt(self.chain.lpf, vo3, zi=self._zi_l)
        self._zi_h = np.ascontiguousarray(self._zi_h, dtype=np.float64)
        self._zi_l = np.ascontiguousarray(self._zi_l, dtype=np.float64)
        self.lsb = 2.0 * p["adc_full_scale"] / 2 ** p["adc_bits"]
        self.next_index = 0

    def retune(self, overrides: Mapping[str, Any]) -> None:
        """The device's physical parameters moved (a temperature change): mechanics and
        comb follow ``overrides`` from the next sample on; the state, the filters' states,
        the chain's calibration (identified once, Sec. 5.5.1) and the noise streams are
        kept."""
        self.p = resolve_amdm(overrides)
        self.mech = device_params(self.p)

    @property
    def delay(self) -> float:
        """Envelope delay of the chain [s] (:func:`chain_delay`)."""
        return self.chain.delay

    def step(self, n: int) -> AmdmFrame:
        """Simulate and return the next ``n`` output samples.

        The per-sample work runs in two numba kernels (:func:`_drive_mechanics`,
        :func:`_chain`) around one numpy ``exp`` (the comb's Gaussian): the same operations
        in the same order as the array formulas of the module doc (:func:`drive_voltage`,
        :func:`~mems_sim.devices.scanner.simulate_mechanics`,
        :func:`~mems_sim.devices.scanner.capacitance`,
        :func:`~mems_sim.devices.scanner.dcap_dtheta`, ``scipy.signal.sosfilt``), so the
        frames are equal bit for bit to theirs; ``exp`` stays numpy's (its SIMD ``exp``
        differs from the C library's in the last bit on some inputs).
        """
        n = int(n)
        if n < 0:
            raise ValueError(f"n = {n} must be >= 0")
        p, D, ch, mech = self.p, self.decimation, self.chain, self.mech
        k0 = self.next_index
        nd = n * D
        f0, f1, ts, tw = (
            p["sweep_start_hz"],
            p["sweep_end_hz"],
            p["sweep_start_s"],
            p["sweep_time_s"],
        )
        wc = 2.0 * math.pi * p["carrier_freq_hz"]
        vc0 = p["carrier_amplitude"]
        std = p["torque_noise_std"]
        tau = self._rng_tau.standard_normal(nd) * std if std > 0 else np.zeros(0)
        v, dv, om, u, w = (np.empty(nd) for _ in range(5))
        drive, freq, theta, omega = (np.empty(n) for _ in range(4))
        fin = _drive_mechanics(
            k0 * D,
            D,
            float(self.f_int),
            float(f0),
            float(f1),
            float(ts),
            float(tw),
            float(ts + tw),
            float((f1 - f0) / tw if tw > 0 else 0.0),
            float(p["drive_voltage_max"]),
            float(wc),
            float(vc0),
            float(0.5 / self.f_int),
            self._state[0],
            self._state[1],
            tau,
            float(mech.J),
            float(mech.k),
            float(mech.b),
            float(mech.drive_c0),
            float(mech.drive_theta0),
            float(mech.theta_th),
            float(mech.sense_theta0),
            v,
            dv,
            om,
            u,
            w,
            drive,
            freq,
            theta,
            omega,
        )
        self._state = (float(fin[0]), float(fin[1]))
        np.exp(w, out=w)  # numpy's exp, as capacitance() and dcap_dtheta() take it
        vlp = np.empty(n)
        _chain(
            v,
            dv,
            om,
            u,
            w,
            D,
            float(mech.sense_c0),
            float(mech.sense_theta0),
            float(mech.sense_cb),
            float(p["parasitic_capacitance"]),
            float(p["feedback_resistance"]),
            float(p["detector_linear_gain"]),
            float(p["detector_square_gain"]),
            ch.hpf,
            ch.lpf,
            self._zi_h,
            self._zi_l,
            vlp,
        )
        y_clean = ch.out_gain * vlp + ch.out_offset
        noise = self._rng_y.standard_normal(n) * math.sqrt(p["output_noise_var"])
        y = y_clean + noise
        half = 2 ** (p["adc_bits"] - 1)
        raw = np.round(y / self.lsb)
        sat = int(np.count_nonzero((raw < -half) | (raw > half - 1)))
        codes = np.clip(raw, -half, half - 1).astype(np.int32)
        self.next_index += n
        return AmdmFrame(k0, codes, y, y_clean, drive, freq, theta, omega, sat)


# ----------------------------------------------------------------------------- kernels
@numba.njit(cache=True, inline="always")
def _phase(t, f0, f1, ts, tw, te, rate):
    """phi_dr(t) and f_dr(t) of :func:`drive_phase` for one instant (same operations)."""
    s = t - ts
    s = s if s > 0.0 else 0.0  # np.clip(t - ts, 0, tw): min(max(x, 0), tw) as numpy's
    s = s if s < tw else tw
    mn = t if t < ts else ts  # np.minimum(t, ts)
    mx = t - te
    mx = mx if mx > 0.0 else 0.0  # np.maximum(t - te, 0)
    cyc = f0 * mn + f0 * s + 0.5 * rate * s * s + f1 * mx
    f = f0 if t < ts else (f0 + rate * s if t < te else f1)
    return 2.0 * math.pi * cyc, f


@numba.njit(cache=True)
def _drive_mechanics(
    j0, D, f_int, f0, f1, ts, tw, te, rate, vmax, wc, vc0, half_dt, th, om, tau,
    J, k, b, dc0, dth0, thth, sth0, v, dv, om_out, u, w, drive, freq, theta, omega,
):  # fmt: skip
    """Drive, carrier and mechanics of :meth:`AmdmScannerDevice.step` per internal sample.

    For internal sample i (t = (j0 + i)/f_int): V (v) and dV/dt (dv) at t, the RK4 step of
    :func:`~mems_sim.devices.scanner.simulate_mechanics` (one substep, V held at the middle
    of the interval, torque ``tau[i]`` if ``tau`` is not empty), omega at t (om_out), and
    u = (theta - theta_th)/theta_0 and w = -u^2 of the sense comb (exp(w) is taken by the
    caller); at every D-th sample the output's drive, frequency, theta and omega.
    Returns the state at the end. The step comes to rest at exactly 0 instead of ringing
    down into subnormal floats (:data:`~mems_sim.devices.scanner.REST_ANGLE`)."""
    hv = 0.5 * vmax
    vcw = vc0 * wc
    hs = (1.0 / f_int) / 1
    noisy = tau.shape[0] > 0
    for i in range(v.shape[0]):
        t = (j0 + i) / f_int
        phi, f = _phase(t, f0, f1, ts, tw, te, rate)
        vdr = hv * (1.0 - math.cos(phi))
        dvdr = hv * math.sin(phi) * 2.0 * math.pi * f
        v[i] = vdr + vc0 * math.sin(wc * t)
        dv[i] = dvdr + vcw * math.cos(wc * t)
        tm = t + half_dt
        phm, _ = _phase(tm, f0, f1, ts, tw, te, rate)
        vm = hv * (1.0 - math.cos(phm)) + vc0 * math.sin(wc * tm)
        om_out[i] = om
        x = (th - thth) / sth0
        u[i] = x
        w[i] = -x * x
        if i % D == 0:
            kk = i // D
            drive[kk] = vdr
            freq[kk] = f
            theta[kk] = th
            omega[kk] = om
        v2 = vm * vm
        tn = tau[i] if noisy else 0.0
        th, om = rk4_step(th, om, v2, tn, hs, J, k, b, dc0, dth0, thth)
    return th, om


@numba.njit(cache=True)
def _chain(v, dv, om, u, e, D, c0, th0, cb, cp, rf, ad, bd, hpf, lpf, zh, zl, out):
    """AMDM chain per internal sample: C_t and dC_s/dtheta from u and e = exp(-u^2)
    (:func:`~mems_sim.devices.scanner.capacitance`, ``dcap_dtheta``), V_o1 (eq. (93)), the
    high-pass and low-pass sections in direct form II transposed (as ``scipy.signal.sosfilt``,
    states ``zh``, ``zl`` updated in place) around the square-law detector; ``out`` gets
    every D-th low-pass output."""
    nh = hpf.shape[0]
    nl = lpf.shape[0]
    m2c0 = -2.0 * c0
    nrf = -rf
    for i in range(v.shape[0]):
        ct = c0 * e[i] + cb + cp
        dc = m2c0 * u[i] / th0 * e[i]
        x = nrf * (dv[i] * ct + v[i] * dc * om[i])
        for s in range(nh):
            y = hpf[s, 0] * x + zh[s, 0]
            zh[s, 0] = hpf[s, 1] * x - hpf[s, 4] * y + zh[s, 1]
            zh[s, 1] = hpf[s, 2] * x - hpf[s, 5] * y
            x = y
        x = ad * x + bd * x * x
        for s in range(nl):
            y = lpf[s, 0] * x + zl[s, 0]
            zl[s, 0] = lpf[s, 1] * x - lpf[s, 4] * y + zl[s, 1]
            zl[s, 1] = lpf[s, 2] * x - lpf[s, 5] * y
            x = y
        if i % D == 0:
            out[i // D] = x
