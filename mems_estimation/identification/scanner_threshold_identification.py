"""Bench identification of the chapter-4 micro-scanner's EKF model (Chen 2018, Sec. 4.4.2).

From one bench record of the device -- the drive voltage ``v`` [V], the sensed ``y_cap`` [V]
(eq. 64) and the PSD angle reference ``theta_psd`` [rad] (eq. 72, delayed), sampled at ``fs``
[Hz] through a sweep into parametric resonance, a hold, the cut-off and the free ring-down
(Sec. 4.4.1) -- as the thesis identified its model (Fig. 4.5, Table 4.2):

1. **Ring-down fit** (Fig. 4.5(a), "fitting the decay curve using linear viscous damping"):
   after the cut-off eq. (66) has V = 0, so theta(t) = A exp(-zeta wn t) cos(wd t + phi),
   wd = wn sqrt(1 - zeta^2); nonlinear least squares on theta_psd over the ring-down gives
   wn [rad/s] and zeta [-] (thesis: 2 pi 624.6 Hz, 0.0066).
2. **Sensing-comb map** (Fig. 4.5(b), eqs. 64, 71 with the Gaussian profile of eq. 105,
   offset to the threshold angle): y_cap = -R_s V_bias dC_s/dtheta omega,
   dC_s/dtheta = -2 C0 u/theta0 exp(-u^2), u = (theta - theta_th)/theta0, fitted on the
   ring-down with theta, omega from the fit of step 1 advanced by the PSD's delay tau.
   Unknowns C0 [F], theta0 [rad], theta_th [rad] (the angle of maximum capacitance,
   thesis 0.0037 rad) and tau [s] (thesis: calibrated 0.114 ms); R_s [Ohm] and V_bias [V]
   are the readout's design values (Table 4.2): only the product R_s V_bias C0 is seen.
   The residual's variance is R_cap [V^2] (Table 4.2: sigma_n = 0.0435 V).
3. **Drive torque** (eqs. 66-67; the EKF's process model needs it over the driven part):
   over the hold, theta'' + 2 zeta wn theta' + wn^2 theta = (C_dr0/J) (-u/theta_dr0)
   exp(-u^2) V^2, u = (theta - theta_th)/theta_dr0, with theta from the delay-corrected PSD,
   in its weak form (modulating functions: no derivative of the measured angle, see
   :func:`drive_fit`); linear least squares in C_dr0/J [F/(kg m^2)] for each theta_dr0,
   theta_dr0 [rad] by a bounded scalar search. J is not identifiable from
   these data (only C_dr0/J and the process-noise torque over J enter the filter): the
   model keeps the mirror's design inertia :data:`DESIGN_INERTIA` and C_dr0 = ratio x J.

Nothing here reads the emulator's parameter table; the result is the estimator's parameter
YAML (:func:`save_identification`, read by :func:`load_identification`), the model the
``scanner_threshold_ekf`` node loads through its ``params_yaml`` parameter.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from mems_estimation.identification.model_yaml import load_model, save_model

__all__ = [
    "DESIGN_INERTIA",
    "MODEL_KEYS",
    "RingdownFit",
    "CombFit",
    "cutoff_index",
    "ringdown_fit",
    "comb_fit",
    "drive_fit",
    "identify",
    "save_identification",
    "load_identification",
]

#: Design moment of inertia of the mirror [kg m^2] (mems_sim.devices.scanner_specs: chosen so
#: that 0-60 V sustains ~0.15 rad); a design value, not identified (module doc, step 3).
DESIGN_INERTIA = 3.25e-13
#: The EKF parameters (``EKF_SPECS``) the identification gives.
MODEL_KEYS = (
    "model_natural_freq_hz",
    "model_damping_ratio",
    "model_inertia",
    "model_threshold_angle",
    "model_sense_c0",
    "model_sense_theta0",
    "model_drive_c0",
    "model_drive_theta0",
    "sense_resistance",
    "bias_voltage",
    "sample_rate_hz",
    "r_cap",
)
#: Largest delay of the PSD reference searched [s] (thesis: 0.114 ms).
MAX_PSD_DELAY_S = 0.5e-3
#: Every how many samples the starting grid of the comb fit evaluates (speed only).
GRID_DECIMATION = 8


class RingdownFit(NamedTuple):
    """theta(t) = amplitude exp(-zeta wn t) cos(wd t + phase), t [s] from ``start``."""

    amplitude: float  # rad
    wn: float  # rad/s
    zeta: float  # -
    phase: float  # rad
    start: int  # first sample of the fit
    rms_residual: float  # rad

    @property
    def wd(self) -> float:
        """Damped angular frequency wn sqrt(1 - zeta^2) [rad/s]."""
        return self.wn * math.sqrt(1.0 - self.zeta**2)

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(theta [rad], omega [rad/s]) of the fitted free decay at times ``t`` [s]."""
        s, wd = self.zeta * self.wn, self.wd
        e = self.amplitude * np.exp(-s * t)
        c, sn = np.cos(wd * t + self.phase), np.sin(wd * t + self.phase)
        return e * c, -e * (s * c + wd * sn)


class CombFit(NamedTuple):
    """Sensing-comb map of eq. (71): C0 [F], theta0 [rad], theta_th [rad], PSD delay [s],
    residual variance R_cap [V^2]."""

    c0: float
    theta0: float
    theta_th: float
    delay_s: float
    r_cap: float


def cutoff_index(v: np.ndarray) -> int:
    """First sample of the ring-down: one after the last non-zero drive sample."""
    nz = np.flatnonzero(np.asarray(v) != 0.0)
    if nz.size == 0:
        raise ValueError("the drive record is all zero: no driven part, no cut-off")
    return int(nz[-1]) + 1


def ringdown_fit(theta_psd: np.ndarray, fs: float, start: int) -> RingdownFit:
    """Step 1 (module doc): the free decay fitted to ``theta_psd[start:]``; ValueError when
    the record holds no decaying oscillation of ten periods."""
    x = np.asarray(theta_psd[start:], dtype=float)
    t = np.arange(x.size) / fs
    if x.size < 64 or not np.any(x):
        raise ValueError("the ring-down record is empty or all zero: no free oscillation")
    # starting values: the spectrum's peak (parabolic interpolation on 8x zero padding) ...
    nfft = 8 * (1 << int(x.size - 1).bit_length())
    spec = np.abs(np.fft.rfft(x, nfft))
    k = int(np.argmax(spec[1:-1])) + 1
    a_, b_, c_ = np.log(spec[k - 1 : k + 2] + 1e-300)
    wd0 = 2.0 * math.pi * fs * (k + 0.5 * (a_ - c_) / (a_ - 2 * b_ + c_)) / nfft
    period = int(round(2.0 * math.pi / wd0 * fs))
    if not 4 <= period <= x.size // 10:
        raise ValueError(
            f"ring-down period {period} samples of {x.size}: no free oscillation of 10 periods"
        )
    # ... the log-amplitude slope of the per-period peaks above a tenth of the first ...
    n_per = x.size // period
    peaks = np.abs(x[: n_per * period]).reshape(n_per, period).max(axis=1)
    tp = (np.arange(n_per) + 0.5) * period / fs
    ok = peaks > 0.1 * peaks[0]
    if ok.sum() < 3:
        raise ValueError("the ring-down decays within three periods: no free oscillation")
    slope, _ = np.polyfit(tp[ok], np.log(peaks[ok]), 1)
    s0 = max(-slope, 1e-6 * wd0)
    # ... and the phase of the first periods (linear least squares on cos, sin)
    m = min(x.size, 3 * period)
    env = np.exp(-s0 * t[:m])
    basis = np.column_stack((env * np.cos(wd0 * t[:m]), env * np.sin(wd0 * t[:m])))
    cc, ss = np.linalg.lstsq(basis, x[:m], rcond=None)[0]
    ph0 = math.atan2(-ss, cc)

    def res(p):
        a, s, wd, ph = p
        return a * np.exp(-s * t) * np.cos(wd * t + ph) - x

    best = least_squares(res, (math.hypot(cc, ss), s0, wd0, ph0), x_scale="jac", method="lm")
    a, s, wd, ph = best.x
    if a < 0:
        a, ph = -a, ph + math.pi
    wn = math.hypot(wd, s)
    return RingdownFit(
        float(a),
        float(wn),
        float(s / wn),
        float(math.remainder(ph, 2 * math.pi)),
        int(start),
        float(np.sqrt(np.mean(best.fun**2))),
    )


def _comb_model(p, t, rd: RingdownFit, gain):
    c0, th0, thth, tau = p
    th, om = rd.state(t + tau)
    u = (th - thth) / th0
    return gain * 2.0 * c0 * u / th0 * np.exp(-u * u) * om


def comb_fit(
    y_cap: np.ndarray,
    rd: RingdownFit,
    fs: float,
    sense_resistance: float,
    bias_voltage: float,
) -> CombFit:
    """Step 2 (module doc): the sensing comb's Gaussian map and the PSD delay from the
    ring-down part of ``y_cap`` (samples from ``rd.start`` on; ``rd`` fits the PSD there).
    A grid over (theta0, tau) with C0 by linear least squares starts the nonlinear fit."""
    y = np.asarray(y_cap[rd.start :], dtype=float)
    t = np.arange(y.size) / fs
    gain = sense_resistance * bias_voltage
    best = (math.inf, None)
    taus = np.arange(0.0, MAX_PSD_DELAY_S + 0.5 / fs, 10.0e-6)
    ts, ys = t[::GRID_DECIMATION], y[::GRID_DECIMATION]
    for tau in taus:
        th, om = rd.state(ts + tau)
        for th0 in np.geomspace(0.005, 0.5, 16):
            u = th / th0
            g = gain * 2.0 * u / th0 * np.exp(-u * u) * om
            gg = float(g @ g)
            if gg <= 0:
                continue
            c0 = float(g @ ys) / gg
            r = float(np.sum((ys - c0 * g) ** 2))
            if c0 > 0 and r < best[0]:
                best = (r, (c0, th0, 0.0, tau))
    if best[1] is None:
        raise ValueError("no sensing-comb map fits the ring-down's y_cap")
    p0 = np.array(best[1])
    scale = np.array([p0[0], p0[1], 0.1 * p0[1], 1.0 / fs])
    r = least_squares(
        lambda p: _comb_model(p * scale, t, rd, gain) - y,
        p0 / scale,
        method="lm",
    )
    c0, th0, thth, tau = r.x * scale
    return CombFit(float(c0), float(abs(th0)), float(thth), float(tau), float(np.mean(r.fun**2)))


#: Length of one modulating function of the drive-torque fit [samples] (a quarter of the
#: nominal 800-sample period at 500 kHz: short against the torque pulses' spacing).
BUMP_SAMPLES = 200


def _bumps(n: int, fs: float, offset: float = 0.0):
    """phi, phi', phi'' (each (n,), per s) of phi(t) = sin(pi t / T)^4 on [0, T],
    T = (L - 1)/fs for a bump of L = ``n`` samples, at the times (k + ``offset``)/fs:
    smooth, zero with three derivatives at both ends."""
    T = (n - 1) / fs
    w = math.pi / T
    x = w * (np.arange(n) + offset) / fs
    sn, cs = np.sin(x), np.cos(x)
    phi = sn**4
    d1 = 4.0 * w * sn**3 * cs
    d2 = 4.0 * w * w * (3.0 * sn**2 * cs**2 - sn**4)
    return phi, d1, d2


def drive_fit(
    v: np.ndarray,
    theta_psd: np.ndarray,
    fs: float,
    rd: RingdownFit,
    comb: CombFit,
    window: tuple[int, int],
) -> tuple[float, float]:
    """Step 3 (module doc): (C_dr0/J [F/(kg m^2)], theta_dr0 [rad]) from the samples
    ``window`` = (lo, hi) of the driven part (the hold before the cut-off). The equation is
    taken in its weak form (modulating functions, Shinbrot 1957; Preisig & Rippin 1993):
    for each smooth bump phi(t) vanishing with its derivatives at its ends, integration by
    parts moves the derivatives off the measured angle,
    int (phi'' - 2 zeta wn phi' + wn^2 phi) theta dt
        = (C_dr0/J) int phi (-u/theta_dr0) exp(-u^2) V^2 dt,
    so the PSD's noise is never differentiated. Bumps of :data:`BUMP_SAMPLES` samples with
    hop half of that tile the window; theta = the PSD advanced by the identified delay; the
    torque integral by the midpoint rule over each interval of the held drive."""
    d = int(round(comb.delay_s * fs))
    lo, hi = window
    lo, hi = max(lo, 0), min(hi, np.asarray(theta_psd).size - d)
    L = BUMP_SAMPLES
    starts = np.arange(lo, hi - L + 1, L // 2)
    if starts.size < 10:
        raise ValueError(f"drive window {window} too short for the drive-torque fit")
    th_all = np.asarray(theta_psd, dtype=float)
    idx = starts[:, None] + np.arange(L)[None, :]
    th = th_all[idx + d]
    phi, d1, d2 = _bumps(L, fs)
    lhs = (th @ (d2 - 2.0 * rd.zeta * rd.wn * d1 + rd.wn**2 * phi)) / fs
    # the torque term by the midpoint rule: the drive is held over each sample interval
    th_mid = 0.5 * (th[:, :-1] + th[:, 1:])
    v2 = np.asarray(v, dtype=float)[idx[:, :-1]] ** 2
    phi_mid = _bumps(L, fs, 0.5)[0][:-1]

    def solve(th0):
        u = (th_mid - comb.theta_th) / th0
        g = ((-u / th0 * np.exp(-u * u) * v2) @ phi_mid) / fs
        ratio = float(g @ lhs) / float(g @ g)
        return ratio, float(np.sum((lhs - ratio * g) ** 2))

    grid = np.geomspace(0.005, 0.5, 25)
    k = int(np.argmin([solve(x)[1] for x in grid]))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    th0 = float(minimize_scalar(lambda x: solve(x)[1], bounds=(a, b), method="bounded").x)
    return solve(th0)[0], th0


def identify(
    v: np.ndarray,
    y_cap: np.ndarray,
    theta_psd: np.ndarray,
    fs: float,
    hold_samples: int,
    sense_resistance: float = 10.0e6,
    bias_voltage: float = 10.0,
) -> dict[str, Any]:
    """The EKF model (:data:`MODEL_KEYS`, SI) from one bench record (module doc, steps 1-3)
    plus ``identification``: what each fit gave (wn [rad/s], zeta, the PSD delay [s], the
    ring-down's start sample and amplitude [rad], the fit residuals). ``hold_samples``: the
    driven samples before the cut-off used by step 3 (the programme's hold). ValueError
    when a fit finds no motion or gives a non-finite or non-physical value."""
    cut = cutoff_index(v)
    start = cut + int(math.ceil(MAX_PSD_DELAY_S * fs))
    rd = ringdown_fit(theta_psd, fs, start)
    comb = comb_fit(y_cap, rd, fs, sense_resistance, bias_voltage)
    ratio, dth0 = drive_fit(v, theta_psd, fs, rd, comb, (cut - hold_samples, cut))
    model = {
        "model_natural_freq_hz": rd.wn / (2.0 * math.pi),
        "model_damping_ratio": rd.zeta,
        "model_inertia": DESIGN_INERTIA,
        "model_threshold_angle": comb.theta_th,
        "model_sense_c0": comb.c0,
        "model_sense_theta0": comb.theta0,
        "model_drive_c0": ratio * DESIGN_INERTIA,
        "model_drive_theta0": dth0,
        "sense_resistance": float(sense_resistance),
        "bias_voltage": float(bias_voltage),
        "sample_rate_hz": float(fs),
        "r_cap": comb.r_cap,
    }
    bad = [
        k
        for k, x in model.items()
        if not (math.isfinite(x) and x > 0) and k != "model_threshold_angle"
    ]
    if bad or not math.isfinite(model["model_threshold_angle"]) or not 0 < rd.zeta < 1:
        raise ValueError(f"identification gave non-physical values: {model}")
    model = {k: float(x) for k, x in model.items()}
    model["identification"] = {
        "ringdown_start_sample": int(start),
        "ringdown_amplitude_rad": rd.amplitude,
        "ringdown_rms_residual_rad": rd.rms_residual,
        "psd_delay_s": comb.delay_s,
        "drive_c0_over_inertia": float(ratio),
        "source": "Chen 2018 Sec. 4.4.2 / Fig. 4.5: ring-down fit, sensing-comb map, "
        "drive-torque fit (mems_estimation.identification.scanner_threshold_identification)",
    }
    return model


def save_identification(model: Mapping[str, Any], path: str) -> None:
    """Write the identified model as the estimator's parameter YAML, whole and never through
    a symbolic link (:func:`mems_sim.bag.output_paths.write_output`; BagWriteError)."""
    save_model(model, path)


def load_identification(path: str) -> dict[str, float]:
    """The model parameters (:data:`MODEL_KEYS`) of a parameter YAML written by
    :func:`save_identification`; FileNotFoundError / ValueError with a clear message."""
    return load_model(path, MODEL_KEYS, "scanner parameter YAML", positive=False)
